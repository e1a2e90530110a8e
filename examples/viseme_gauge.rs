//! Each viseme of a head at half and full weight, rendered front on and measured by the mouth
//! gauge, for `tools/gauge_check.py` to set beside what a face tracker sees on the same renders:
//! `cargo run --example viseme_gauge -- OUT_DIR [--head FILE.glb]` writes OUT_DIR/NAME_AMOUNT.png
//! and OUT_DIR/gauge.csv (viseme, amount, lip gap and mouth width in eye widths).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use lipcall::render::mouth_gauge::MouthGauge;
use lipcall::render::{FrameOptions, Framing, GpuContext, OffscreenRenderer, load_head_or_default};
use lipcall::vocab::{VISEME_NAMES, VisemeWeights};

const AMOUNTS: [f32; 2] = [0.5, 1.0];

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let out = PathBuf::from(args.next().context("OUT_DIR [--head FILE.glb]")?);
    let head = match args.next().as_deref() {
        Some("--head") => Some(PathBuf::from(args.next().context("--head FILE.glb")?)),
        Some(other) => anyhow::bail!("unexpected argument {other}"),
        None => None,
    };
    let model = load_head_or_default(head.as_deref())?;
    let gauge = MouthGauge::new(&model).context("the head has no mouth the gauge can find")?;
    let ctx = GpuContext::new_headless()?;
    let options = FrameOptions {
        width: 640,
        height: 640,
        framing: Framing::Face,
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &model, options)?;
    std::fs::create_dir_all(&out)?;
    let mut csv = String::from("viseme,amount,lip_gap,mouth_width\n");
    for (v, name) in VISEME_NAMES.iter().enumerate() {
        for amount in AMOUNTS {
            // The rest shape takes what the viseme leaves, as the network's convex weights do.
            let mut weights = VisemeWeights::one_hot(0);
            weights.0[0] = 1.0 - amount;
            weights.0[v] += amount;
            let m = gauge.measure(&model, &model.blend_cpu(&weights));
            writeln!(csv, "{name},{amount},{:.4},{:.4}", m.gap, m.width)?;
            offscreen
                .render(&ctx, &weights)?
                .save(out.join(format!("{name}_{amount}.png")))?;
        }
    }
    std::fs::write(out.join("gauge.csv"), csv)?;
    println!("wrote {} on {}", out.display(), ctx.adapter_description());
    Ok(())
}

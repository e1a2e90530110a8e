//! The default head in all 15 visemes, front view, as a labelled 5x3 grid:
//! `cargo run --release --example contact_sheet [OUT.png] [--mouth] [--head FILE.glb] [--tile PX]`
//! (default output `docs/visemes.png`; `--mouth` uses the lipreading close-up; `--head` draws
//! another head than the bundled one; `--tile` sets the side of each of the 15 tiles, 256 px).
mod label;

use std::path::PathBuf;

use anyhow::Context;
use lipcall::render::{FrameOptions, Framing, GpuContext, OffscreenRenderer, load_head_or_default};
use lipcall::vocab::{VISEME_NAMES, VisemeWeights};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut mouth = false;
    let mut head = None;
    let mut tile = 256u32;
    let mut out = None;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--mouth" => mouth = true,
            "--head" => head = Some(PathBuf::from(it.next().context("--head FILE.glb")?)),
            "--tile" => tile = it.next().context("--tile PX")?.parse()?,
            _ => out = Some(PathBuf::from(arg)),
        }
    }
    let out =
        out.unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/visemes.png"));
    let model = load_head_or_default(head.as_deref())?;
    let ctx = GpuContext::new_headless()?;
    let options = FrameOptions {
        width: tile,
        height: tile,
        framing: if mouth { Framing::Mouth } else { Framing::Face },
        ..Default::default()
    };
    let mut offscreen = OffscreenRenderer::new(&ctx, &model, options)?;
    let (cols, rows) = (5u32, 3u32);
    let mut sheet =
        image::RgbaImage::from_pixel(cols * tile, rows * tile, image::Rgba([0, 0, 0, 255]));
    for (i, name) in VISEME_NAMES.iter().enumerate() {
        let weights = VisemeWeights::one_hot(i);
        let img = offscreen.render(&ctx, &weights)?;
        let (x, y) = ((i as u32 % cols) * tile, (i as u32 / cols) * tile);
        image::imageops::overlay(&mut sheet, &img, x as i64, y as i64);
        label::draw_text(
            &mut sheet,
            x + 8,
            y + 8,
            (tile / 85).max(1),
            name,
            [255, 255, 255, 255],
        );
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    sheet.save(&out)?;
    println!("wrote {} on {}", out.display(), ctx.adapter_description());
    Ok(())
}

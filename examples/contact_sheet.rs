//! The default head in all 15 visemes, front view, as a labelled 5x3 grid:
//! `cargo run --release --example contact_sheet [OUT.png] [--mouth]`
//! (default output `docs/visemes.png`; `--mouth` uses the lipreading close-up).
use std::path::PathBuf;

use lipcall::render::{
    FrameOptions, Framing, GpuContext, OffscreenRenderer, VISEME_NAMES, VisemeWeights, label,
};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mouth = args.iter().any(|a| a == "--mouth");
    let out = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/visemes.png"));
    let model = lipcall::render::default_head()?;
    let ctx = GpuContext::new_headless()?;
    let tile = 256u32;
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
        label::draw_text(&mut sheet, x + 8, y + 8, 3, name, [255, 255, 255, 255]);
    }
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    sheet.save(&out)?;
    println!("wrote {} on {}", out.display(), ctx.adapter_description());
    Ok(())
}

use lipcall::render::{FrameOptions, GpuContext, OffscreenRenderer, VisemeWeights, VISEME_NAMES, generate};

fn main() -> anyhow::Result<()> {
    let model = generate::build_default_head();
    let ctx = GpuContext::new_headless()?;
    let mut off = OffscreenRenderer::new(&ctx, &model, FrameOptions { width: 320, height: 320, ..Default::default() })?;
    for name in ["sil", "aa", "PP", "U", "I"] {
        let img = off.render(&ctx, &VisemeWeights::single(name).unwrap())?;
        img.save(format!("/tmp/head_{name}.png"))?;
    }
    let _ = VISEME_NAMES;
    Ok(())
}

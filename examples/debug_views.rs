//! Renders a few views of the default head to /tmp for tuning by eye.
use lipcall::render::{
    Camera, FrameOptions, Framing, GpuContext, OffscreenRenderer, VisemeWeights, generate,
};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let names: Vec<&str> = if args.is_empty() {
        vec!["sil", "aa"]
    } else {
        args.iter().map(|s| s.as_str()).collect()
    };
    let model = generate::build_default_head();
    let frame = model.face_frame();
    eprintln!("{frame:?}");
    let ctx = GpuContext::new_headless()?;
    let mut off = OffscreenRenderer::new(
        &ctx,
        &model,
        FrameOptions {
            width: 400,
            height: 400,
            ..Default::default()
        },
    )?;
    for name in names {
        let w = VisemeWeights::single(name).ok_or_else(|| anyhow::anyhow!("bad name"))?;
        for (tag, framing, yaw) in [
            ("front", Framing::Face, 0.0f32),
            ("side", Framing::Face, 1.35),
            ("mouth", Framing::Mouth, 0.0),
            ("three", Framing::Face, 0.6),
        ] {
            off.camera = Camera::framing_yaw(&frame, framing, yaw);
            off.render(&ctx, &w)?
                .save(format!("/tmp/v_{name}_{tag}.png"))?;
        }
    }
    Ok(())
}

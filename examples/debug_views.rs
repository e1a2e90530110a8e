//! Renders a few views of a head to a folder for tuning by eye:
//! `cargo run --release --example debug_views -- [--head FILE.glb] [--out DIR] [--size PX] [MIX ...]`
//!
//! Each MIX is a viseme name (`aa`) or a weighted blend (`aa=0.5+PP=0.5`); the default is
//! `sil aa`. Every mix is drawn from the front, the side, three-quarters and as the lipreading
//! close-up, to `DIR/v_<mix>_<view>.png` (default DIR `/tmp`).
use std::path::PathBuf;

use anyhow::Context;
use lipcall::render::{
    Camera, FrameOptions, Framing, GpuContext, OffscreenRenderer, load_head_or_default,
};
use lipcall::vocab::VisemeWeights;

fn parse_mix(spec: &str) -> anyhow::Result<VisemeWeights> {
    let mut pairs = Vec::new();
    for part in spec.split('+') {
        let (name, weight) = match part.split_once('=') {
            Some((n, w)) => (n, w.parse::<f32>().context("bad weight")?),
            None => (part, 1.0),
        };
        pairs.push((name, weight));
    }
    Ok(VisemeWeights::from_named(pairs)?)
}

fn main() -> anyhow::Result<()> {
    let mut head = None;
    let mut out = PathBuf::from("/tmp");
    let mut size = 400u32;
    let mut mixes = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--head" => head = Some(PathBuf::from(args.next().context("--head FILE")?)),
            "--out" => out = PathBuf::from(args.next().context("--out DIR")?),
            "--size" => size = args.next().context("--size PX")?.parse()?,
            _ => mixes.push(arg),
        }
    }
    if mixes.is_empty() {
        mixes = vec!["sil".into(), "aa".into()];
    }
    let model = load_head_or_default(head.as_deref())?;
    let frame = model.face_frame();
    eprintln!(
        "{} vertices, {} triangles, {frame:?}",
        model.vertex_count(),
        model.triangle_count()
    );
    let ctx = GpuContext::new_headless()?;
    let mut off = OffscreenRenderer::new(
        &ctx,
        &model,
        FrameOptions {
            width: size,
            height: size,
            ..Default::default()
        },
    )?;
    std::fs::create_dir_all(&out)?;
    for spec in mixes {
        let w = parse_mix(&spec)?;
        let tag = spec.replace(['=', '+'], "_");
        for (view, framing, yaw) in [
            ("front", Framing::Face, 0.0f32),
            ("side", Framing::Face, 1.35),
            ("mouth", Framing::Mouth, 0.0),
            ("three", Framing::Face, 0.6),
        ] {
            off.camera = Camera::framing_yaw(&frame, framing, yaw);
            off.render(&ctx, &w)?
                .save(out.join(format!("v_{tag}_{view}.png")))?;
        }
    }
    Ok(())
}

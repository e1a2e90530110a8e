//! Writes a Ready Player Me-like avatar for offline face-tracker checks
//! (`tools/face_lips.py`): `cargo run --example avatar_glb -- OUT.glb`.
//!
//! The bundled head's geometry, with `viseme_*` targets at 0.35 of its visemes' motion (the
//! range of a Ready Player Me avatar's visemes; the loader's mouth gauge opens them to a
//! speaker's range, as `tests/mouth_gauge.rs`'s weak avatar) and, on the same meshes, ARKit
//! shapes at the same strength: `jawOpen` (its `aa`), `mouthPucker` (its `U`), the stretch pair
//! (half its `I` each) and the blink pair, as `tests/mouth_gauge.rs`'s weak ARKit-only avatar.
//! Both kinds side by side, as Ready Player Me exports them: the loader takes the avatar's own
//! visemes and the ARKit shapes only fill in what it lacks (here the eyes' blink).

#[allow(dead_code)]
#[path = "../tests/common/glb_write.rs"]
mod glb_write;

use anyhow::Context;
use glb_write::{MeshOut, write_meshes};
use lipcall::render::head::{Expression, MorphDelta};
use lipcall::vocab::{VISEME_COUNT, VISEME_NAMES, Viseme};

/// Ready Player Me's viseme range against the bundled head's (tests/mouth_gauge.rs).
const STRENGTH: f32 = 0.35;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .context("usage: avatar_glb OUT.glb")?;
    let head = lipcall::render::default_head()?;
    let slot = |name: &str| Viseme::from_name(name).map(Viseme::index).unwrap();
    let meshes: Vec<MeshOut> = head
        .primitives
        .iter()
        .map(|p| {
            // Target `src` of every vertex, times `by` (absent deltas as zeros).
            let scaled = |src: usize, by: f32| -> Vec<MorphDelta> {
                (0..p.vertices.len())
                    .map(|i| {
                        p.targets[src]
                            .get(i)
                            .map_or(MorphDelta::default(), |d| MorphDelta {
                                position: d.position.map(|x| x * by),
                                normal: d.normal.map(|x| x * by),
                            })
                    })
                    .collect()
            };
            let (mut names, mut targets) = (Vec::new(), Vec::new());
            if p.has_targets() {
                for (v, name) in VISEME_NAMES.iter().enumerate().take(VISEME_COUNT) {
                    names.push(format!("viseme_{name}"));
                    targets.push(scaled(v, STRENGTH));
                }
                for (name, src, by) in [
                    ("jawOpen", slot("aa"), STRENGTH),
                    ("mouthPucker", slot("U"), STRENGTH),
                    ("mouthStretchLeft", slot("I"), 0.5 * STRENGTH),
                    ("mouthStretchRight", slot("I"), 0.5 * STRENGTH),
                    ("eyeBlinkLeft", Expression::Blink.slot(), 0.5),
                    ("eyeBlinkRight", Expression::Blink.slot(), 0.5),
                ] {
                    names.push(name.to_string());
                    targets.push(scaled(src, by));
                }
            }
            MeshOut::unskinned(p, names, targets)
        })
        .collect();
    std::fs::write(&out, write_meshes(&meshes, &head.materials))
        .with_context(|| format!("cannot write {out}"))?;
    let back = lipcall::render::load_head_or_default(Some(std::path::Path::new(&out)))?;
    eprintln!(
        "{out}: {} meshes, viseme_* and ARKit targets; loads as {:?}",
        meshes.len(),
        back.source
    );
    Ok(())
}

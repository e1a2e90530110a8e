//! Rebuilds the bundled default head: `cargo run --release --example build_head [OUT.glb]`.
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/heads/default.glb")
        });
    let model = lipcall::render::generate::build_default_head();
    let bytes = lipcall::render::glb_write::write_glb(&model);
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&out, &bytes)?;
    // The written file must load back with all 15 shapes.
    let back = lipcall::render::gltf_load::load_head_from_slice(&bytes)?;
    anyhow::ensure!(
        back.missing_visemes.is_empty(),
        "missing {:?}",
        back.missing_visemes
    );
    println!(
        "wrote {} ({} bytes, {} vertices, {} triangles)",
        out.display(),
        bytes.len(),
        model.vertex_count(),
        model.triangle_count()
    );
    Ok(())
}

//! Talking heads: the bundled default head, glTF avatars, GPU morph-target blending with wgpu
//! and offscreen frame rendering.
//!
//! The renderer ([`renderer::HeadRenderer`]) does not depend on egui: it builds its pipeline once,
//! uploads each head's morph deltas once ([`renderer::GpuHead`]), writes the weights of at most 20
//! slots (15 visemes, 5 eye shapes) and the head's rotation ([`head::FacePose`]) per head per
//! frame in [`renderer::HeadRenderer::prepare`] and records draws into a render pass it is given
//! ([`renderer::HeadRenderer::paint`]), which is the shape egui-wgpu paint callbacks need.

pub mod arkit;
pub mod camera;
pub mod gltf_load;
pub mod head;
pub mod offscreen;
mod readback;
pub mod renderer;
pub mod target;

pub use camera::{Camera, Framing};
pub use head::HeadModel;
pub use offscreen::{FrameOptions, GpuContext, OffscreenRenderer, WeightTrack, render_frames};
pub use renderer::{GpuHead, HeadInstance, HeadRenderer};

/// Everything that can go wrong while loading, building or rendering a head.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("not a valid glTF/GLB file: {0}")]
    Gltf(String),
    #[error("unsupported glTF content: {0}")]
    Unsupported(String),
    #[error(
        "the head has no usable mouth shapes: expected morph targets named after the visemes \
         (viseme_aa or aa, viseme_PP or PP, ...) or ARKit blendshapes (jawOpen, mouthClose, \
         mouthFunnel, mouthPucker, ...); target names found: {}",
        if found.is_empty() { "none".to_owned() } else { found.join(", ") }
    )]
    NoUsableTargets { found: Vec<String> },
    #[error("invalid head: {0}")]
    InvalidHead(String),
    #[error(
        "unknown viseme name {0:?} (expected one of sil PP FF TH DD kk CH SS nn RR aa E I O U)"
    )]
    UnknownViseme(String),
    #[error("no GPU adapter available (not even a software one): {0}")]
    NoAdapter(String),
    #[error("GPU adapter {adapter:?} lacks what the head renderer needs: {missing}")]
    AdapterUnsuitable { adapter: String, missing: String },
    #[error("GPU device request failed: {0}")]
    Device(String),
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("cannot write image {path}: {message}")]
    Image {
        path: std::path::PathBuf,
        message: String,
    },
    #[error("bad frame options: {0}")]
    Options(String),
}

/// Path of the bundled default head, relative to the repository root.
pub const DEFAULT_HEAD_PATH: &str = "assets/heads/default.glb";

/// The bundled default head (built from the MakeHuman base mesh by `tools/build_head.py`).
pub fn default_head() -> Result<HeadModel, RenderError> {
    gltf_load::load_head_from_slice(include_bytes!("../../assets/heads/default.glb"))
}

/// Loads `--head FILE.glb` if given, else the bundled default head.
pub fn load_head_or_default(path: Option<&std::path::Path>) -> Result<HeadModel, RenderError> {
    match path {
        Some(p) => gltf_load::load_head(p),
        None => default_head(),
    }
}

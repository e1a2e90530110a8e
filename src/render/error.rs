//! What can go wrong in the render layer.

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

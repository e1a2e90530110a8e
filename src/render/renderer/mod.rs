//! The wgpu head renderer: one pipeline per kind of material, heads uploaded once, weights and pose written per frame.
//!
//! The pipelines and layouts (`pipelines`: [`HeadRenderer`]), the upload of a head's meshes,
//! materials and morph deltas (`upload`: [`GpuHead`]), the per-frame uniforms and draws
//! (`frame`: [`HeadInstance`]), whether a frame's picture would differ from the last (`motion`)
//! and the compute pass that reads the GPU's blend back for tests (`gpu_blend`).

mod frame;
mod gpu_blend;
mod motion;
mod pipelines;
mod upload;

pub use frame::HeadInstance;
pub use motion::UNSEEN_MOTION_PX;
pub use pipelines::{DEPTH_FORMAT, HeadRenderer, SHADER_SOURCE, Shading};
pub use upload::{GpuHead, VERTEX_LIT_MAX_EDGE_PX};

//! Talking heads: the bundled default head, glTF avatars, GPU morph-target blending with wgpu
//! and offscreen frame rendering.
//!
//! The renderer ([`renderer::HeadRenderer`]) does not depend on egui: it builds its pipeline once,
//! uploads each head's morph deltas once ([`renderer::GpuHead`]), writes the weights of at most 20
//! slots (15 visemes, 5 eye shapes) and the head's rotation ([`head::FacePose`]) per head per
//! frame in [`renderer::HeadRenderer::prepare`] and records draws into a render pass it is given
//! ([`renderer::HeadRenderer::paint`]), which is the shape egui-wgpu paint callbacks need.

pub mod arkit;
pub mod blit;
pub mod camera;
pub mod drive;
mod error;
pub mod facing;
pub mod gltf_load;
pub mod head;
pub mod lod;
pub mod mouth_gauge;
pub mod offscreen;
mod readback;
pub mod renderer;
pub mod target;
pub mod variant;

pub use camera::{Camera, Framing};
pub use error::RenderError;
pub use gltf_load::{DEFAULT_HEAD_PATH, default_head, load_head_or_default};
pub use head::HeadModel;
pub use offscreen::{FrameOptions, GpuContext, OffscreenRenderer, WeightTrack, render_frames};
pub use renderer::{GpuHead, HeadInstance, HeadRenderer};
pub use variant::{HeadVariant, VARIANTS};

//! Lip sync: viseme sets, phone-derived targets, mouth geometry, the paper's decomposition, the
//! per-frame network and the jaw-from-energy baseline.

pub mod animator;
pub mod builtin;
pub mod coarticulation;
pub mod controls;
pub mod decompose;
pub mod jaw;
pub mod life;
pub mod lips;
pub mod markers;
pub mod mouth;
pub mod network;
pub mod phones;
pub mod receiver;
pub mod recipe;
pub mod reproject;
pub mod viseme_controls;

pub use animator::{Animator, ModelAnimator, parse_closure_bias};
pub use builtin::default_model;
pub use receiver::{LipSync, LipSyncOptions};

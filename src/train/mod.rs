//! Offline training and evaluation of the lip-sync network on a TIMIT-style corpus.

pub mod an4;
pub mod augment;
mod backprop;
pub mod card;
mod closure_snap;
pub mod codec_features;
pub mod config;
pub mod control_targets;
pub mod corpus;
pub mod crossval;
mod dataset;
pub mod error;
pub mod eval;
pub mod grid;
pub mod grid_shapes;
mod init;
pub mod lag;
pub mod plan;
pub mod plot;
pub mod sharpness;
pub mod table_i;
pub mod targets;
pub mod trainer;
pub mod video;

pub use config::TrainConfig;
pub use error::TrainError;
pub use trainer::{TrainReport, run};

#[cfg(test)]
pub(crate) mod stand_in;

//! What can stop a training run, for every part of training to return.

use std::path::PathBuf;

use crate::lipsync::decompose::DecomposeError;
use crate::lipsync::network::MULTIPLY_ADD_BUDGET;
use crate::train::corpus::CorpusError;
use crate::train::eval::EvalError;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Corpus(#[from] CorpusError),
    #[error(transparent)]
    Decompose(#[from] DecomposeError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(
        "the network costs {cost} multiply-adds per frame, over the budget of {MULTIPLY_ADD_BUDGET} \
         (fewer hidden units or context frames, or allow it explicitly)"
    )]
    OverBudget { cost: usize },
    #[error("bad training setting: {0}")]
    BadConfig(String),
    #[error("no training frames")]
    NoFrames,
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

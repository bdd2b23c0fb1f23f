//! Errors of the evaluation layer; each names the file or caption at fault.

use std::path::{Path, PathBuf};

use diffkfc_data::DataError;
use diffkfc_model::error::ModelError;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// A file or directory could not be read or written.
    #[error("{path}: {err}")]
    Io { path: PathBuf, err: std::io::Error },
    /// A file's content does not fit: an evaluator config, its normalisation, a missing checkpoint.
    #[error("{path}: {msg}")]
    File { path: PathBuf, msg: String },
    /// A caption asked of the evaluator has no cached text embedding.
    #[error("caption not embedded: {0}")]
    CaptionNotEmbedded(String),
    /// A loss, weight or embedding is not finite: never turned into a score.
    #[error("{0}")]
    NonFinite(String),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Data(#[from] DataError),
}

impl EvalError {
    pub fn file(path: &Path, msg: impl std::fmt::Display) -> EvalError {
        EvalError::File { path: path.to_path_buf(), msg: msg.to_string() }
    }
}

pub type Result<T, E = EvalError> = std::result::Result<T, E>;

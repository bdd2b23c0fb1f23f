//! Errors of the model layer (configs, run directories, checkpoints, training); each names the
//! file, key or flag at fault and what to do where there is something to do.

use std::path::{Path, PathBuf};

use diffkfc_data::DataError;

use crate::text::TextError;

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    // Not `source`: the message already carries it, and anyhow's chain would print it twice.
    /// A file or directory could not be read or written.
    #[error("{path}: {err}")]
    Io { path: PathBuf, err: std::io::Error },
    /// A file's content is wrong: not a checkpoint, a tensor missing, a stored config invalid.
    #[error("{path}: {msg}")]
    File { path: PathBuf, msg: String },
    /// A run configuration key or value (the message names the key).
    #[error("{0}")]
    Config(String),
    /// A request that cannot be carried out as given (resuming another model's run, stopping
    /// past the learning rate's decay); the message says what to pass instead.
    #[error("{0}")]
    Refused(String),
    /// Training met a non-finite loss, gradient or weight and stopped before saving it.
    #[error("{0}")]
    Diverged(String),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Text(#[from] TextError),
}

impl ModelError {
    /// For `map_err`: an I/O error on `path`.
    pub fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ModelError + '_ {
        move |err| ModelError::Io { path: path.to_path_buf(), err }
    }

    /// A content error in `path`.
    pub fn file(path: &Path, msg: impl std::fmt::Display) -> ModelError {
        ModelError::File { path: path.to_path_buf(), msg: msg.to_string() }
    }

    /// Attach a file name to a config error (a config read from `path`).
    pub fn in_file(self, path: &Path) -> ModelError {
        match self {
            ModelError::Config(msg) => ModelError::file(path, msg),
            other => other,
        }
    }
}

pub type Result<T, E = ModelError> = std::result::Result<T, E>;

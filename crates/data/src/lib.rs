//! diffkfc-data: everything about motion data before and after the network, in the order of the
//! pipeline: `motion` (skeletons, the HumanML3D representation, root keys and tracks), `io`
//! (npy, BVH, motion and keyframe files, atomic outputs), `dataset` (the HumanML3D layout, the
//! packed cache, batches with keyframe masks, checks, the synthetic set), `keyframes`
//! (selection) and `postprocess` (warp, rigid refit, foot lock). Pictures of motion are the
//! `diffkfc-render` crate's.

pub mod dataset;
pub mod io;
pub mod keyframes;
pub mod motion;
pub mod postprocess;
pub mod rng;
#[cfg(any(test, feature = "testing"))]
pub mod testing;

pub use io::atomic::write_atomic;
pub use motion::representation::{features_from_joints, recover_from_ric, Joints, Layout};
pub use motion::skeleton::{Skeleton, KIT, T2M};

use std::path::PathBuf;

/// A name that is none of the choices a setting has (`FromStr` of the settings' enums).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown {what} '{given}' ({choices})")]
pub struct UnknownChoice {
    pub what: &'static str,
    pub given: String,
    pub choices: &'static str,
}

/// Errors of the data layer; each names the file or value at fault.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    // Not `source`: the message already carries it, and anyhow's chain would print it twice.
    #[error("{path}: {err}")]
    Io { path: PathBuf, err: std::io::Error },
    #[error("{path}: {msg}")]
    Npy { path: PathBuf, msg: String },
    #[error("{0}")]
    Invalid(String),
}

impl DataError {
    /// Attach a file name to a content error.
    pub fn in_file(self, path: &std::path::Path) -> DataError {
        match self {
            DataError::Invalid(msg) => DataError::Npy { path: path.to_path_buf(), msg },
            other => other,
        }
    }
}

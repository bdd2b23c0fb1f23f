//! diffkfc-data: the HumanML3D / KIT-ML file formats, skeletons and motion representation.

pub mod absolute_root;
mod atomic;
pub mod batch;
pub mod bvh;
pub mod cache;
pub mod check;
pub mod dataset;
pub mod fixtures;
pub mod footlock;
pub mod fuzz;
pub mod keyframe_file;
pub mod keyframes;
pub mod loader_bench;
pub mod magnitude;
pub mod motion_file;
pub mod npy;
pub mod output_set;
pub mod plausibility;
pub(crate) mod pose;
pub mod quat;
pub mod render;
pub mod representation;
pub mod rig;
pub mod rigid;
pub mod rng;
pub mod root_path;
pub mod root_track;
pub mod skeleton;
pub mod synth;
pub mod texts;
pub mod timeline;
pub mod viewer;
pub mod warp;

pub use atomic::write_atomic;
pub use representation::{features_from_joints, recover_from_ric, Joints, Layout};
pub use skeleton::{Skeleton, KIT, T2M};

use std::path::PathBuf;

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

//! diffkfc-model: the DiffKFC network in Burn (text encoder, Dilated Mask Attention keyframe
//! encoder, transformer decoder) and its diffusion, guidance and losses.

pub mod attention;
pub(crate) mod batch;
pub mod bench;
pub mod checkpoint;
pub(crate) mod config;
pub(crate) mod decoder;
pub mod denoiser;
pub mod diffusion;
pub mod dma;
pub mod dropout;
pub(crate) mod embed;
pub mod error;
pub mod fit;
pub mod flops;
pub mod guidance;
pub mod kernels;
pub(crate) mod kinematics;
pub(crate) mod losses;
pub mod memory;
pub mod optim;
pub mod parallel;
pub mod params;
pub mod pipeline;
pub mod place;
pub mod run_config;
pub mod run_dir;
pub mod run_lock;
pub mod sampler;
pub mod scheduler;
pub(crate) mod temporal;
pub mod text;
pub mod trainer;
pub(crate) mod transition;
pub(crate) mod warm_start;

pub use config::DiffKfcConfig;
pub use denoiser::{Condition, Denoiser, Encoded};

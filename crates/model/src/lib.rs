//! diffkfc-model: the DiffKFC network in Burn and everything that runs it, in the order of the
//! pipeline: `text` (the frozen MiniLM encoder), `network` (keyframe encoder, decoder),
//! `diffusion` (the noise schedule and its schedulers), `training` (loop, losses, optimiser),
//! `run` (configs, run directories, checkpoints, loading for inference), `sampling` (the
//! reverse loop, guidance, fits, the generation pipeline), `kernels` (fused CPU kernels) and
//! `bench`.

pub mod bench;
pub mod diffusion;
pub mod error;
pub mod kernels;
pub mod network;
pub mod run;
pub mod sampling;
pub mod text;
pub mod training;

pub use network::condition::Condition;
pub use network::config::DiffKfcConfig;
pub use network::denoiser::{Denoiser, Encoded};

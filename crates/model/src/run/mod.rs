//! A run on disk: its config, its directory (normalisation, metrics, loss plot), the lock a
//! training holds on it, checkpoints and exported models, and loading a model for inference.

pub mod checkpoint;
pub mod config;
pub mod dir;
pub mod load;
pub mod lock;
pub mod recipe;
pub mod retired;

//! The DiffKFC network: the denoiser (text and timestep conditioning, transformer decoder
//! layers with an optional temporal convolution), the Dilated Mask Attention keyframe encoder,
//! attention, sinusoidal encodings, dropout, word-level text conditioning, its config and its
//! parameters as host vectors.

pub mod attention;
pub mod condition;
pub mod config;
pub(crate) mod decoder;
pub mod denoiser;
pub mod dropout;
pub mod inference;
pub mod keyframe_encoder;
pub mod params;
pub(crate) mod sinusoidal;
pub(crate) mod temporal;
pub mod words;

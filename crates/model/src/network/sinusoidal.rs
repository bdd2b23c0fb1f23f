//! Sinusoidal encodings (frame positions and diffusion timesteps) and the timestep MLP.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::kernels::linear;
use burn::tensor::activation::silu;

/// Sinusoidal table [n, d]: sin on even, cos on odd channels (Vaswani et al.).
pub fn sinusoid_table(positions: &[f32], d: usize) -> Vec<f32> {
    let mut out = vec![0f32; positions.len() * d];
    for (i, &p) in positions.iter().enumerate() {
        for k in 0..d / 2 {
            let freq = (-(10000f32.ln()) * (2 * k) as f32 / d as f32).exp();
            out[i * d + 2 * k] = (p * freq).sin();
            out[i * d + 2 * k + 1] = (p * freq).cos();
        }
    }
    out
}

/// Positional encodings of `n` frames: [1, n, d].
pub fn positions(n: usize, d: usize, device: &Device) -> Tensor<3> {
    Tensor::<1>::from_floats(position_table(n, d).as_slice(), device).reshape([1, n, d])
}

/// The same encodings on the host, [n, d].
pub fn position_table(n: usize, d: usize) -> Vec<f32> {
    let pos: Vec<f32> = (0..n).map(|i| i as f32).collect();
    sinusoid_table(&pos, d)
}

/// Timestep embedding: sinusoid of t, then Linear-SiLU-Linear (MDM's TimestepEmbedder).
#[derive(Module, Debug)]
pub struct TimestepEmbed {
    pub(super) fc1: Linear,
    pub(super) fc2: Linear,
    pub(super) d: usize,
}

impl TimestepEmbed {
    pub fn new(d: usize, device: &Device) -> Self {
        TimestepEmbed {
            fc1: LinearConfig::new(d, d).init(device),
            fc2: LinearConfig::new(d, d).init(device),
            d,
        }
    }

    /// `t`: timesteps, one per sample -> [B, 1, d].
    pub fn forward(&self, t: &[usize], device: &Device) -> Tensor<3> {
        let pos: Vec<f32> = t.iter().map(|&x| x as f32).collect();
        let table = Tensor::<1>::from_floats(sinusoid_table(&pos, self.d).as_slice(), device)
            .reshape([t.len(), self.d]);
        linear(&self.fc2, silu(linear(&self.fc1, table))).unsqueeze_dim(1)
    }
}

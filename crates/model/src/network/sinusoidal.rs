//! Sinusoidal encodings (frame positions and diffusion timesteps) and the timestep MLP.

use std::collections::BTreeMap;
use std::sync::Mutex;

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::kernels::linear;
use burn::tensor::activation::silu;

/// Sinusoidal table [n, d]: sin on even, cos on odd channels (Vaswani et al.).
pub fn sinusoid_table(positions: &[f32], d: usize) -> Vec<f32> {
    let freqs: Vec<f32> =
        (0..d / 2).map(|k| (-(10000f32.ln()) * (2 * k) as f32 / d as f32).exp()).collect();
    let mut out = vec![0f32; positions.len() * d];
    for (row, &p) in out.chunks_exact_mut(d).zip(positions) {
        for (pair, &freq) in row.chunks_exact_mut(2).zip(&freqs) {
            pair[0] = (p * freq).sin();
            pair[1] = (p * freq).cos();
        }
    }
    out
}

/// Positional encodings of `n` frames: [1, n, d].
pub fn positions(n: usize, d: usize, device: &Device) -> Tensor<3> {
    Tensor::<1>::from_floats(position_table(n, d).as_slice(), device).reshape([1, n, d])
}

/// The same encodings on the host, [n, d]. A frame's row does not depend on n, so the rows come
/// from one table per width, grown to the longest n asked for: every sampling call and training
/// step reads them, and n x d sines and cosines cost more than the rest of the DMA plan.
pub fn position_table(n: usize, d: usize) -> Vec<f32> {
    static TABLES: Mutex<BTreeMap<usize, Vec<f32>>> = Mutex::new(BTreeMap::new());
    let mut tables = TABLES.lock().unwrap_or_else(|e| e.into_inner());
    let table = tables.entry(d).or_default();
    if table.len() < n * d {
        let pos: Vec<f32> = (0..n).map(|i| i as f32).collect();
        *table = sinusoid_table(&pos, d);
    }
    table[..n * d].to_vec()
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The cached rows are the table's own: asked for shorter, longer, then shorter again.
    #[test]
    fn position_rows_do_not_depend_on_the_length_asked() {
        for n in [5, 40, 1, 17, 40, 41] {
            let pos: Vec<f32> = (0..n).map(|i| i as f32).collect();
            assert_eq!(position_table(n, 6), sinusoid_table(&pos, 6), "n = {n}");
        }
        // Frame 1 of d = 4: frequencies 1 and 10000^(-2/4).
        let want = [1f64.sin(), 1f64.cos(), 0.01f64.sin(), 0.01f64.cos()];
        for (got, want) in position_table(3, 4)[4..8].iter().zip(want) {
            assert!((*got as f64 - want).abs() < 1e-6, "{got} against {want}");
        }
    }
}

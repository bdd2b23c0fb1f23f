//! Data batches (flat host buffers from `diffkfc-data`) to Burn tensors.

use burn::prelude::*;
use diffkfc_data::batch::Batch;

use crate::denoiser::Condition;

/// Tensors of a training batch: the clean motion and what it is conditioned on.
pub struct TensorBatch {
    /// [B, N, D] normalised features (zero on padding).
    pub x0: Tensor<3>,
    /// [B, N] 1 on real frames.
    pub valid: Tensor<2>,
    pub cond: Condition,
}

/// `text` holds one embedding of width `text_dim` per sample, row-major.
pub fn to_tensors(b: &Batch, text: &[f32], text_dim: usize, device: &Device) -> TensorBatch {
    let (bs, n, d) = (b.batch_size, b.frames, b.dim);
    assert_eq!(text.len(), bs * text_dim, "one text embedding per sample");
    let x0 = Tensor::<1>::from_floats(b.x0.as_slice(), device).reshape([bs, n, d]);
    let kf_mask = Tensor::<1>::from_floats(b.kf_mask.as_slice(), device).reshape([bs, n, d]);
    let kf = x0.clone() * kf_mask.clone();
    let real = b.valid.iter().map(|&v| v > 0.0).collect();
    let text = Tensor::<1>::from_floats(text, device).reshape([bs, text_dim]);
    let cond = Condition::new(text, kf, kf_mask, &b.kf_mask, &b.root, &b.root_mask, real, device);
    TensorBatch {
        x0,
        valid: Tensor::<1>::from_floats(b.valid.as_slice(), device).reshape([bs, n]),
        cond,
    }
}

//! Data batches (flat host buffers from `diffkfc-data`) to Burn tensors.

use burn::prelude::*;
use burn::tensor::TensorData;
use diffkfc_data::dataset::batch::Batch;
use rayon::prelude::*;

use crate::diffusion::Schedule;
use crate::network::condition::Condition;

/// Tensors of a training batch: the clean motion and what it is conditioned on.
pub struct TensorBatch {
    /// [B, N, D] normalised features (zero on padding).
    pub x0: Tensor<3>,
    /// [B, N, D] x0 noised to each sample's timestep (`Schedule::q_sample`).
    pub x_t: Tensor<3>,
    /// [B, N] 1 on real frames.
    pub valid: Tensor<2>,
    pub cond: Condition,
}

/// `text` holds one embedding of width `text_dim` per sample, row-major. `noised`: the
/// schedule, timesteps and noise ([B * N * D]) that make x_t. The elementwise work runs here
/// on the host, in parallel, and the buffers become tensors without a copy: as Burn ops they
/// were single-threaded passes on the training thread.
pub fn to_tensors(
    b: &Batch,
    text: &[f32],
    text_dim: usize,
    noised: (&Schedule, &[usize], &[f32]),
    device: &Device,
) -> TensorBatch {
    let (bs, n, d) = (b.batch_size, b.frames, b.dim);
    assert_eq!(text.len(), bs * text_dim, "one text embedding per sample");
    let (x0, kf_mask) = (b.x0.clone(), &b.kf_mask);
    let (schedule, t, noise) = noised;
    let x_t = schedule.q_sample_host(&x0, t, noise);
    let kf: Vec<f32> = x0.par_iter().zip(kf_mask).map(|(x, m)| x * m).collect();
    let owned = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [bs, n, d]), device);
    let kf_mask_t = Tensor::<1>::from_floats(kf_mask.as_slice(), device).reshape([bs, n, d]);
    let real = b.valid.iter().map(|&v| v > 0.0).collect();
    let text = Tensor::<1>::from_floats(text, device).reshape([bs, text_dim]);
    let cond =
        Condition::new(text, owned(kf), kf_mask_t, kf_mask, &b.root, &b.root_mask, real, device);
    TensorBatch {
        x0: owned(x0),
        x_t: owned(x_t),
        valid: Tensor::<1>::from_floats(b.valid.as_slice(), device).reshape([bs, n]),
        cond,
    }
}

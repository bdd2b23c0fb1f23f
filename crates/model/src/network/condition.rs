//! What the denoiser is conditioned on: the text embedding, the keyframes' features and masks,
//! their root places and headings, for a batch.

use burn::prelude::*;

use diffkfc_data::motion::root_key::ROOT_CHANNELS;

/// What the model is conditioned on, for a batch of B samples of N frames.
#[derive(Clone, Debug)]
pub struct Condition {
    /// [B, text_dim] frozen text embeddings.
    pub text: Tensor<2>,
    /// [B, N, D] normalised keyframe features, zero where unobserved.
    pub kf: Tensor<3>,
    /// [B, N, D] 1 where a keyframe observes a feature.
    pub kf_mask: Tensor<3>,
    /// [B, N, ROOT_CHANNELS] keyed root place and heading (`diffkfc_data::motion::root_key::RootKey`),
    /// zero where unobserved, and its mask.
    pub root: Tensor<3>,
    pub root_mask: Tensor<3>,
    /// `[B*N]` frames with any observed feature.
    pub kf_frames: Vec<bool>,
    /// `[B*N]` real (non-padding) frames.
    pub real: Vec<bool>,
}

impl Condition {
    /// A condition from device tensors `text` [B, T], `kf`/`kf_mask` [B, N, D] and the host
    /// copies of the masks (`[B*N*D]` features, `[B*N*R]` root channels with their values).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        text: Tensor<2>,
        kf: Tensor<3>,
        kf_mask: Tensor<3>,
        mask: &[f32],
        root: &[f32],
        root_mask: &[f32],
        real: Vec<bool>,
        device: &Device,
    ) -> Condition {
        let [b, n, d] = kf.dims();
        let r = ROOT_CHANNELS;
        assert_eq!(
            (root.len(), root_mask.len()),
            (b * n * r, b * n * r),
            "root channels [B, N, {r}]"
        );
        let kf_frames = (0..b * n)
            .map(|f| {
                mask[f * d..(f + 1) * d]
                    .iter()
                    .chain(&root_mask[f * r..(f + 1) * r])
                    .any(|&m| m > 0.0)
            })
            .collect();
        let root_t = |v: &[f32]| Tensor::<1>::from_floats(v, device).reshape([b, n, r]);
        Condition {
            text,
            kf,
            kf_mask,
            root: root_t(root),
            root_mask: root_t(root_mask),
            kf_frames,
            real,
        }
    }

    /// The same condition with its text dropped (a zero embedding, as training drops it):
    /// text classifier-free guidance.
    pub fn without_text(&self) -> Condition {
        Condition { text: self.text.zeros_like(), ..self.clone() }
    }

    /// The same condition with all keyframes dropped (keyframe classifier-free guidance).
    pub fn without_keyframes(&self) -> Condition {
        Condition {
            text: self.text.clone(),
            kf: self.kf.zeros_like(),
            kf_mask: self.kf_mask.zeros_like(),
            root: self.root.zeros_like(),
            root_mask: self.root_mask.zeros_like(),
            kf_frames: vec![false; self.kf_frames.len()],
            real: self.real.clone(),
        }
    }

    /// The condition of batch rows `rows` (in that order).
    pub fn select_rows(&self, rows: &[usize]) -> Condition {
        let n = self.kf.dims()[1];
        let idx = row_index(rows, &self.kf.device());
        let frames = |v: &[bool]| -> Vec<bool> {
            rows.iter().flat_map(|&r| v[r * n..(r + 1) * n].iter().copied()).collect()
        };
        Condition {
            text: self.text.clone().select(0, idx.clone()),
            kf: self.kf.clone().select(0, idx.clone()),
            kf_mask: self.kf_mask.clone().select(0, idx.clone()),
            root: self.root.clone().select(0, idx.clone()),
            root_mask: self.root_mask.clone().select(0, idx),
            kf_frames: frames(&self.kf_frames),
            real: frames(&self.real),
        }
    }

    /// The same condition on the inner backend: for a forward pass nothing differentiates.
    pub fn without_autodiff(&self) -> Condition {
        Condition {
            text: self.text.clone().without_autodiff(),
            kf: self.kf.clone().without_autodiff(),
            kf_mask: self.kf_mask.clone().without_autodiff(),
            root: self.root.clone().without_autodiff(),
            root_mask: self.root_mask.clone().without_autodiff(),
            kf_frames: self.kf_frames.clone(),
            real: self.real.clone(),
        }
    }
}

/// `rows` as the index tensor of `select` / `select_assign` along the batch axis.
pub fn row_index(rows: &[usize], device: &Device) -> Tensor<1, Int> {
    let idx: Vec<i64> = rows.iter().map(|&r| r as i64).collect();
    Tensor::<1, Int>::from_ints(idx.as_slice(), device)
}

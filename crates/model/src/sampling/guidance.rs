//! Keyframe classifier-free guidance (paper Eq. 3): X = X(C, none) + s (X(C, kf) - X(C, none)).
//! Training drops all keyframes of some samples (`diffkfc_data::dataset::batch`) so that the keyframe-free
//! branch is learned; sampling runs both branches in one batched forward and combines them here.

use burn::prelude::*;

use crate::Condition;

/// Largest keyframe guidance scale accepted (at 100 the sampler already diverges).
pub const MAX_GUIDANCE: f64 = 100.0;
/// Largest transition or place guidance strength accepted.
pub const MAX_STRENGTH: f64 = 1e5;

/// A guidance value outside its range, named as the user gave it (a flag or a request field).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{name}: {value} must be a number from 0 to {max}{hint}")]
pub struct OutOfRange {
    pub name: String,
    pub value: f64,
    pub max: f64,
    /// What values mean, appended to the message.
    pub hint: String,
}

/// A guidance scale or strength `v` named `name` (a flag or a request field) in 0..=`max`;
/// `hint` ends the message (what values mean).
pub fn check_range(name: &str, v: f64, max: f64, hint: &str) -> Result<(), OutOfRange> {
    if v.is_finite() && (0.0..=max).contains(&v) {
        Ok(())
    } else {
        Err(OutOfRange { name: name.into(), value: v, max, hint: hint.into() })
    }
}

/// Whether sampling with keyframe guidance scale `s` runs both branches (a doubled batch): only
/// when there are keyframes, the keyframe branch is used (not MDM-inp) and s is not 1 (where
/// the combination is the conditional branch alone).
pub fn is_guided(s: f64, any_keys: bool, inpaint: bool) -> bool {
    any_keys && !inpaint && (s - 1.0).abs() > 1e-12
}

/// The guidance batch of a condition: [with keyframes; without], one forward for both.
pub fn pair(c: &Condition) -> Condition {
    stack(c, &c.without_keyframes())
}

/// The guided prediction from the output of a [`pair`] batch, [2B, N, D] -> [B, N, D].
pub fn combine(out: Tensor<3>, s: f64) -> Tensor<3> {
    let [b2, n, d] = out.dims();
    let b = b2 / 2;
    let c = out.clone().slice([0..b, 0..n, 0..d]);
    let u = out.slice([b..b2, 0..n, 0..d]);
    u.clone() + (c - u) * s
}

/// Two conditions stacked along the batch: [a; b].
fn stack(a: &Condition, b: &Condition) -> Condition {
    Condition {
        text: Tensor::cat(vec![a.text.clone(), b.text.clone()], 0),
        kf: Tensor::cat(vec![a.kf.clone(), b.kf.clone()], 0),
        kf_mask: Tensor::cat(vec![a.kf_mask.clone(), b.kf_mask.clone()], 0),
        root: Tensor::cat(vec![a.root.clone(), b.root.clone()], 0),
        root_mask: Tensor::cat(vec![a.root_mask.clone(), b.root_mask.clone()], 0),
        path: Tensor::cat(vec![a.path.clone(), b.path.clone()], 0),
        kf_frames: a.kf_frames.iter().chain(&b.kf_frames).copied().collect(),
        real: a.real.iter().chain(&b.real).copied().collect(),
    }
}

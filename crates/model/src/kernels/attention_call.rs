//! What one attention call is, for every kernel that computes one (the per-head kernel, the
//! flash kernel, the softmax rows): its shapes and which keys each query may see.

use std::sync::Arc;

use super::host::View;

/// Which keys each query may not see (true = blocked).
#[derive(Clone, Debug)]
pub enum Mask {
    None,
    /// [B * Lk]: key padding, the same for every query.
    Keys(Arc<Vec<bool>>),
    /// [B * Lq * Lk]: per query and key.
    Full(Arc<Vec<bool>>),
}

impl Mask {
    /// The mask of samples `samples` alone, for queries of `lq` rows and keys of `lk`.
    pub fn of_samples(&self, samples: std::ops::Range<usize>, lq: usize, lk: usize) -> Mask {
        let cut =
            |m: &[bool], per: usize| Arc::new(m[samples.start * per..samples.end * per].to_vec());
        match self {
            Mask::None => Mask::None,
            Mask::Keys(m) => Mask::Keys(cut(m, lk)),
            Mask::Full(m) => Mask::Full(cut(m, lq * lk)),
        }
    }
}

/// Shapes of one attention call: queries [B, Lq, d], keys and values [B, Lk, d], d = heads x dh;
/// head h owns channels h*dh .. (h+1)*dh of every row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttnShape {
    pub batch: usize,
    pub lq: usize,
    pub lk: usize,
    pub heads: usize,
    pub d: usize,
}

impl AttnShape {
    pub(super) fn dh(&self) -> usize {
        self.d / self.heads
    }

    pub(super) fn scale(&self) -> f32 {
        1.0 / (self.dh() as f32).sqrt()
    }

    /// Head h of sample b of a [B, L, d] tensor as an [L, dh] view.
    pub(super) fn head(&self, x: &[f32], l: usize, b: usize, h: usize) -> View {
        View { ptr: x[(b * l) * self.d + h * self.dh()..].as_ptr(), rs: self.d as isize, cs: 1 }
    }
}

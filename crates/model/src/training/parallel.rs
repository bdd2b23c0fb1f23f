//! Data-parallel training's one subtle point, worked out and tested on the CPU (no multi-GPU
//! machine here; docs/multi-gpu.md has the design). Every loss term is a masked sum divided by a
//! count over the whole batch (feature elements no keyframe observes, observed elements, real
//! frames, pairs of real frames), and the shards of a batch have different counts: lengths and
//! keyframes differ per sample. Averaging the shards' own losses, which a plain mean all-reduce
//! of gradients does, weights samples differently from the single-device step. Weighting each
//! shard's terms by its share of the batch's count of that term and summing the gradients
//! reproduces the single-device gradient; the counts are four scalars per shard, all-reduced
//! before the backward pass.

use burn::prelude::*;
use diffkfc_data::dataset::batch::Batch;

use crate::training::losses::{Kinematic, Losses, Over};

/// The counts the loss terms divide by, over one batch or shard.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Counts {
    /// Feature elements of real frames that no keyframe observes (L_simple).
    pub free: f64,
    /// Feature elements of real frames a keyframe observes (the keyframe loss).
    pub observed: f64,
    /// Real frames (the position loss).
    pub frames: f64,
    /// Pairs of consecutive real frames (the smoothness, velocity and foot losses).
    pub pairs: f64,
}

impl Counts {
    pub fn of(b: &Batch) -> Counts {
        let (n, d) = (b.frames, b.dim);
        let mut c = Counts::default();
        for i in 0..b.batch_size {
            for f in 0..n {
                let v = b.valid[i * n + f] as f64;
                let observed: f64 =
                    b.kf_mask[(i * n + f) * d..(i * n + f + 1) * d].iter().map(|&m| m as f64).sum();
                c.observed += v * observed;
                c.free += v * (d as f64 - observed);
                c.frames += v;
                if f + 1 < n {
                    c.pairs += v * b.valid[i * n + f + 1] as f64;
                }
            }
        }
        c
    }

    /// The counts of the whole batch from its shards' (what the all-reduce computes).
    pub fn sum(parts: &[Counts]) -> Counts {
        parts.iter().fold(Counts::default(), |a, p| Counts {
            free: a.free + p.free,
            observed: a.observed + p.observed,
            frames: a.frames + p.frames,
            pairs: a.pairs + p.pairs,
        })
    }
}

/// How shard gradients are combined.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Combine {
    /// Each term weighted by the shard's share of the batch's count: the single-device gradient.
    ByCounts,
    /// The mean of the shards' own losses (a plain mean all-reduce): not the same gradient.
    Mean,
}

/// A shard's weight on each loss term: its share of the batch's count that term divides by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shares {
    pub free: f64,
    pub observed: f64,
    pub frames: f64,
    pub pairs: f64,
}

impl Shares {
    /// The whole batch.
    pub const ONE: Shares = Shares { free: 1.0, observed: 1.0, frames: 1.0, pairs: 1.0 };

    pub fn of(mine: &Counts, all: &Counts, shards: usize, combine: Combine) -> Shares {
        let share = |m: f64, a: f64| match combine {
            Combine::ByCounts if a > 0.0 => m / a,
            Combine::ByCounts => 0.0,
            Combine::Mean => 1.0 / shards as f64,
        };
        Shares {
            free: share(mine.free, all.free),
            observed: share(mine.observed, all.observed),
            frames: share(mine.frames, all.frames),
            pairs: share(mine.pairs, all.pairs),
        }
    }
}

impl Shares {
    /// The share of a term that is a mean over `over`.
    pub(crate) fn of_term(&self, over: Over) -> f64 {
        match over {
            Over::Observed => self.observed,
            Over::Frames => self.frames,
            Over::Pairs => self.pairs,
        }
    }
}

/// One shard's objective, its terms weighted by its `shares`: backward of it on every shard,
/// gradients summed, gives the gradient of `Losses::total` over the whole batch
/// (`Combine::ByCounts` shares).
pub(crate) fn shard_objective(l: &Losses, k: &Kinematic, shares: &Shares) -> Tensor<1> {
    let mut t = l.simple.clone() * shares.free;
    for (term, w, over) in l.terms(k) {
        if let Some(x) = term {
            t = t + x.clone() * (w * shares.of_term(over));
        }
    }
    t
}

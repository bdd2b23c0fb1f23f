//! The keyframe encoder: a stack of Dilated Mask Attention (DMA) blocks (paper Eq. 6-7).
//!
//! Token 0 is the text token y_c (always valid); tokens 1..=N are frames. In a block of window
//! size s, a frame is *active* iff a valid frame lies within s of it; active frames attend to
//! the valid frames within s and to y_c; inactive frames are left unchanged and stay invalid;
//! afterwards every active frame is valid, so the valid region dilates block by block.
//! Padding is never valid. Block: Z' = FC([DMA(Z) || Z]), Z = MLP(Z'); no LayerNorm; a global
//! skip from the encoder input to its output.

use std::sync::Arc;

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::kernels::{linear, linear_gelu, rows_run, Mask};
use crate::network::attention::{Attention, TokenRows};
use crate::network::condition::Condition;

/// Per-block validity and attention masks of a batch, computed on the host from the keyframe
/// frames and the padding (they do not depend on any tensor value).
#[derive(Clone, Debug)]
pub struct DmaPlan {
    pub batch: usize,
    pub frames: usize,
    /// Per block: [B * (1+N)] whether a token is updated (text token always).
    pub active: Vec<Vec<bool>>,
    /// [B * (1+N)] validity before the first block (text token and real keyframes), then after
    /// each block: blocks + 1 entries.
    pub valid: Vec<Vec<bool>>,
    /// Per block: [B * (1+N) * (1+N)] true where query i must not see key j.
    pub blocked: Vec<Arc<Vec<bool>>>,
}

impl DmaPlan {
    /// `keyframe[b*N+i]`: frame i of sample b is observed; `real`: it is not padding.
    pub fn new(
        keyframe: &[bool],
        real: &[bool],
        batch: usize,
        frames: usize,
        sizes: &[usize],
    ) -> DmaPlan {
        let (n, l) = (frames, frames + 1);
        let mut valid: Vec<bool> = (0..batch * l)
            .map(|k| {
                let (b, i) = (k / l, k % l);
                i == 0 || (keyframe[b * n + i - 1] && real[b * n + i - 1])
            })
            .collect();
        let (mut active_all, mut blocked_all) = (Vec::new(), Vec::new());
        let mut valid_all = vec![valid.clone()];
        for &size in sizes {
            let s = if size == 0 { n } else { size };
            let mut active = vec![false; batch * l];
            let mut blocked = vec![true; batch * l * l];
            for b in 0..batch {
                let v = &valid[b * l..(b + 1) * l];
                active[b * l] = true;
                // Text query: every valid token.
                for j in 0..l {
                    blocked[(b * l) * l + j] = !v[j];
                }
                for i in 1..l {
                    let row = (b * l + i) * l;
                    // Every query may see y_c, so no row is empty (inactive rows are discarded).
                    blocked[row] = false;
                    if !real[b * n + i - 1] {
                        continue;
                    }
                    let (lo, hi) = (i.saturating_sub(s).max(1), (i + s).min(n));
                    for j in lo..=hi {
                        if v[j] {
                            active[b * l + i] = true;
                            blocked[row + j] = false;
                        }
                    }
                }
            }
            for (v, a) in valid.iter_mut().zip(&active) {
                *v |= *a;
            }
            active_all.push(active);
            valid_all.push(valid.clone());
            blocked_all.push(Arc::new(blocked));
        }
        DmaPlan { batch, frames, active: active_all, valid: valid_all, blocked: blocked_all }
    }

    /// Tokens block k may attend to (valid before it).
    pub fn valid_before(&self, k: usize) -> &[bool] {
        &self.valid[k]
    }

    /// Validity after block k.
    pub fn valid_after(&self, k: usize) -> &[bool] {
        &self.valid[k + 1]
    }

    /// The rows and attention scores each block runs on the fused CPU path, after its gathers
    /// (for the FLOP count of what is computed rather than of the dense shapes). The tensor path
    /// scores every query row; with `query_rows` (the sampling path's encoder,
    /// `network::inference`) the attention runs on the rows the block gathers.
    pub fn work(&self, query_rows: bool) -> Vec<BlockWork> {
        let (b, l) = (self.batch, self.frames + 1);
        let count = |m: &[bool]| m.iter().filter(|&&v| v).count();
        let rows = |m: &[bool]| rows_run(count(m), m.len());
        (0..self.active.len())
            .map(|k| {
                let (valid, active) = (self.valid_before(k), &self.active[k]);
                // The rule that gathers the block's rows (`rows_run`) gathers its queries.
                let gathered = query_rows && rows(active) < active.len();
                // Every query sees y_c; the text query sees every valid token, the others a
                // subset: a sample's seen keys are its valid tokens (what the kernel gathers).
                let scores = (0..b)
                    .map(|s| {
                        let queries = if gathered { count(&active[s * l..(s + 1) * l]) } else { l };
                        queries * rows(&valid[s * l..(s + 1) * l])
                    })
                    .sum();
                BlockWork { queries: rows(active), keys: rows(valid), scores }
            })
            .collect()
    }

    /// Valid tokens at the encoder output (text token included): what the decoder may attend.
    pub fn final_valid(&self) -> &[bool] {
        self.valid.last().expect("the initial validity is always there")
    }
}

/// What one DMA block computes, summed over the batch: rows through the query, output, concat-FC
/// and MLP layers; rows through the key and value layers; query-key pairs scored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlockWork {
    pub queries: usize,
    pub keys: usize,
    pub scores: usize,
}

impl BlockWork {
    /// Every token of `batch` sequences of `tokens` as query and key.
    pub fn dense(batch: usize, tokens: usize) -> BlockWork {
        BlockWork { queries: batch * tokens, keys: batch * tokens, scores: batch * tokens * tokens }
    }
}

#[derive(Module, Debug)]
pub struct DmaBlock {
    pub(super) attn: Attention,
    pub(super) fc: Linear,
    pub(super) mlp1: Linear,
    pub(super) mlp2: Linear,
}

impl DmaBlock {
    pub fn new(d: usize, heads: usize, ffn: usize, device: &Device) -> Self {
        DmaBlock {
            attn: Attention::new(d, heads, device),
            fc: LinearConfig::new(2 * d, d).init(device),
            mlp1: LinearConfig::new(d, ffn).init(device),
            mlp2: LinearConfig::new(ffn, d).init(device),
        }
    }

    /// `z`: [B, 1+N, d]; `blocked`: the block's [B, 1+N, 1+N] mask; `active`: per token (B x
    /// (1+N), host) whether it takes this block's update; `valid`: whether it may be attended.
    /// Inactive tokens pass through unchanged and invalid ones are never seen, so queries (and
    /// the concat-FC and MLP) run on the active rows only and keys and values on the valid rows
    /// only: early blocks with small windows, and the keyframe-free half of a guided batch, have
    /// few of either.
    pub fn forward(
        &self,
        z: Tensor<3>,
        blocked: Mask,
        active: &[bool],
        valid: &[bool],
    ) -> Tensor<3> {
        let [b, l, d] = z.dims();
        let rows = TokenRows::new(active, &z.device());
        if rows.count == 0 {
            return z;
        }
        let flat = z.reshape([b * l, d]);
        let keys = TokenRows::new(valid, &flat.device());
        let zs = rows.gather(flat.clone());
        let a = self.attn.forward_rows(flat.clone(), b, &rows, &keys, blocked);
        let zk = linear(
            &self.mlp2,
            linear_gelu(&self.mlp1, linear(&self.fc, Tensor::cat(vec![a, zs.clone()], 1))),
        );
        match &rows.index {
            None => zk.reshape([b, l, d]),
            Some(idx) => flat
                .select_assign(0, idx.clone(), zk - zs, IndexingUpdateOp::Add)
                .reshape([b, l, d]),
        }
    }
}

#[derive(Module, Debug)]
pub struct KeyframeEncoder {
    /// Keyframe values and their per-feature mask (and the root channels with theirs, when the
    /// model has them) -> d (the mask tells partial keyframes apart).
    pub(super) kf_in: Linear,
    pub(super) blocks: Vec<DmaBlock>,
    pub(super) root_channels: usize,
}

impl KeyframeEncoder {
    pub fn new(
        feat: usize,
        root_channels: usize,
        d: usize,
        heads: usize,
        ffn: usize,
        blocks: usize,
        device: &Device,
    ) -> Self {
        KeyframeEncoder {
            kf_in: LinearConfig::new(2 * (feat + root_channels), d).init(device),
            blocks: (0..blocks).map(|_| DmaBlock::new(d, heads, ffn, device)).collect(),
            root_channels,
        }
    }

    /// The observation each frame token is built from: the condition's keyframes `kf`/`kf_mask`
    /// `[B,N,D]` and the model's root channels `[B,N,R]`, each value masked, beside its mask ->
    /// [B, N, 2(D+R)]. The decoder's per-frame key input reads the same vector.
    pub fn observations(&self, c: &Condition) -> Tensor<3> {
        let mut parts = vec![c.kf.clone() * c.kf_mask.clone(), c.kf_mask.clone()];
        if self.root_channels > 0 {
            let [b, n, _] = c.root.dims();
            let r = self.root_channels;
            parts.push((c.root.clone() * c.root_mask.clone()).slice([0..b, 0..n, 0..r]));
            parts.push(c.root_mask.clone().slice([0..b, 0..n, 0..r]));
        }
        Tensor::cat(parts, 2)
    }

    /// `text_tok` `[B,1,d]`; `obs` [B,N,2(D+R)] ([`Self::observations`]); `pos` `[1,N,d]`
    /// -> [B, 1+N, d].
    pub fn forward(
        &self,
        text_tok: Tensor<3>,
        obs: Tensor<3>,
        pos: Tensor<3>,
        plan: &DmaPlan,
    ) -> Tensor<3> {
        let frames = linear(&self.kf_in, obs) + pos;
        let z0 = Tensor::cat(vec![text_tok, frames], 1);
        let mut z = z0.clone();
        for (k, block) in self.blocks.iter().enumerate() {
            z = block.forward(
                z,
                Mask::Full(plan.blocked[k].clone()),
                &plan.active[k],
                plan.valid_before(k),
            );
        }
        z + z0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dilate(keys: &[usize], real: usize, r: usize) -> Vec<bool> {
        (0..real)
            .map(|i| keys.iter().any(|&k| (k as i64 - i as i64).unsigned_abs() as usize <= r))
            .collect()
    }

    #[test]
    fn valid_region_dilates_by_the_sizes_so_far() {
        let (n, real) = (40, 33);
        let keys = [3usize, 20];
        let kf: Vec<bool> = (0..n).map(|i| keys.contains(&i)).collect();
        let re: Vec<bool> = (0..n).map(|i| i < real).collect();
        let sizes = [2, 2, 4, 0];
        let plan = DmaPlan::new(&kf, &re, 1, n, &sizes);
        let mut total = 0;
        for (k, &s) in sizes.iter().enumerate() {
            total += if s == 0 { n } else { s };
            let want = dilate(&keys, real, total);
            for (i, &w) in want.iter().enumerate().take(n) {
                let got = plan.valid_after(k)[1 + i];
                assert_eq!(got, i < real && w, "block {k} frame {i}");
            }
            assert!(plan.valid_after(k)[0], "text token always valid");
        }
    }

    #[test]
    fn no_keyframes_no_active_frames() {
        let plan = DmaPlan::new(&[false; 10], &[true; 10], 1, 10, &[2, 0]);
        for a in &plan.active {
            assert!(a[0] && a[1..].iter().all(|x| !x));
        }
        // The text query sees only itself; frame rows see only the text token.
        assert!(!plan.blocked[0][0] && plan.blocked[0][1..11].iter().all(|&x| x));
    }
}

//! Matrix-multiply FLOPs of one forward pass (2 per multiply-add), counted from the shapes of
//! our implementation, for the GFLOP/s the benchmarks report. Elementwise work, softmax and
//! normalisation are not counted (they are a few percent of the total). The keyframe encoder's
//! blocks are counted either dense ([`forward`]) or as the rows and scores their gathers leave
//! ([`forward_planned`] with `DmaPlan::work`: what the fused CPU path computes, so a rate from
//! it is never above what the machine did).

use crate::network::keyframe_encoder::BlockWork;
use crate::DiffKfcConfig;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Flops {
    /// Keyframe encoder, text projection and the decoder's cross-attention K/V of its output
    /// (computed once per condition when sampling).
    pub encoder: f64,
    /// Decoder, input/output projections and timestep embedding (every denoising step).
    pub decoder: f64,
}

impl Flops {
    pub fn total(&self) -> f64 {
        self.encoder + self.decoder
    }
}

/// Linear layer: rows x (k -> n).
fn linear(rows: usize, k: usize, n: usize) -> f64 {
    2.0 * rows as f64 * k as f64 * n as f64
}

/// Attention scores and weighted values of `b` sequences: QK^T and AV, summed over heads.
fn attend(b: usize, lq: usize, lk: usize, d: usize) -> f64 {
    2.0 * 2.0 * b as f64 * lq as f64 * lk as f64 * d as f64
}

/// One forward of `batch` motions of `frames` frames, every encoder block dense.
pub fn forward(c: &DiffKfcConfig, batch: usize, frames: usize) -> Flops {
    let dense = vec![BlockWork::dense(batch, frames + 1); c.dma_sizes.len()];
    forward_planned(c, batch, frames, &dense)
}

/// One forward with the encoder blocks' work given (`DmaPlan::work`, one entry per block).
pub fn forward_planned(
    c: &DiffKfcConfig,
    batch: usize,
    frames: usize,
    work: &[BlockWork],
) -> Flops {
    let (b, n, d, f) = (batch, frames, c.d_model, c.ffn);
    let (le, ld) = (n + 1, n + 2);
    let block = |w: &BlockWork| {
        let (q, k) = (w.queries, w.keys);
        linear(q, d, d)
            + linear(k, d, 2 * d)
            + 2.0 * 2.0 * w.scores as f64 * d as f64
            + linear(q, d, d)
            + linear(q, 2 * d, d)
            + linear(q, d, f)
            + linear(q, f, d)
    };
    // Word tokens (`text_words`): their projection and each layer's keys and values.
    let w = c.text_words;
    let encoder = linear(b, c.text_dim, d)
        + linear(b * w, c.text_dim, d)
        + c.dec_layers as f64 * linear(b * w, d, 2 * d)
        + linear(b * n, 2 * (c.feat_dim + c.root_channels), d)
        + work.iter().map(block).sum::<f64>()
        + c.dec_layers as f64 * linear(b * le, d, 2 * d);
    let word_attention = if w > 0 { 2.0 * linear(b * ld, d, d) + attend(b, ld, w, d) } else { 0.0 };
    let layer = linear(b * ld, d, 3 * d)
        + attend(b, ld, ld, d)
        + linear(b * ld, d, d)
        + linear(b * ld, d, d)
        + attend(b, ld, le, d)
        + linear(b * ld, d, d)
        + linear(b * ld, d, f)
        + linear(b * ld, f, d)
        + word_attention;
    // The extensions' per-frame projections added to the decoder's frame tokens.
    let key_in =
        if c.key_input { linear(b * n, 2 * (c.feat_dim + c.root_channels), d) } else { 0.0 };
    let decoder = linear(b * n, c.feat_dim, d)
        + key_in
        + 2.0 * linear(b, d, d)
        + c.dec_layers as f64 * layer
        + linear(b * n, d, c.feat_dim);
    Flops { encoder, decoder }
}

/// A training step with the encoder blocks' work given: forward plus backward (about twice the
/// forward: gradients with respect to both the inputs and the weights of every matmul).
pub fn train_step(c: &DiffKfcConfig, batch: usize, frames: usize, work: &[BlockWork]) -> f64 {
    3.0 * forward_planned(c, batch, frames, work).total()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cross-check against the parameter count: a linear layer's FLOPs per row are twice its
    /// weights, so without attention products, one frame token costs ~2 x (weights it passes).
    #[test]
    fn per_token_cost_matches_the_weights() {
        let c = DiffKfcConfig::paper();
        let one = forward(&c, 1, 1);
        let big = forward(&c, 1, 101);
        // Attention products grow quadratically; the rest linearly in frames.
        let d = c.d_model as f64;
        let per_frame_linear = (big.total() - one.total()) / 100.0;
        let block_weights = 4.0 * d * d + 2.0 * d * d + 2.0 * d * c.ffn as f64;
        let layer_weights = 4.0 * d * d + 2.0 * d * d + 2.0 * d * d + 2.0 * d * c.ffn as f64;
        let io = (2 * c.feat_dim) as f64 * d + 2.0 * c.feat_dim as f64 * d;
        let weights =
            c.dma_sizes.len() as f64 * block_weights + c.dec_layers as f64 * layer_weights + io;
        // Attention products add ~4 L d per layer per frame: small next to the weights.
        assert!(
            per_frame_linear > 2.0 * weights && per_frame_linear < 2.6 * weights,
            "{per_frame_linear} vs {weights}"
        );
        // Paper decoder at batch 2 x 196 frames, by hand: 396 tokens x 8 layers x 2 x 2.62 M
        // weights = 16.6 GFLOP, attention products 8 x 0.32 = 2.6, input/output 0.2: 19.4.
        let dec = forward(&c, 2, 196).decoder / 1e9;
        assert!((dec - 19.4).abs() < 0.1, "{dec}");
    }

    /// The per-frame key input costs twice its weights per frame, the weights
    /// counted on the built model (its parameter count less the base model's, less the bias).
    #[test]
    fn key_input_costs_its_projection() {
        use burn::prelude::*;
        let dev = Device::flex();
        let base = DiffKfcConfig::tiny();
        let params = |c: &DiffKfcConfig| c.init(&dev).num_params() as f64;
        let d = base.d_model as f64;
        let grown = base.clone().with_key_input(true);
        let weights = params(&grown) - params(&base) - d;
        let per_frame =
            |c: &DiffKfcConfig| (forward(c, 1, 11).total() - forward(c, 1, 1).total()) / 10.0;
        let added = per_frame(&grown) - per_frame(&base);
        assert!((added - 2.0 * weights).abs() < 1e-6 * added, "{added} vs 2 x {weights}");
    }

    /// With no keyframe each block updates only the text token and attends only to it: the
    /// encoder's blocks shrink to one row per sample, counted by hand for the tiny config.
    #[test]
    fn planned_count_follows_the_gathers() {
        let c = DiffKfcConfig::tiny();
        let (b, n) = (2, 40);
        let plan = crate::network::keyframe_encoder::DmaPlan::new(
            &vec![false; b * n],
            &vec![true; b * n],
            b,
            n,
            &c.dma_sizes,
        );
        let work = plan.work(false);
        let l = n + 1;
        for w in &work {
            assert_eq!(*w, BlockWork { queries: b, keys: b, scores: b * l });
        }
        // The sampling path's encoder scores the text query alone.
        for w in &plan.work(true) {
            assert_eq!(*w, BlockWork { queries: b, keys: b, scores: b });
        }
        let (d, f) = (c.d_model as f64, c.ffn as f64);
        let rows = b as f64;
        let per_block = 2.0 * rows * (d * d + 2.0 * d * d + d * d + 2.0 * d * d + 2.0 * d * f)
            + 4.0 * (b * l) as f64 * d;
        let saved = forward(&c, b, n).encoder - forward_planned(&c, b, n, &work).encoder;
        let dense_block =
            2.0 * (b * l) as f64 * (6.0 * d * d + 2.0 * d * f) + 4.0 * (b * l * l) as f64 * d;
        let want = c.dma_sizes.len() as f64 * (dense_block - per_block);
        assert!((saved - want).abs() < 1e-6 * want, "{saved} vs {want}");
        // Every frame a keyframe: nothing to gather, the dense count.
        let all = crate::network::keyframe_encoder::DmaPlan::new(
            &vec![true; b * n],
            &vec![true; b * n],
            b,
            n,
            &c.dma_sizes,
        );
        for query_rows in [false, true] {
            assert_eq!(forward_planned(&c, b, n, &all.work(query_rows)), forward(&c, b, n));
        }
    }
}

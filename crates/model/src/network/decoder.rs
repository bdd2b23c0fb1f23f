//! The denoising decoder: L layers of self-attention over [y_t, y_c, frame tokens],
//! cross-attention to the keyframe encoder's output (keys masked to valid tokens), and a
//! feed-forward block; post-norm residuals as in MDM. With `model.temporal_kernel` > 0 a
//! depthwise convolution over the frames joins the self-attention's residual ([`TemporalConv`]);
//! with `model.text_words` > 0 an attention to the text's word states follows the
//! cross-attention (`crate::network::words`).

use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::prelude::*;

use crate::kernels::{linear, linear_gelu_dropout, residual_layer_norm, Mask};
use crate::network::attention::Attention;
use crate::network::dropout::Dropout;
use crate::network::temporal::{RealFrames, TemporalConv};

#[derive(Module, Debug)]
pub struct DecoderLayer {
    pub(super) self_attn: Attention,
    pub(super) cross_attn: Attention,
    pub(super) ff1: Linear,
    pub(super) ff2: Linear,
    pub(super) ln1: LayerNorm,
    pub(super) ln2: LayerNorm,
    pub(super) ln3: LayerNorm,
    drop: Dropout,
    /// Last, so that layers without it visit their parameters as before (old checkpoints).
    pub(super) temporal: Option<TemporalConv>,
    /// Attention to the word tokens, zero output at first (after `temporal`, for the same reason).
    pub(super) words: Option<Attention>,
}

/// A decoder layer's word keys and values ([B, W, d] each) and the word padding.
pub type WordKeys<'a> = (&'a (Tensor<3>, Tensor<3>), &'a Mask);

impl DecoderLayer {
    /// `temporal_kernel` 0: no temporal convolution (the paper); `words`: attend to word tokens.
    pub fn new(
        d: usize,
        heads: usize,
        ffn: usize,
        dropout: f64,
        temporal_kernel: usize,
        words: bool,
        device: &Device,
    ) -> Self {
        DecoderLayer {
            self_attn: Attention::new(d, heads, device),
            cross_attn: Attention::new(d, heads, device),
            ff1: LinearConfig::new(d, ffn).init(device),
            ff2: LinearConfig::new(ffn, d).init(device),
            ln1: LayerNormConfig::new(d).init(device),
            ln2: LayerNormConfig::new(d).init(device),
            ln3: LayerNormConfig::new(d).init(device),
            drop: Dropout::new(dropout),
            temporal: (temporal_kernel > 0).then(|| TemporalConv::new(temporal_kernel, d, device)),
            words: words.then(|| Attention::zero_output(d, heads, device)),
        }
    }

    /// The word attention's keys and values of the word tokens [B, W, d] (None without one).
    pub fn word_kv(&self, tokens: Tensor<3>) -> Option<(Tensor<3>, Tensor<3>)> {
        self.words.as_ref().map(|a| a.keys_values(tokens))
    }

    /// The cross-attention keys and values of the encoder output (fixed across denoising steps).
    pub fn cross_kv(&self, enc: Tensor<3>) -> (Tensor<3>, Tensor<3>) {
        self.cross_attn.keys_values(enc)
    }

    /// `h` [B, 2+N, d] with `self_pad` (key padding of the decoder sequence); `enc_kv` from
    /// [`cross_kv`] with `enc_pad` (encoder tokens that are not valid keys); `real`: which
    /// frames are real; `words`: this layer's word keys (models with word tokens) -> [B, 2+N, d].
    pub fn forward(
        &self,
        h: Tensor<3>,
        self_pad: Mask,
        enc_kv: &(Tensor<3>, Tensor<3>),
        enc_pad: Mask,
        real: &RealFrames,
        words: Option<WordKeys>,
    ) -> Tensor<3> {
        let mut a = self.self_attn.forward(h.clone(), h.clone(), self_pad);
        if let Some(conv) = &self.temporal {
            a = a + conv.forward_tokens(h.clone(), real, 2);
        }
        let h = residual_layer_norm(&self.ln1, h, a, &self.drop);
        let c = self.cross_attn.forward_kv(h.clone(), enc_kv, enc_pad);
        let mut h = residual_layer_norm(&self.ln2, h, c, &self.drop);
        // A plain residual: with its zero output the branch leaves the layer as it was.
        if let (Some(att), Some((kv, pad))) = (&self.words, words) {
            h = h.clone() + self.drop.forward(att.forward_kv(h, kv, pad.clone()));
        }
        let f = linear(&self.ff2, linear_gelu_dropout(&self.ff1, h.clone(), &self.drop));
        residual_layer_norm(&self.ln3, h, f, &self.drop)
    }
}

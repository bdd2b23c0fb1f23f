//! Word-level text conditioning (`model.text_words`, our extension): the decoder's tokens also
//! attend to the text encoder's per-token states. MiniLM's pooled sentence vector reads
//! "kneels down, then sprints ahead" and its swapped twin alike (cosine 0.99), so the order of
//! two actions cannot reach the network through it; the word states keep it. Each decoder
//! layer's attention to the words starts with a zero output projection, so a model grown from
//! one without words (`--init`) starts as that model.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::kernels::{key_mask, linear, Mask};
use crate::network::params::host;
use crate::network::sinusoidal::positions;

/// The model's text input [B, text_dim * (1 + W)] as the pooled embedding [B, text_dim] and,
/// for W > 0, the word states [B, W, text_dim] (`TextEncoder::embed_words`'s layout).
pub fn split(text: Tensor<2>, text_dim: usize, words: usize) -> (Tensor<2>, Option<Tensor<3>>) {
    if words == 0 {
        return (text, None);
    }
    let b = text.dims()[0];
    let pooled = text.clone().slice([0..b, 0..text_dim]);
    let states = text.slice([0..b, text_dim..text_dim * (1 + words)]).reshape([b, words, text_dim]);
    (pooled, Some(states))
}

/// `[B * W]` word slots that are not keys (true): the zero rows past a text's tokens. Slot 0
/// always stays a key, so a dropped text (all zero) still attends somewhere (to a constant).
pub fn padding(text: &[f32], b: usize, text_dim: usize, words: usize) -> Vec<bool> {
    let width = text_dim * (1 + words);
    assert_eq!(text.len(), b * width, "text input [B, text_dim * (1 + W)]");
    (0..b * words)
        .map(|k| {
            let (s, w) = (k / words, k % words);
            let at = s * width + text_dim * (1 + w);
            w > 0 && text[at..at + text_dim].iter().all(|&v| v == 0.0)
        })
        .collect()
}

/// The word states' projection to the decoder's width, with sinusoidal slot positions.
#[derive(Module, Debug)]
pub struct WordInput {
    pub(super) proj: Linear,
    /// sqrt(text_dim): the states are unit vectors, each element about 1/sqrt(text_dim); at
    /// that scale their projection was about 0.04 against the positions' 0.7, and the words'
    /// attention read their slots rather than their words. No parameters.
    pub(super) scale: f32,
}

impl WordInput {
    pub fn new(text_dim: usize, d: usize, device: &Device) -> Self {
        WordInput {
            proj: LinearConfig::new(text_dim, d).init(device),
            scale: (text_dim as f32).sqrt(),
        }
    }

    /// Word states [B, W, text_dim] -> word tokens [B, W, d].
    pub fn forward(&self, states: Tensor<3>) -> Tensor<3> {
        let [_, w, _] = states.dims();
        let y = linear(&self.proj, states.mul_scalar(self.scale));
        let d = y.dims()[2];
        y + positions(w, d, &self.proj.weight.device())
    }
}

/// The words as every decoder layer's attention reads them: per layer keys and values
/// [B, W, d], and the padding slots. Computed once per condition.
#[derive(Clone, Debug)]
pub struct WordMemory {
    pub kv: Vec<(Tensor<3>, Tensor<3>)>,
    pub pad: Mask,
}

impl WordMemory {
    /// `kv` of the word tokens per layer; the padding read from the text input [B, width].
    pub fn new(kv: Vec<(Tensor<3>, Tensor<3>)>, text: &Tensor<2>, text_dim: usize) -> Self {
        let [b, width] = text.dims();
        let words = width / text_dim - 1;
        WordMemory { kv, pad: key_mask(padding(&host(text.clone()), b, text_dim, words)) }
    }

    pub fn detach(self) -> Self {
        WordMemory {
            kv: self.kv.into_iter().map(|(k, v)| (k.detach(), v.detach())).collect(),
            pad: self.pad,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_and_padding_follow_the_layout() {
        let dev = Device::flex();
        let (td, w) = (3, 2);
        // Sample 0: pooled, one word, then a zero row; sample 1: dropped (all zero).
        let mut v = vec![1.0, 2.0, 3.0, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0];
        v.extend([0.0; 9]);
        let t = Tensor::<1>::from_floats(v.as_slice(), &dev).reshape([2, td * (1 + w)]);
        let (pooled, states) = split(t, td, w);
        assert_eq!(host(pooled), vec![1.0, 2.0, 3.0, 0.0, 0.0, 0.0]);
        let states = states.unwrap();
        assert_eq!(states.dims(), [2, w, td]);
        assert_eq!(&host(states)[..3], &[0.5, 0.5, 0.5]);
        assert_eq!(padding(&v, 2, td, w), vec![false, true, false, true]);
        let (same, none) = split(Tensor::<2>::zeros([2, td], &dev), td, 0);
        assert!(none.is_none() && same.dims() == [2, td]);
    }
}

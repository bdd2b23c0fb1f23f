//! The DiffKFC denoiser X_theta(x_t, keyframes, text, t) -> x0, with the keyframe encoder
//! callable once per sample and reused at every denoising step (it does not see t).

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::kernels::{key_mask, linear, Mask};
use crate::network::condition::Condition;
use crate::network::config::DiffKfcConfig;
use crate::network::decoder::DecoderLayer;
use crate::network::keyframe_encoder::{DmaPlan, KeyframeEncoder};
use crate::network::sinusoidal::{positions, TimestepEmbed};
use crate::network::temporal::RealFrames;
use crate::network::words::{self, WordInput, WordMemory};

/// The encoder's output for a condition, reused across denoising steps.
#[derive(Clone, Debug)]
pub struct Encoded {
    /// [B, 1+N, d]
    pub tokens: Tensor<3>,
    /// Per decoder layer: cross-attention keys and values of `tokens` ([B, 1+N, d] each).
    pub cross_kv: Vec<(Tensor<3>, Tensor<3>)>,
    /// [B, 1+N] keys the decoder must not attend (never-valid tokens, padding).
    pub key_pad: Mask,
    /// [B, 1, d] text token y_c.
    pub text_tok: Tensor<3>,
    /// [B, 2+N] padding tokens of the decoder sequence.
    pub self_pad: Mask,
    /// [1, N, d] frame position encodings (computed once, not per step).
    pub pos: Tensor<3>,
    /// Which decoder tokens are real (what the temporal convolution may read).
    pub real: RealFrames,
    /// [B, N, d] each frame's own keyframe observation (`KeyframeEncoder::observations`),
    /// embedded (models with key input).
    pub key: Option<Tensor<3>>,
    /// The text's word tokens as each decoder layer attends to them (models with `text_words`).
    pub words: Option<WordMemory>,
}

impl Encoded {
    /// Every tensor detached from the autodiff graph: reused across denoising steps, none of
    /// them may be reached by a step's backward pass (exact transition guidance differentiates
    /// each step with respect to x_t alone; a second backward through a shared tensor would
    /// find its graph consumed).
    pub fn detach(self) -> Encoded {
        Encoded {
            tokens: self.tokens.detach(),
            cross_kv: self.cross_kv.into_iter().map(|(k, v)| (k.detach(), v.detach())).collect(),
            text_tok: self.text_tok.detach(),
            pos: self.pos.detach(),
            key: self.key.map(Tensor::detach),
            words: self.words.map(WordMemory::detach),
            ..self
        }
    }
}

#[derive(Module, Debug)]
pub struct Denoiser {
    pub(super) x_in: Linear,
    pub(super) text_in: Linear,
    pub(super) time: TimestepEmbed,
    pub(super) encoder: KeyframeEncoder,
    pub(super) layers: Vec<DecoderLayer>,
    pub(super) out: Linear,
    pub(super) d_model: usize,
    pub(super) dma_sizes: Vec<usize>,
    /// The per-frame keyframe input's projection (last, so positional checkpoints of models
    /// without it are a prefix of its parameters).
    pub(super) key_in: Option<Linear>,
    /// The word states' projection (models with `text_words`; last, like `key_in`).
    pub(super) word_in: Option<WordInput>,
    /// Width of the pooled text embedding and word states per text (`text_dim`, `text_words`).
    /// No parameters.
    pub(super) text_dim: usize,
    pub(super) text_words: usize,
}

impl DiffKfcConfig {
    pub fn init(&self, device: &Device) -> Denoiser {
        let d = self.d_model;
        Denoiser {
            x_in: LinearConfig::new(self.feat_dim, d).init(device),
            text_in: LinearConfig::new(self.text_dim, d).init(device),
            time: TimestepEmbed::new(d, device),
            encoder: KeyframeEncoder::new(
                self.feat_dim,
                self.root_channels,
                d,
                self.heads,
                self.ffn,
                self.dma_sizes.len(),
                device,
            ),
            layers: (0..self.dec_layers)
                .map(|_| {
                    DecoderLayer::new(
                        d,
                        self.heads,
                        self.ffn,
                        self.dropout,
                        self.temporal_kernel,
                        self.text_words > 0,
                        device,
                    )
                })
                .collect(),
            out: LinearConfig::new(d, self.feat_dim).init(device),
            d_model: d,
            dma_sizes: self.dma_sizes.clone(),
            key_in: self.key_input.then(|| {
                LinearConfig::new(2 * (self.feat_dim + self.root_channels), d)
                    .with_initializer(burn::nn::Initializer::Zeros)
                    .init(device)
            }),
            word_in: (self.text_words > 0).then(|| WordInput::new(self.text_dim, d, device)),
            text_dim: self.text_dim,
            text_words: self.text_words,
        }
    }
}

/// Keys of the decoder's sequence [B * (2 + N)] that are padding (time and text tokens, then
/// the frames; `real` [B * N]).
pub fn self_padding(real: &[bool], b: usize, n: usize) -> Mask {
    let l = n + 2;
    key_mask((0..b * l).map(|k| k % l >= 2 && !real[k / l * n + k % l - 2]).collect())
}

impl Denoiser {
    /// Run the keyframe encoder and the decoder's cross-attention projections of its output
    /// (once per condition).
    pub fn encode(&self, c: &Condition) -> Encoded {
        let device = c.kf.device();
        let [b, n, _] = c.kf.dims();
        let (pooled, word_states) = words::split(c.text.clone(), self.text_dim, self.text_words);
        let text_tok = linear(&self.text_in, pooled).unsqueeze_dim::<3>(1);
        let words = self.word_in.as_ref().zip(word_states).map(|(wi, states)| {
            let tokens = wi.forward(states);
            let kv = self.layers.iter().filter_map(|l| l.word_kv(tokens.clone())).collect();
            WordMemory::new(kv, &c.text, self.text_dim)
        });
        let plan = DmaPlan::new(&c.kf_frames, &c.real, b, n, &self.dma_sizes);
        let pos = positions(n, self.d_model, &device);
        let obs = self.encoder.observations(c);
        let key = self.key_in.as_ref().map(|l| linear(l, obs.clone()));
        let tokens = self.encoder.forward(text_tok.clone(), obs, pos.clone(), &plan);
        let key_pad = plan.final_valid().iter().map(|v| !v).collect();
        let cross_kv = self.layers.iter().map(|l| l.cross_kv(tokens.clone())).collect();
        Encoded {
            words,
            key,
            real: RealFrames::new(&c.real, b, n, &device),
            cross_kv,
            tokens,
            key_pad: key_mask(key_pad),
            text_tok,
            self_pad: self_padding(&c.real, b, n),
            pos,
        }
    }

    /// Predict x0 from x_t [B, N, D] at timesteps `t` (one per sample) -> [B, N, D]; the decoder
    /// runs on [B, 2 + N, d] (time and text tokens, then the frames).
    pub fn decode(&self, x_t: Tensor<3>, t: &[usize], e: &Encoded) -> Tensor<3> {
        let device = x_t.device();
        let [b, n, _] = x_t.dims();
        let mut frames = linear(&self.x_in, x_t) + e.pos.clone();
        if let Some(k) = &e.key {
            frames = frames + k.clone();
        }
        let y_t = self.time.forward(t, &device);
        let mut h = Tensor::cat(vec![y_t, e.text_tok.clone(), frames], 1);
        for (i, (layer, kv)) in self.layers.iter().zip(&e.cross_kv).enumerate() {
            let w = e.words.as_ref().map(|m| (&m.kv[i], &m.pad));
            h = layer.forward(h, e.self_pad.clone(), kv, e.key_pad.clone(), &e.real, w);
        }
        let d = self.d_model;
        linear(&self.out, h.slice([0..b, 2..n + 2, 0..d]))
    }

    pub fn forward(&self, x_t: Tensor<3>, t: &[usize], c: &Condition) -> Tensor<3> {
        self.decode(x_t, t, &self.encode(c))
    }

    /// Parameter counts: (keyframe encoder, decoder and the rest, total).
    pub fn param_counts(&self) -> Vec<(&'static str, usize)> {
        let enc = self.encoder.num_params();
        let dec: usize = self.layers.iter().map(|l| l.num_params()).sum();
        let emb = self.x_in.num_params()
            + self.text_in.num_params()
            + self.time.num_params()
            + self.out.num_params()
            + self.key_in.as_ref().map_or(0, |l| l.num_params())
            + self.word_in.as_ref().map_or(0, |l| l.num_params());
        vec![
            ("keyframe encoder (DMA)", enc),
            ("decoder layers", dec),
            ("input/output/timestep/text projections", emb),
            ("total", self.num_params()),
        ]
    }
}

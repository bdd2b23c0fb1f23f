//! A text-motion evaluator trained contrastively on the training split (the official T2M
//! evaluator weights cannot be downloaded here). Motion encoder: features without foot
//! contacts, two strided temporal convolutions (x4 downsampling), a small transformer, masked
//! mean pooling, Linear -> 512. Text encoder: the frozen MiniLM embedding through an MLP -> 512.
//! Trained with a symmetric InfoNCE loss; embeddings are L2-normalised and scaled so that
//! Euclidean distances stay in the range the metrics were designed for.

use burn::nn::conv::{Conv1d, Conv1dConfig};
use burn::nn::{LayerNorm, LayerNormConfig, Linear, LinearConfig, PaddingConfig1d};
use burn::prelude::*;
use burn::tensor::activation::{gelu, log_softmax};
use diffkfc_model::kernels::{key_mask, layer_norm, linear, linear_gelu};
use diffkfc_model::network::attention::Attention;

use crate::error::{EvalError, Result};

/// Width of the shared embedding space.
pub const EMBED: usize = 512;
/// Scale of the unit-norm embeddings (distances of true pairs land near MDM's ~3-5 range).
pub const SCALE: f64 = 4.0;

#[derive(Config, Debug)]
pub struct EvaluatorConfig {
    /// Motion feature width (the dataset's minus the 4 foot contacts).
    #[config(default = 259)]
    pub motion_dim: usize,
    #[config(default = 384)]
    pub text_dim: usize,
    #[config(default = 256)]
    pub hidden: usize,
    #[config(default = 2)]
    pub layers: usize,
    #[config(default = 4)]
    pub heads: usize,
    #[config(default = 0.07)]
    pub temperature: f64,
}

#[derive(Module, Debug)]
struct Block {
    attn: Attention,
    ln1: LayerNorm,
    ff1: Linear,
    ff2: Linear,
    ln2: LayerNorm,
}

#[derive(Module, Debug)]
pub struct Evaluator {
    conv1: Conv1d,
    conv2: Conv1d,
    blocks: Vec<Block>,
    motion_out: Linear,
    text1: Linear,
    text2: Linear,
}

impl EvaluatorConfig {
    pub fn init(&self, device: &Device) -> Evaluator {
        let h = self.hidden;
        let conv = |i: usize, o: usize| {
            Conv1dConfig::new(i, o, 4)
                .with_stride(2)
                .with_padding(PaddingConfig1d::Explicit(1, 1))
                .init(device)
        };
        Evaluator {
            conv1: conv(self.motion_dim, h),
            conv2: conv(h, h),
            blocks: (0..self.layers)
                .map(|_| Block {
                    attn: Attention::new(h, self.heads, device),
                    ln1: LayerNormConfig::new(h).init(device),
                    ff1: LinearConfig::new(h, 2 * h).init(device),
                    ff2: LinearConfig::new(2 * h, h).init(device),
                    ln2: LayerNormConfig::new(h).init(device),
                })
                .collect(),
            motion_out: LinearConfig::new(h, EMBED).init(device),
            text1: LinearConfig::new(self.text_dim, EMBED).init(device),
            text2: LinearConfig::new(EMBED, EMBED).init(device),
        }
    }
}

fn normalise(x: Tensor<2>) -> Tensor<2> {
    let n = x.clone().powf_scalar(2.0).sum_dim(1).sqrt().clamp_min(1e-8);
    x / n * SCALE
}

impl Evaluator {
    /// Motions [B, N, Dm] (normalised, no foot contacts) with lengths -> [B, 512].
    pub fn encode_motion(&self, x: Tensor<3>, lengths: &[usize]) -> Tensor<2> {
        let device = x.device();
        let h = gelu(self.conv1.forward(x.swap_dims(1, 2)));
        let h = gelu(self.conv2.forward(h)).swap_dims(1, 2); // [B, N/4, H]
        let [b, n4, hid] = h.dims();
        // Valid downsampled steps: ceil(len / 4), at least one.
        let valid: Vec<bool> =
            lengths.iter().flat_map(|&l| (0..n4).map(move |i| i < l.div_ceil(4).max(1))).collect();
        let pad = key_mask(valid.iter().map(|v| !v).collect());
        let mut h = h;
        for blk in &self.blocks {
            let a = blk.attn.forward(h.clone(), h.clone(), pad.clone());
            h = layer_norm(&blk.ln1, h + a);
            let f = linear(&blk.ff2, linear_gelu(&blk.ff1, h.clone()));
            h = layer_norm(&blk.ln2, h + f);
        }
        let w = Tensor::<1>::from_floats(
            valid.iter().map(|&v| v as i32 as f32).collect::<Vec<_>>().as_slice(),
            &device,
        )
        .reshape([b, n4, 1]);
        let pooled = (h * w.clone()).sum_dim(1).reshape([b, hid]) / w.sum_dim(1).reshape([b, 1]);
        normalise(linear(&self.motion_out, pooled))
    }

    /// Frozen text embeddings [B, text_dim] -> [B, 512].
    pub fn encode_text(&self, t: Tensor<2>) -> Tensor<2> {
        normalise(linear(&self.text2, linear_gelu(&self.text1, t)))
    }
}

/// Symmetric InfoNCE over a batch of paired embeddings (cosine similarity / temperature).
/// Pairs with the same caption are not negatives of each other: `same[i*B+j]` marks them.
pub fn info_nce(m: Tensor<2>, t: Tensor<2>, temperature: f64, same: &[bool]) -> Tensor<1> {
    let [b, _] = m.dims();
    let device = m.device();
    let logits = m.matmul(t.transpose()) / (SCALE * SCALE * temperature);
    // Other pairs with an identical caption are masked out of the denominators.
    let off: Vec<f32> =
        (0..b * b).map(|k| if same[k] && k / b != k % b { -1e4 } else { 0.0 }).collect();
    let logits = logits + Tensor::<1>::from_floats(off.as_slice(), &device).reshape([b, b]);
    let eye: Vec<f32> = (0..b * b).map(|k| (k / b == k % b) as i32 as f32).collect();
    let eye = Tensor::<1>::from_floats(eye.as_slice(), &device).reshape([b, b]);
    let l1 = -(log_softmax(logits.clone(), 1) * eye.clone()).sum() / b as f64;
    let l2 = -(log_softmax(logits.transpose(), 1) * eye).sum() / b as f64;
    (l1 + l2) / 2.0
}

/// Frames of a clip the evaluator sees: the first 196, rounded down to a multiple of 4 (its
/// convolutions downsample by 4), as T2M's evaluation loader does.
pub fn eval_length(len: usize) -> usize {
    let u = diffkfc_data::dataset::UNIT_LENGTH;
    (len.min(diffkfc_data::dataset::MAX_FRAMES) / u * u).max(u)
}

/// What the text-motion metrics need from an evaluator: embeddings in one shared space.
/// Implemented by our contrastive evaluator; a converted official T2M evaluator would be another.
pub trait TextMotionEvaluator {
    /// Raw (de-normalised) motions, each [len, D] with len a multiple of 4 -> one row each.
    fn embed_motions(&self, motions: &[&[f32]]) -> Vec<Vec<f64>>;
    /// Captions -> one row each.
    fn embed_texts(&self, captions: &[&str]) -> Result<Vec<Vec<f64>>>;
    /// Width of the raw motion features it reads (foot contacts included).
    fn feature_dim(&self) -> usize;
    /// Which evaluator this is, as the reports name it.
    fn name(&self) -> String;
}

/// The trained contrastive evaluator with the normalisation it was trained with.
pub struct ContrastiveEvaluator<'a> {
    pub model: Evaluator,
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
    pub text: &'a diffkfc_model::text::cache::EmbeddingCache,
    pub device: Device,
}

/// Motion input of the evaluator: normalised features [B, N, D] (row-major) without the 4 foot
/// contacts -> [B, N, D - 4].
pub fn motion_tensor(x: &[f32], b: usize, n: usize, d: usize, device: &Device) -> Tensor<3> {
    Tensor::<1>::from_floats(x, device).reshape([b, n, d]).slice([0..b, 0..n, 0..d - 4])
}

/// Text input of the evaluator: the cached frozen embeddings of `captions` -> [B, text_dim].
pub fn text_tensor(
    cache: &diffkfc_model::text::cache::EmbeddingCache,
    captions: &[&str],
    device: &Device,
) -> Result<Tensor<2>> {
    let mut v = Vec::with_capacity(captions.len() * cache.dim);
    for c in captions {
        v.extend_from_slice(
            cache.get(c).ok_or_else(|| EvalError::CaptionNotEmbedded(c.to_string()))?,
        );
    }
    Ok(Tensor::<1>::from_floats(v.as_slice(), device).reshape([captions.len(), cache.dim]))
}

/// Rows of a [B, 512] tensor as f64 vectors.
fn rows(t: Tensor<2>) -> Vec<Vec<f64>> {
    diffkfc_model::network::params::host(t)
        .chunks(EMBED)
        .map(|r| r.iter().map(|&x| x as f64).collect())
        .collect()
}

impl<'a> ContrastiveEvaluator<'a> {
    /// Load the newest checkpoint of `diffkfc eval train-evaluator --out DIR`.
    pub fn load(
        dir: &std::path::Path,
        text: &'a diffkfc_model::text::cache::EmbeddingCache,
        device: &Device,
    ) -> Result<Self> {
        let mut ck =
            diffkfc_model::run::checkpoint::Checkpoint::latest(dir).ok_or_else(|| {
                EvalError::file(
                    dir,
                    "no evaluator checkpoint (run `diffkfc eval train-evaluator` first)",
                )
            })??;
        let cfg: EvaluatorConfig = serde_json::from_str(&ck.config)
            .map_err(|e| EvalError::file(dir, format!("evaluator config: {e}")))?;
        if cfg.text_dim != text.dim {
            return Err(EvalError::file(
                dir,
                format!(
                    "evaluator expects {}-d text embeddings, the text encoder gives {}",
                    cfg.text_dim, text.dim
                ),
            ));
        }
        let read = |n: &str| diffkfc_data::io::npy::read_f32(dir.join(n)).map(|a| a.data);
        let (mean, std) = (read("Mean.npy")?, read("Std.npy")?);
        if mean.len() != cfg.motion_dim + 4 || std.len() != mean.len() {
            return Err(EvalError::file(
                dir,
                format!(
                    "Mean/Std have {} values, the evaluator expects {}",
                    mean.len(),
                    cfg.motion_dim + 4
                ),
            ));
        }
        let model = cfg.init(device);
        ck.align(&diffkfc_model::network::params::names(&model), dir)?;
        Ok(ContrastiveEvaluator {
            model: diffkfc_model::network::params::load(model, &ck.model),
            mean,
            std,
            text,
            device: device.clone(),
        })
    }
}

impl TextMotionEvaluator for ContrastiveEvaluator<'_> {
    fn embed_motions(&self, motions: &[&[f32]]) -> Vec<Vec<f64>> {
        let d = self.mean.len();
        let mut out = Vec::with_capacity(motions.len());
        for chunk in motions.chunks(32) {
            let n = chunk.iter().map(|m| m.len() / d).max().unwrap_or(1).max(4);
            let mut x = vec![0f32; chunk.len() * n * d];
            for (k, m) in chunk.iter().enumerate() {
                let dst = &mut x[k * n * d..k * n * d + m.len()];
                dst.copy_from_slice(m);
                diffkfc_data::dataset::normalise(dst, &self.mean, &self.std);
            }
            let lengths: Vec<usize> = chunk.iter().map(|m| m.len() / d).collect();
            out.extend(rows(
                self.model
                    .encode_motion(motion_tensor(&x, chunk.len(), n, d, &self.device), &lengths),
            ));
        }
        out
    }

    fn embed_texts(&self, captions: &[&str]) -> Result<Vec<Vec<f64>>> {
        let mut out = Vec::with_capacity(captions.len());
        for chunk in captions.chunks(256) {
            out.extend(rows(self.model.encode_text(text_tensor(self.text, chunk, &self.device)?)));
        }
        Ok(out)
    }

    fn feature_dim(&self) -> usize {
        self.mean.len()
    }

    fn name(&self) -> String {
        "diffkfc's contrastive evaluator (trained on the dataset; not comparable with published numbers)".into()
    }
}

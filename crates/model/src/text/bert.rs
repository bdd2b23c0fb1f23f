//! A BERT encoder (embeddings, post-norm transformer layers with exact GELU) loaded from
//! Hugging Face safetensors. Inference only: it is frozen.

use std::path::Path;

use burn::module::Param;
use burn::nn::{Embedding, LayerNorm, LayerNormConfig, Linear};
use burn::prelude::*;
use burn::tensor::activation::{gelu, softmax};
use safetensors::SafeTensors;

use super::TextError;

#[derive(serde::Deserialize, Debug, Clone)]
pub struct BertConfig {
    pub hidden_size: usize,
    pub num_attention_heads: usize,
    pub num_hidden_layers: usize,
    pub intermediate_size: usize,
    pub layer_norm_eps: f64,
}

#[derive(Module, Debug)]
struct BertLayer {
    query: Linear,
    key: Linear,
    value: Linear,
    attn_out: Linear,
    ln_attn: LayerNorm,
    inter: Linear,
    out: Linear,
    ln_out: LayerNorm,
}

#[derive(Module, Debug)]
pub struct Bert {
    word: Embedding,
    position: Embedding,
    token_type: Embedding,
    ln_emb: LayerNorm,
    layers: Vec<BertLayer>,
    heads: usize,
}

/// Reads named tensors out of a safetensors file.
struct Weights<'a> {
    st: SafeTensors<'a>,
    path: &'a Path,
    device: Device,
}

impl Weights<'_> {
    fn get(&self, name: &str) -> Result<(Vec<f32>, Vec<usize>), TextError> {
        let bad = |msg: String| TextError::Bad { path: self.path.to_path_buf(), msg };
        let t = self.st.tensor(name).map_err(|_| bad(format!("tensor '{name}' missing")))?;
        if t.dtype() != safetensors::Dtype::F32 {
            return Err(bad(format!("tensor '{name}' is {:?}, expected F32", t.dtype())));
        }
        Ok((crate::run::checkpoint::f32s(t.data()), t.shape().to_vec()))
    }

    fn tensor<const D: usize>(&self, name: &str) -> Result<Tensor<D>, TextError> {
        let (data, shape) = self.get(name)?;
        let shape: [usize; D] = shape.try_into().map_err(|_| TextError::Bad {
            path: self.path.to_path_buf(),
            msg: format!("tensor '{name}' has the wrong rank"),
        })?;
        Ok(Tensor::<1>::from_floats(data.as_slice(), &self.device).reshape(shape))
    }

    /// A PyTorch Linear ([out, in] weight) as a Burn Linear ([in, out]).
    fn linear(&self, prefix: &str) -> Result<Linear, TextError> {
        let w: Tensor<2> = self.tensor(&format!("{prefix}.weight"))?;
        let b: Tensor<1> = self.tensor(&format!("{prefix}.bias"))?;
        Ok(Linear { weight: Param::from_tensor(w.transpose()), bias: Some(Param::from_tensor(b)) })
    }

    fn layer_norm(&self, prefix: &str, eps: f64) -> Result<LayerNorm, TextError> {
        let gamma: Tensor<1> = self.tensor(&format!("{prefix}.weight"))?;
        let mut ln = LayerNormConfig::new(gamma.dims()[0]).with_epsilon(eps).init(&self.device);
        ln.gamma = Param::from_tensor(gamma);
        ln.beta = Some(Param::from_tensor(self.tensor(&format!("{prefix}.bias"))?));
        Ok(ln)
    }

    fn embedding(&self, name: &str) -> Result<Embedding, TextError> {
        Ok(Embedding { weight: Param::from_tensor(self.tensor(name)?) })
    }
}

impl Bert {
    pub fn load(safetensors: &Path, cfg: &BertConfig, device: &Device) -> Result<Bert, TextError> {
        let bytes = std::fs::read(safetensors)
            .map_err(|e| TextError::Bad { path: safetensors.to_path_buf(), msg: e.to_string() })?;
        let st = SafeTensors::deserialize(&bytes)
            .map_err(|e| TextError::Bad { path: safetensors.to_path_buf(), msg: e.to_string() })?;
        let w = Weights { st, path: safetensors, device: device.clone() };
        let eps = cfg.layer_norm_eps;
        let layers = (0..cfg.num_hidden_layers)
            .map(|i| {
                let p = format!("encoder.layer.{i}");
                Ok(BertLayer {
                    query: w.linear(&format!("{p}.attention.self.query"))?,
                    key: w.linear(&format!("{p}.attention.self.key"))?,
                    value: w.linear(&format!("{p}.attention.self.value"))?,
                    attn_out: w.linear(&format!("{p}.attention.output.dense"))?,
                    ln_attn: w.layer_norm(&format!("{p}.attention.output.LayerNorm"), eps)?,
                    inter: w.linear(&format!("{p}.intermediate.dense"))?,
                    out: w.linear(&format!("{p}.output.dense"))?,
                    ln_out: w.layer_norm(&format!("{p}.output.LayerNorm"), eps)?,
                })
            })
            .collect::<Result<Vec<_>, TextError>>()?;
        Ok(Bert {
            word: w.embedding("embeddings.word_embeddings.weight")?,
            position: w.embedding("embeddings.position_embeddings.weight")?,
            token_type: w.embedding("embeddings.token_type_embeddings.weight")?,
            ln_emb: w.layer_norm("embeddings.LayerNorm", eps)?,
            layers,
            heads: cfg.num_attention_heads,
        })
    }

    /// Hidden states [B, L, H] of token ids [B, L] with attention mask [B, L] (1 = token).
    pub fn forward(&self, ids: Tensor<2, Int>, mask: Tensor<2>) -> Tensor<3> {
        let [b, l] = ids.dims();
        let device = ids.device();
        let pos = Tensor::<1, Int>::arange(0..l as i64, &device).reshape([1, l]).expand([b, l]);
        let tt = Tensor::<2, Int>::zeros([b, l], &device);
        let mut h = self.ln_emb.forward(
            self.word.forward(ids) + self.position.forward(pos) + self.token_type.forward(tt),
        );
        let hidden = h.dims()[2];
        let dh = hidden / self.heads;
        // Additive mask on keys: 0 for tokens, -1e4 for padding (as BERT does).
        let key_bias = (mask.ones_like() - mask).mul_scalar(-1e4).reshape([b, 1, 1, l]);
        for layer in &self.layers {
            let split = |t: Tensor<3>| t.reshape([b, l, self.heads, dh]).swap_dims(1, 2);
            let q = split(layer.query.forward(h.clone()));
            let k = split(layer.key.forward(h.clone()));
            let v = split(layer.value.forward(h.clone()));
            let scores = q.matmul(k.transpose()).div_scalar((dh as f32).sqrt()) + key_bias.clone();
            let ctx = softmax(scores, 3).matmul(v).swap_dims(1, 2).reshape([b, l, hidden]);
            h = layer.ln_attn.forward(layer.attn_out.forward(ctx) + h);
            let f = layer.out.forward(gelu(layer.inter.forward(h.clone())));
            h = layer.ln_out.forward(f + h);
        }
        h
    }
}

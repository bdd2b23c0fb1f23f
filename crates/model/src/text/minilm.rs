//! all-MiniLM-L6-v2 (sentence-transformers): BERT, mean pooling over the attention mask
//! (`[CLS]` and `[SEP]` included), L2 normalisation; on request also the per-token states
//! before pooling (`TextEncoder::embed_words`).

use std::path::{Path, PathBuf};

use burn::prelude::*;

use super::bert::{Bert, BertConfig};
use super::wordpiece::WordPiece;
use super::{TextEncoder, TextError};
use crate::network::params::host;

pub struct MiniLm {
    tokenizer: WordPiece,
    bert: Bert,
    hidden: usize,
    device: Device,
}

fn need(dir: &Path, file: &'static str) -> Result<PathBuf, TextError> {
    let p = dir.join(file);
    if p.is_file() {
        Ok(p)
    } else {
        Err(TextError::Missing { dir: dir.to_path_buf(), file })
    }
}

impl MiniLm {
    /// Load from a directory holding model.safetensors, config.json and tokenizer.json.
    pub fn load(dir: &Path, device: &Device) -> Result<MiniLm, TextError> {
        let (weights, config, tok) = (
            need(dir, "model.safetensors")?,
            need(dir, "config.json")?,
            need(dir, "tokenizer.json")?,
        );
        let cfg: BertConfig = serde_json::from_slice(
            &std::fs::read(&config)
                .map_err(|e| TextError::Bad { path: config.clone(), msg: e.to_string() })?,
        )
        .map_err(|e| TextError::Bad { path: config.clone(), msg: e.to_string() })?;
        let tokenizer = WordPiece::from_file(&tok)?;
        let bert = Bert::load(&weights, &cfg, device)?;
        Ok(MiniLm { tokenizer, bert, hidden: cfg.hidden_size, device: device.clone() })
    }
}

impl TextEncoder for MiniLm {
    fn dim(&self) -> usize {
        self.hidden
    }

    fn name(&self) -> &str {
        "all-MiniLM-L6-v2"
    }

    fn token_ids(&self, text: &str) -> Result<Vec<u32>, TextError> {
        if text.trim().is_empty() {
            return Err(TextError::Empty);
        }
        Ok(self.tokenizer.encode(text))
    }

    fn embed_words(&self, texts: &[&str], words: usize) -> Result<Vec<Vec<f32>>, TextError> {
        if texts.iter().any(|t| t.trim().is_empty()) {
            return Err(TextError::Empty);
        }
        if texts.is_empty() {
            return Ok(vec![]);
        }
        // Padded within the batch to its longest text; the attention mask keeps pooling exact.
        let encs: Vec<Vec<u32>> = texts.iter().map(|t| self.tokenizer.encode(t)).collect();
        let (b, l) = (encs.len(), encs.iter().map(Vec::len).max().unwrap_or(0));
        let pad = self.tokenizer.pad_id();
        let ids: Vec<i64> = encs
            .iter()
            .flat_map(|e| e.iter().copied().chain(std::iter::repeat(pad)).take(l))
            .map(i64::from)
            .collect();
        let mask: Vec<f32> = encs
            .iter()
            .flat_map(|e| (0..l).map(move |t| if t < e.len() { 1.0 } else { 0.0 }))
            .collect();
        let ids = Tensor::<1, Int>::from_ints(ids.as_slice(), &self.device).reshape([b, l]);
        let mask_t = Tensor::<1>::from_floats(mask.as_slice(), &self.device).reshape([b, l]);
        let h = self.bert.forward(ids, mask_t.clone());
        let m3 = mask_t.clone().unsqueeze_dim::<3>(2);
        let pooled = (h.clone() * m3).sum_dim(1).reshape([b, self.hidden])
            / mask_t.sum_dim(1).reshape([b, 1]);
        let pooled = host(l2_normalise(pooled));
        let states = (words > 0).then(|| host(l2_normalise(h.reshape([b * l, self.hidden]))));
        let hd = self.hidden;
        Ok((0..b)
            .map(|i| {
                let mut out = pooled[i * hd..(i + 1) * hd].to_vec();
                if let Some(s) = &states {
                    let n = (0..l).filter(|&t| mask[i * l + t] > 0.0).count().min(words);
                    out.extend_from_slice(&s[i * l * hd..(i * l + n) * hd]);
                    out.resize(hd * (1 + words), 0.0);
                }
                out
            })
            .collect())
    }
}

/// Rows of `x` [R, H] scaled to unit length.
fn l2_normalise(x: Tensor<2>) -> Tensor<2> {
    let norm = x.clone().powf_scalar(2.0).sum_dim(1).sqrt().clamp_min(1e-12);
    x / norm
}

//! Caption embeddings computed once per dataset and stored as safetensors (one tensor per
//! caption, named by the caption), so training never runs the text encoder per step. A model
//! that reads word states (`model.text_words`) has its own file beside the pooled one.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};

use super::{TextEncoder, TextError};

pub struct EmbeddingCache {
    /// Values per caption: the encoder's width times 1 + word states.
    pub dim: usize,
    pub map: HashMap<String, Vec<f32>>,
}

impl EmbeddingCache {
    pub fn get(&self, caption: &str) -> Option<&[f32]> {
        self.map.get(caption).map(|v| v.as_slice())
    }

    /// Load `path` if it holds all `captions` from the same encoder and word count; otherwise
    /// embed the missing ones (`TextEncoder::embed_words` with `words`, in chunks, calling
    /// `progress(done, total)`) and rewrite the file atomically.
    pub fn build(
        path: &Path,
        encoder: &dyn TextEncoder,
        words: usize,
        captions: &[String],
        mut progress: impl FnMut(usize, usize),
    ) -> Result<EmbeddingCache, TextError> {
        let name = cache_name(encoder.name(), words);
        let bad = |msg: String| TextError::Bad { path: path.to_path_buf(), msg };
        let mut map = read_cached(path, &name).map_err(|e| bad(e.to_string()))?;
        let mut missing: Vec<&String> =
            captions.iter().filter(|c| !map.contains_key(c.as_str())).collect();
        missing.sort();
        missing.dedup();
        if !missing.is_empty() {
            for (k, chunk) in missing.chunks(64).enumerate() {
                progress(k * 64, missing.len());
                let texts: Vec<&str> = chunk.iter().map(|s| s.as_str()).collect();
                for (c, e) in chunk.iter().zip(encoder.embed_words(&texts, words)?) {
                    map.insert((*c).clone(), e);
                }
            }
            progress(missing.len(), missing.len());
            let bytes_of: HashMap<&String, Vec<u8>> = map
                .iter()
                .map(|(k, v)| (k, v.iter().flat_map(|f| f.to_le_bytes()).collect()))
                .collect();
            let views: Vec<(&str, TensorView)> = bytes_of
                .iter()
                .map(|(k, b)| {
                    (k.as_str(), TensorView::new(Dtype::F32, vec![b.len() / 4], b).expect("view"))
                })
                .collect();
            let meta = HashMap::from([("encoder".to_string(), name)]);
            let out = safetensors::serialize(views, Some(meta)).map_err(|e| bad(e.to_string()))?;
            diffkfc_data::write_atomic(path, &out).map_err(|e| bad(e.to_string()))?;
        }
        Ok(EmbeddingCache { dim: encoder.dim() * (1 + words), map })
    }
}

/// What a cache file records as its encoder: the encoder's name, and the word count where
/// word states follow the pooled embedding.
fn cache_name(encoder: &str, words: usize) -> String {
    if words == 0 {
        encoder.to_string()
    } else {
        format!("{encoder}+words{words}")
    }
}

/// The caption embeddings of a dataset's splits with the default text encoder, with `words`
/// word states each (0: the pooled embedding alone, what the evaluator reads), cached next to
/// the dataset's packed splits (`text-<encoder>[+words<W>].safetensors`).
pub fn embed_captions(
    ds: &diffkfc_data::dataset::Dataset,
    splits: &[&diffkfc_data::dataset::cache::PackedSplit],
    words: usize,
    progress: impl FnMut(usize, usize),
) -> Result<EmbeddingCache, TextError> {
    let encoder =
        super::minilm::MiniLm::load(&super::default_dir(), &burn::prelude::Device::flex())?;
    let captions: Vec<String> =
        splits.iter().flat_map(|s| s.items.iter().flat_map(|i| i.captions.clone())).collect();
    let path = diffkfc_data::dataset::cache::default_cache_dir(ds)
        .join(format!("text-{}.safetensors", cache_name(encoder.name(), words)));
    EmbeddingCache::build(&path, &encoder, words, &captions, progress)
}

/// The embeddings a cache file at `path` holds, if it was made by encoder `name` (none if the
/// file is missing, unreadable as a cache, or another encoder's).
fn read_cached(
    path: &Path,
    name: &str,
) -> Result<HashMap<String, Vec<f32>>, safetensors::SafeTensorError> {
    let mut map = HashMap::new();
    let Ok(bytes) = std::fs::read(path) else {
        return Ok(map);
    };
    let Ok((_, meta)) = safetensors::SafeTensors::read_metadata(&bytes) else {
        return Ok(map);
    };
    if meta.metadata().as_ref().and_then(|m| m.get("encoder")).is_some_and(|e| e == name) {
        let st = safetensors::SafeTensors::deserialize(&bytes)?;
        for (caption, t) in st.tensors() {
            map.insert(caption, crate::run::checkpoint::f32s(t.data()));
        }
    }
    Ok(map)
}

//! Frozen text encoders behind one trait (MiniLM now; CLIP's text tower can join later), and
//! where their weights live.

pub mod bert;
pub mod cache;
pub mod minilm;
pub mod wordpiece;

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum TextError {
    #[error("text encoder weights not found in {dir}: missing {file}; run scripts/fetch-text-encoder.sh (or set DIFFKFC_TEXT_ENCODER to a directory holding model.safetensors, config.json and tokenizer.json)")]
    Missing { dir: PathBuf, file: &'static str },
    #[error("{path}: {msg}")]
    Bad { path: PathBuf, msg: String },
    #[error("empty text: a caption needs at least one word")]
    Empty,
}

pub trait TextEncoder {
    /// Embedding width.
    fn dim(&self) -> usize;
    /// A name recorded with cached embeddings (a different encoder invalidates them).
    fn name(&self) -> &str;
    /// Token ids as the encoder sees them (special tokens included).
    fn token_ids(&self, text: &str) -> Result<Vec<u32>, TextError>;
    /// L2-normalised embeddings, one per text.
    fn embed(&self, texts: &[&str]) -> Result<Vec<Vec<f32>>, TextError> {
        self.embed_words(texts, 0)
    }
    /// Per text, the embedding of [`embed`](TextEncoder::embed) followed by the encoder's
    /// last hidden states of its first `words` tokens (`[CLS]` and `[SEP]` included), each
    /// L2-normalised, and zero rows past the text's tokens: `dim() * (1 + words)` values (the
    /// layout `network::words::split` reads). `words` 0 is `embed`.
    fn embed_words(&self, texts: &[&str], words: usize) -> Result<Vec<Vec<f32>>, TextError>;
}

/// The text encoder directory: `$DIFFKFC_TEXT_ENCODER`, else `$DIFFKFC_HOME/text-encoder`,
/// else `~/.cache/diffkfc/text-encoder` (where scripts/fetch-text-encoder.sh puts it).
pub fn default_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("DIFFKFC_TEXT_ENCODER") {
        return PathBuf::from(d);
    }
    let home = std::env::var_os("DIFFKFC_HOME").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/diffkfc")
    });
    home.join("text-encoder")
}

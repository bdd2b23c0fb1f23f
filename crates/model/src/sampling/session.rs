//! A model loaded for generation with its text encoder: the one entry point `sample` and the
//! editor's server share. It embeds prompts (cached), builds requests, runs the pipeline and
//! refuses a motion that diverged instead of handing on non-finite joints.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;

use burn::prelude::Device;
use diffkfc_data::motion::plausibility;
use diffkfc_data::Skeleton;

use crate::error::Result;
use crate::run::load::InferenceModel;
use crate::sampling::fit::{Fit, Fitted};
use crate::sampling::pipeline::{Generator, KeyedItem};
use crate::sampling::sampler::{Options, Request};
use crate::text::{self, minilm::MiniLm, TextEncoder};

/// Prompts whose embeddings are kept (an editing session types a handful).
const EMBEDDING_CACHE: usize = 256;

pub struct Session {
    pub loaded: InferenceModel,
    pub skel: &'static Skeleton,
    enc: MiniLm,
    embeddings: Mutex<HashMap<String, Vec<f32>>>,
}

/// A generated motion that is not drawable (non-finite or exploded joints): sample `index`,
/// and why.
#[derive(Debug, thiserror::Error)]
#[error("sample {index} diverged ({reason})")]
pub struct Diverged {
    pub index: usize,
    pub reason: String,
}

impl Session {
    /// The model at `checkpoint` (a run or model folder, or a checkpoint file) on `device`,
    /// and the installed text encoder (on the CPU: one prompt at a time).
    pub fn load(checkpoint: &Path, device: &Device, skel: &'static Skeleton) -> Result<Session> {
        let loaded = InferenceModel::load(checkpoint, device)?;
        let enc = MiniLm::load(&text::default_dir(), &Device::flex())?;
        Ok(Session { loaded, skel, enc, embeddings: Mutex::new(HashMap::new()) })
    }

    /// The checkpoint's training step.
    pub fn step(&self) -> usize {
        self.loaded.step
    }

    /// Longest motion the model was built for (`model.max_frames`).
    pub fn max_frames(&self) -> usize {
        self.loaded.cfg.model.max_frames
    }

    /// The library's generator of the loaded model.
    pub fn generator(&self) -> Generator<'_> {
        self.loaded.generator(self.skel)
    }

    /// The prompt's embedding as the model reads it (the word states it was trained with).
    pub fn embed(&self, text: &str) -> Result<Vec<f32>> {
        let mut cache = self.embeddings.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(e) = cache.get(text) {
            return Ok(e.clone());
        }
        let words = self.loaded.cfg.model.text_words;
        let e = self.enc.embed_words(&[text], words)?.remove(0);
        if cache.len() >= EMBEDDING_CACHE {
            cache.clear();
        }
        cache.insert(text.to_string(), e.clone());
        Ok(e)
    }

    /// The request for `items`, padded to `frames` frames.
    pub fn request(&self, frames: usize, items: &[KeyedItem]) -> Request {
        self.generator().request(frames, items)
    }

    /// Sample and finish every motion of `req`; `progress(done, total)` after every denoising
    /// step. A motion that diverged (extreme guidance) is an error, not a NaN file.
    pub fn generate(
        &self,
        req: &Request,
        opts: &Options,
        fit: Fit,
        progress: impl FnMut(usize, usize),
    ) -> std::result::Result<Vec<Fitted>, Diverged> {
        let fitted = self.generator().generate(req, opts, fit, progress);
        for (index, f) in fitted.iter().enumerate() {
            if let Err(e) = plausibility::drawable_joints(self.skel, &f.features) {
                return Err(Diverged { index, reason: e.to_string() });
            }
        }
        Ok(fitted)
    }
}

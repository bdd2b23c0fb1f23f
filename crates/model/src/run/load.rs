//! Loading a trained model for inference (sampling, evaluation, export): the checkpoint a path
//! names and the network it holds, with its EMA weights when the run kept them.

use std::path::Path;

use burn::prelude::*;

use crate::diffusion::Schedule;
use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::run::config::RunConfig;
use crate::run::dir::RunDir;
use crate::sampling::pipeline::Generator;
use crate::Denoiser;

/// The checkpoint a path names: a checkpoint file, a run directory (its newest checkpoint) or a
/// model directory (`diffkfc model export`).
pub fn checkpoint_at(path: &Path) -> Result<Checkpoint> {
    let exported = path.join(crate::run::checkpoint::WEIGHTS_FILE);
    if path.is_file() {
        Checkpoint::load(path)
    } else if let Some(ck) = Checkpoint::latest(path) {
        ck
    } else if exported.is_file() {
        Checkpoint::load(&exported)
    } else {
        Err(ModelError::file(path, "no checkpoint found (train first, or pass a run directory, a model directory or a ckpt-*.safetensors file)"))
    }
}

/// Load the weights of a run for inference: the EMA when present, else the raw model. `run_dir`
/// is a run directory (its newest checkpoint) or one checkpoint file of it.
pub fn load_for_inference(run_dir: &Path, device: &Device) -> Result<(RunConfig, Denoiser, usize)> {
    let ck = checkpoint_at(run_dir)?;
    let mut cfg = RunConfig::parse(&ck.config)
        .map_err(|e| ModelError::file(run_dir, format!("stored config: {e}")))?;
    // Inference: no dropout (it has no parameters, so the weights load the same).
    cfg.model.dropout = 0.0;
    let mut ck = ck;
    let mut model = cfg.model.init(device);
    let fits = |m: &Denoiser, ck: &mut Checkpoint| {
        ck.align(&params::names(m), run_dir).is_ok() && params::shapes(m) == ck.shapes
    };
    if !fits(&model, &mut ck) {
        // Checkpoints from before root channels: their configs do not name them.
        let old = cfg.model.clone().with_root_channels(0);
        model = old.init(device);
        if !fits(&model, &mut ck) {
            return Err(ModelError::file(
                run_dir,
                "checkpoint tensors do not match its stored config",
            ));
        }
        cfg.model = old;
    }
    let weights = ck.ema.as_ref().unwrap_or(&ck.model);
    Ok((cfg, params::load(model, weights), ck.step))
}

/// A model loaded for inference once: its stored config, network, noise schedule, the
/// normalisation it was trained with, and its step.
pub struct InferenceModel {
    pub cfg: RunConfig,
    pub model: Denoiser,
    pub schedule: Schedule,
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
    pub step: usize,
}

impl InferenceModel {
    /// Load a run directory, model directory or checkpoint file for sampling or evaluation.
    pub fn load(path: &Path, device: &Device) -> Result<InferenceModel> {
        let (cfg, model, step) = load_for_inference(path, device)?;
        let (mean, std) = RunDir::of(path).normalisation(&cfg)?;
        let schedule = cfg.diffusion.schedule().map_err(|e| e.in_file(path))?;
        Ok(InferenceModel { cfg, model, schedule, mean, std, step })
    }

    /// The generator of this model for motions of `skel`.
    pub fn generator<'a>(&'a self, skel: &'a diffkfc_data::Skeleton) -> Generator<'a> {
        Generator {
            model: &self.model,
            schedule: &self.schedule,
            mean: &self.mean,
            std: &self.std,
            skel,
        }
    }
}

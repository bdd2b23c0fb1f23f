//! Loading a trained model for inference (sampling, evaluation, export): the checkpoint a path
//! names and the network it holds, with its EMA weights when the run kept them.

use std::path::Path;

use burn::prelude::*;

use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::run::config::RunConfig;
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

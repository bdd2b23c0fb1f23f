//! What a training run writes while it trains: metrics.jsonl lines and atomic checkpoints that
//! never rotate away the last good one, and the error of a run that went non-finite.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::run::config::RunConfig;
use crate::training::memory::DeviceMemory;
use crate::training::optim::Snapshot;
use crate::Denoiser;

/// One optimisation step's record (a line of metrics.jsonl).
#[derive(Clone, Debug, serde::Serialize)]
pub struct StepRecord {
    pub step: usize,
    pub loss: f64,
    pub l_simple: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub l_key: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub l_smooth: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub l_pos: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub l_vel: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub l_foot: Option<f64>,
    pub lr: f64,
    pub grad_norm: f64,
    pub wall_s: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub val_loss: Option<f64>,
    /// A GPU device's memory after the step (None on the CPU backends).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device_memory: Option<DeviceMemory>,
}

/// What a run writes while it trains: metrics.jsonl lines and checkpoints (with the tensor
/// names and shapes, config and seed they carry).
pub(crate) struct RunFiles {
    run_dir: PathBuf,
    metrics: std::fs::File,
    metrics_path: PathBuf,
    started: Instant,
    shapes: Vec<Vec<usize>>,
    names: Vec<String>,
    config: String,
    seed: u64,
    keep: usize,
}

impl RunFiles {
    /// The run's files from step `start` on (a resumed run drops the metrics lines after it).
    pub(crate) fn open(
        run_dir: &Path,
        cfg: &RunConfig,
        model: &Denoiser,
        start: usize,
    ) -> Result<RunFiles> {
        let run = crate::run::dir::RunDir::new(run_dir);
        let metrics_path = run.metrics_path();
        run.truncate_metrics(start)?;
        let metrics = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&metrics_path)
            .map_err(ModelError::io(&metrics_path))?;
        Ok(RunFiles {
            run_dir: run_dir.to_path_buf(),
            metrics,
            metrics_path,
            started: Instant::now(),
            shapes: params::shapes(model),
            names: params::names(model),
            config: cfg.to_json(),
            seed: cfg.training.seed,
            keep: cfg.training.keep_checkpoints,
        })
    }

    pub(crate) fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    fn line(&mut self, line: &str) -> Result<()> {
        writeln!(self.metrics, "{line}").map_err(ModelError::io(&self.metrics_path))
    }

    /// A validation line without a training loss (when there is a validation split).
    pub(crate) fn validation(&mut self, step: usize, val: Option<f64>) -> Result<()> {
        match val {
            Some(v) => self.line(
                &serde_json::json!({"step": step, "val_loss": v, "wall_s": self.elapsed()})
                    .to_string(),
            ),
            None => Ok(()),
        }
    }

    pub(crate) fn record(&mut self, rec: &StepRecord) -> Result<()> {
        self.line(&serde_json::to_string(rec).expect("json"))
    }

    /// Write the checkpoint of `step` and rotate old ones away; never for non-finite weights
    /// (so rotation never removes the last good checkpoint).
    pub(crate) fn checkpoint(&self, step: usize, snap: Snapshot) -> Result<PathBuf> {
        if let Some(x) = snap
            .model
            .iter()
            .chain(snap.ema.iter().flatten())
            .flat_map(|v| v.iter())
            .find(|x| !x.is_finite())
        {
            return Err(non_finite(step, "a weight", *x as f64, &self.run_dir));
        }
        let ck = Checkpoint {
            step,
            shapes: self.shapes.clone(),
            model: snap.model,
            ema: snap.ema,
            adam_step: snap.step,
            adam_m: snap.m,
            adam_v: snap.v,
            config: self.config.clone(),
            seed: self.seed,
            names: self.names.clone(),
        };
        let p = ck.save(&self.run_dir)?;
        Checkpoint::prune(&self.run_dir, self.keep);
        Ok(p)
    }
}

/// The error of a training run that went non-finite (no checkpoint is written for that step).
pub(crate) fn non_finite(step: usize, what: &str, value: f64, run_dir: &Path) -> ModelError {
    let kept = Checkpoint::list(run_dir)
        .last()
        .map(|(s, _)| format!("the newest checkpoint (step {s}) is kept"))
        .unwrap_or_else(|| "no checkpoint was written".into());
    ModelError::Diverged(format!("{}: step {step}: {what} is {value} (not finite): training stopped; {kept}. Lower training.lr, check the data with `diffkfc data check`, or resume from the checkpoint", run_dir.display()))
}

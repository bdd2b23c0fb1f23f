//! The training loop (paper section "Diffusion Model with Keyframe Collaborated"): x0
//! prediction, L_simple on non-keyframe non-padding elements plus optional kinematic losses,
//! keyframe dropout for classifier-free guidance, Adam with clipping, warm-up / cosine decay, an
//! EMA, validation, atomic checkpoints and exact resume.
//!
//! Every random draw is derived from (seed, step): the batch, the timesteps, the noise and the
//! dropout masks. A run of 2N steps and a run of N steps resumed to 2N are the same run.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::prelude::*;
use diffkfc_data::dataset::batch::{Batch, Loader};
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_data::motion::absolute_root::VelocityStats;
use diffkfc_data::rng::Rng;

use crate::diffusion::Schedule;
use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::run::config::RunConfig;
use crate::text::cache::EmbeddingCache;
use crate::training::batch::to_tensors;
use crate::training::losses::{losses, Kinematic};
use crate::training::optim::{learning_rate, Optimiser, Snapshot, StateLocation};
use crate::training::parallel::{shard_objective, Combine, Counts};
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
}

pub enum Event<'a> {
    Step(&'a StepRecord),
    Checkpoint(usize, &'a Path),
    /// A fresh run took its weights from `Trainer::init`; these parameters it had no tensor
    /// for keep their initialisation.
    WarmStart(Vec<String>),
}

pub struct Trainer<'a> {
    pub cfg: &'a RunConfig,
    pub ds: &'a Dataset,
    pub train: &'a PackedSplit,
    pub val: Option<&'a PackedSplit>,
    pub text: &'a EmbeddingCache,
    pub device: Device,
    pub run_dir: PathBuf,
    /// Where the optimiser's state lives (`StateLocation::for_device(&device)` unless overridden).
    pub optimiser: StateLocation,
    /// A fresh run starts from these weights (`warm_start`) instead of the initialisation.
    pub init: Option<PathBuf>,
}

/// How a training call ended.
#[derive(Debug)]
pub struct Outcome {
    pub start_step: usize,
    pub end_step: usize,
    pub stopped_early: bool,
    pub last: Option<StepRecord>,
}

fn scalar(t: Tensor<1>) -> f64 {
    t.into_data().convert::<f64>().try_to_vec::<f64>().expect("scalar")[0]
}

impl Trainer<'_> {
    fn text_of(&self, b: &Batch) -> Vec<f32> {
        b.captions
            .iter()
            .flat_map(|c| {
                self.text.get(c).unwrap_or_else(|| panic!("caption not embedded: {c}")).to_vec()
            })
            .collect()
    }

    fn kinematic(&self) -> Kinematic<'_> {
        let s = self.ds.skeleton;
        let t = &self.cfg.training;
        Kinematic {
            mean: &self.ds.mean,
            std: &self.ds.std,
            joints: s.num_joints(),
            feet: [s.feet_left[0], s.feet_left[1], s.feet_right[0], s.feet_right[1]],
            lambda_pos: t.lambda_pos,
            lambda_vel: t.lambda_vel,
            lambda_foot: t.lambda_foot,
            keyframe_loss: t.keyframe_loss,
            smooth_loss: t.smooth_loss,
        }
    }

    /// Timesteps and noise of a step, from (seed, stream, index) only.
    fn draw(
        &self,
        stream: u64,
        index: u64,
        [b, n, d]: [usize; 3],
        steps: usize,
        device: &Device,
    ) -> (Vec<usize>, Tensor<3>) {
        let mut r = Rng::derive(self.cfg.training.seed, stream, index);
        let t: Vec<usize> = (0..b).map(|_| r.below(steps)).collect();
        let noise: Vec<f32> = (0..b * n * d).map(|_| r.normal() as f32).collect();
        (t, Tensor::<1>::from_floats(noise.as_slice(), device).reshape([b, n, d]))
    }

    /// Loss of the model on a batch at the given timesteps and noise.
    fn batch_loss(
        &self,
        model: &Denoiser,
        schedule: &Schedule,
        b: &Batch,
        t: &[usize],
        noise: Tensor<3>,
        device: &Device,
    ) -> crate::training::losses::Losses {
        let abs = self.cfg.model.absolute();
        let tb = to_tensors(b, &self.text_of(b), self.text.dim, abs.as_ref(), device);
        let x_t = schedule.q_sample(tb.x0.clone(), t, noise);
        let pred = model.forward(x_t, t, &tb.cond);
        losses(tb.x0, pred, tb.cond.kf_mask, tb.valid, &self.kinematic())
    }

    /// Gradients (on the host, one vector per parameter) of `model` (on an autodiff device) on
    /// batch `b` at timesteps `t` and `noise` [B * N * D], computed as `shards` devices would:
    /// each shard's objective backward on its own, the gradients summed (`crate::training::parallel`).
    /// One shard is the single-device gradient.
    pub fn shard_gradients(
        &self,
        model: &Denoiser,
        b: &Batch,
        t: &[usize],
        noise: &[f32],
        shards: usize,
        combine: Combine,
    ) -> Vec<Vec<f32>> {
        let schedule = self.cfg.diffusion.schedule().expect("a validated config");
        let device = model.devices().first().cloned().expect("a model device");
        let (n, d) = (b.frames, b.dim);
        let per = b.batch_size.div_ceil(shards.max(1));
        let ranges: Vec<_> =
            (0..b.batch_size).step_by(per.max(1)).map(|s| s..(s + per).min(b.batch_size)).collect();
        let parts: Vec<Batch> = ranges.iter().map(|r| b.shard(r.clone())).collect();
        let counts: Vec<Counts> = parts.iter().map(Counts::of).collect();
        let all = Counts::sum(&counts);
        let mut sum: Vec<Vec<f32>> = Vec::new();
        for ((part, r), mine) in parts.iter().zip(&ranges).zip(&counts) {
            let nz = Tensor::<1>::from_floats(&noise[r.start * n * d..r.end * n * d], &device)
                .reshape([r.len(), n, d]);
            let l = self.batch_loss(model, &schedule, part, &t[r.clone()], nz, &device);
            let obj = shard_objective(&l, &self.kinematic(), mine, &all, ranges.len(), combine);
            let grads = burn::optim::GradientsParams::from_grads(obj.backward(), model);
            let g = params::grads(model, &grads);
            if sum.is_empty() {
                sum = g;
            } else {
                sum.iter_mut()
                    .zip(g)
                    .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x += y));
            }
        }
        sum
    }

    /// Mean validation loss (L_simple + weighted kinematic terms) over fixed batches, for the
    /// given flat weights (the EMA when there is one), on the non-autodiff device.
    fn validate(&self, weights: &[Vec<f32>], schedule: &Schedule) -> Option<f64> {
        let val = self.val?;
        if val.items.is_empty() {
            return None;
        }
        let model = params::load(self.cfg.model.init(&self.device), weights);
        let tc = &self.cfg.training;
        let loader =
            Loader::new(self.ds, val, tc.batch_size, tc.seed ^ 0x5A17, self.cfg.keyframes.clone());
        let dev = self.device.clone();
        let n = tc.val_batches.min(loader.batches_per_epoch()).max(1);
        let mut total = 0.0;
        for k in 0..n {
            let b = loader.batch(0, k);
            let (t, noise) =
                self.draw(0xFA11, k as u64, [b.batch_size, b.frames, b.dim], schedule.steps, &dev);
            let l = self.batch_loss(&model, schedule, &b, &t, noise, &dev);
            total += scalar(l.total(&self.kinematic()));
        }
        Some(total / n as f64)
    }

    /// Train to `max_steps` (from the latest checkpoint when `resume`). `stop()` is polled
    /// before every step; when it says stop, a checkpoint is written and the call returns.
    pub fn run(
        &self,
        resume: bool,
        max_steps: usize,
        stop: &dyn Fn() -> bool,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<Outcome> {
        let tc = &self.cfg.training;
        let schedule = self.checked_schedule(max_steps)?;
        std::fs::create_dir_all(&self.run_dir).map_err(ModelError::io(&self.run_dir))?;
        let device = self.device.clone().autodiff();
        device.seed(tc.seed);
        let (mut model, mut optim, start) = self.starting_point(resume, &device, on_event)?;
        let mut files = RunFiles::open(self, &model, start)?;
        let loader =
            Loader::new(self.ds, self.train, tc.batch_size, tc.seed, self.cfg.keyframes.clone());
        let (mut step, mut last, mut stopped) = (start, None, false);
        // Validation lines without a training loss: before the first step of a fresh run, and
        // where a run is stopped early, so start and end are always measured.
        if start == 0 && tc.val_every > 0 && step < max_steps {
            files.validation(0, self.validate(&optim.eval_weights(&model), &schedule))?;
        }
        while step < max_steps {
            if stop() {
                stopped = true;
                if tc.val_every > 0 && step > start {
                    files
                        .validation(step, self.validate(&optim.eval_weights(&model), &schedule))?;
                }
                break;
            }
            let (updated, mut rec) =
                self.step(model, &mut optim, &loader, &schedule, step, &device, &files)?;
            model = updated;
            step += 1;
            if tc.val_every > 0 && (step % tc.val_every == 0 || step == max_steps) {
                rec.val_loss = self.validate(&optim.eval_weights(&model), &schedule);
            }
            files.record(&rec)?;
            on_event(Event::Step(&rec));
            if step % tc.checkpoint_every.max(1) == 0 || step == max_steps {
                let p = files.checkpoint(step, optim.snapshot(&model))?;
                on_event(Event::Checkpoint(step, &p));
            }
            last = Some(rec);
        }
        if stopped
            && step > start
            && !Checkpoint::list(&self.run_dir).iter().any(|(s, _)| *s == step)
        {
            let p = files.checkpoint(step, optim.snapshot(&model))?;
            on_event(Event::Checkpoint(step, &p));
        }
        Ok(Outcome { start_step: start, end_step: step, stopped_early: stopped, last })
    }

    /// The schedule, after the checks a run must pass before it writes anything.
    fn checked_schedule(&self, max_steps: usize) -> Result<Schedule> {
        self.cfg.training.check_stop(max_steps)?;
        let schedule = self.cfg.diffusion.schedule()?;
        if self.cfg.model.absolute_root
            && VelocityStats::from_flat(&self.cfg.model.velocity_stats).is_none()
        {
            return Err(ModelError::Config(
                "model.absolute_root: the config lacks the dataset's velocity statistics (RunConfig::bind_dataset)".into(),
            ));
        }
        Ok(schedule)
    }

    /// The model and optimiser a run starts from, and its step: the newest checkpoint when
    /// resuming, else `init`'s weights (warm start) or a fresh initialisation.
    fn starting_point(
        &self,
        resume: bool,
        device: &Device,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<(Denoiser, Optimiser, usize)> {
        let keep_ema = self.cfg.training.ema_decay > 0.0;
        let mut model = self.cfg.model.init(device);
        if resume {
            if let Some(ck) = Checkpoint::latest(&self.run_dir) {
                let mut ck = ck?;
                ck.align(&params::names(&model), &self.run_dir)?;
                if ck.shapes != params::shapes(&model) {
                    return Err(ModelError::file(
                        &self.run_dir,
                        "checkpoint does not match the model in the config (different shapes; runs made before keyframes had root channels cannot be resumed: start a new --out)",
                    ));
                }
                let start = ck.step;
                let ema = keep_ema.then(|| ck.ema.unwrap_or_else(|| ck.model.clone()));
                let snap = Snapshot {
                    model: ck.model,
                    ema,
                    step: ck.adam_step,
                    m: ck.adam_m,
                    v: ck.adam_v,
                };
                let (model, optim) = Optimiser::restore(model, snap, self.optimiser);
                return Ok((model, optim, start));
            }
        }
        if let Some(path) = &self.init {
            let ck = crate::run::load::checkpoint_at(path)?;
            let (m, fresh) = crate::training::warm_start::warm_start(model, &ck, path)?;
            model = m;
            on_event(Event::WarmStart(fresh));
        }
        let optim = Optimiser::new(&model, self.optimiser, keep_ema);
        Ok((model, optim, 0))
    }

    /// One optimisation step from `step` (its batch, timesteps, noise and dropout derived from
    /// the seed and the step): the updated model and the step's record.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        model: Denoiser,
        optim: &mut Optimiser,
        loader: &Loader,
        schedule: &Schedule,
        step: usize,
        device: &Device,
        files: &RunFiles,
    ) -> Result<(Denoiser, StepRecord)> {
        let tc = &self.cfg.training;
        let step_seed = tc.seed.wrapping_mul(0x9E37_79B9).wrapping_add(step as u64);
        device.seed(step_seed);
        crate::network::dropout::seed(step_seed);
        let per_epoch = loader.batches_per_epoch().max(1);
        let b = loader.batch((step / per_epoch) as u64, step % per_epoch);
        let (t, noise) =
            self.draw(0x7EA1, step as u64, [b.batch_size, b.frames, b.dim], schedule.steps, device);
        let l = self.batch_loss(&model, schedule, &b, &t, noise, device);
        let total = l.total(&self.kinematic());
        let lr = learning_rate(tc.lr, step, tc.warmup_steps, tc.cosine_decay, tc.max_steps);
        let loss = scalar(total.clone());
        if !loss.is_finite() {
            // Stop before the step is taken: the weights and every checkpoint stay finite.
            return Err(non_finite(step + 1, "loss", loss, &self.run_dir));
        }
        let (model, grad_norm) = optim.descend(model, total, tc.grad_clip, lr);
        if !grad_norm.is_finite() {
            return Err(non_finite(step + 1, "gradient norm", grad_norm, &self.run_dir));
        }
        // Early in training the EMA follows closely (as in common EMA warm-ups).
        let decay = tc.ema_decay.min((1.0 + step as f64) / (10.0 + step as f64));
        optim.update_ema(&model, decay);
        let rec = StepRecord {
            step: step + 1,
            loss,
            l_simple: scalar(l.simple),
            l_key: l.key.map(scalar),
            l_smooth: l.smooth.map(scalar),
            l_pos: l.pos.map(scalar),
            l_vel: l.vel.map(scalar),
            l_foot: l.foot.map(scalar),
            lr,
            grad_norm,
            wall_s: files.elapsed(),
            val_loss: None,
        };
        Ok((model, rec))
    }
}

/// What a run writes while it trains: metrics.jsonl lines and checkpoints (with the tensor
/// names and shapes, config and seed they carry).
struct RunFiles {
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
    fn open(t: &Trainer, model: &Denoiser, start: usize) -> Result<RunFiles> {
        let run = crate::run::dir::RunDir::new(&t.run_dir);
        let metrics_path = run.metrics_path();
        run.truncate_metrics(start)?;
        let metrics = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&metrics_path)
            .map_err(ModelError::io(&metrics_path))?;
        Ok(RunFiles {
            run_dir: t.run_dir.clone(),
            metrics,
            metrics_path,
            started: Instant::now(),
            shapes: params::shapes(model),
            names: params::names(model),
            config: t.cfg.to_json(),
            seed: t.cfg.training.seed,
            keep: t.cfg.training.keep_checkpoints,
        })
    }

    fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    fn line(&mut self, line: &str) -> Result<()> {
        writeln!(self.metrics, "{line}").map_err(ModelError::io(&self.metrics_path))
    }

    /// A validation line without a training loss (when there is a validation split).
    fn validation(&mut self, step: usize, val: Option<f64>) -> Result<()> {
        match val {
            Some(v) => self.line(
                &serde_json::json!({"step": step, "val_loss": v, "wall_s": self.elapsed()})
                    .to_string(),
            ),
            None => Ok(()),
        }
    }

    fn record(&mut self, rec: &StepRecord) -> Result<()> {
        self.line(&serde_json::to_string(rec).expect("json"))
    }

    /// Write the checkpoint of `step` and rotate old ones away; never for non-finite weights
    /// (so rotation never removes the last good checkpoint).
    fn checkpoint(&self, step: usize, snap: Snapshot) -> Result<PathBuf> {
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
fn non_finite(step: usize, what: &str, value: f64, run_dir: &Path) -> ModelError {
    let kept = Checkpoint::list(run_dir)
        .last()
        .map(|(s, _)| format!("the newest checkpoint (step {s}) is kept"))
        .unwrap_or_else(|| "no checkpoint was written".into());
    ModelError::Diverged(format!("{}: step {step}: {what} is {value} (not finite): training stopped; {kept}. Lower training.lr, check the data with `diffkfc data check`, or resume from the checkpoint", run_dir.display()))
}

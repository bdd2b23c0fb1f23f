//! The training loop (paper section "Diffusion Model with Keyframe Collaborated"): x0
//! prediction, L_simple on non-keyframe non-padding elements plus optional kinematic losses,
//! keyframe dropout for classifier-free guidance, Adam with clipping, warm-up / cosine decay, an
//! EMA, validation, atomic checkpoints and exact resume.
//!
//! Every random draw is derived from (seed, step): the batch, the timesteps, the noise and the
//! dropout masks. A run of 2N steps and a run of N steps resumed to 2N are the same run.

use std::borrow::Cow;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::prelude::*;
use diffkfc_data::dataset::batch::{Batch, KeyframeConfig, Loader};
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_data::rng::Rng;

use crate::diffusion::Schedule;
use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::checkpoint::Checkpoint;
use crate::run::config::RunConfig;
use crate::text::cache::EmbeddingCache;
use crate::training::batch::to_tensors;
use crate::training::data_parallel::{
    self, DataParallel, GradSum, Replica, ReplicaPart, Shard, StepSync, Workers,
};
use crate::training::losses::Losses;
use crate::training::losses::{losses, Kinematic};
use crate::training::memory::device_memory;
use crate::training::optim::{learning_rate, Optimiser, Snapshot, StateLocation};
use crate::training::parallel::{shard_objective, Combine, Shares};
use crate::training::rollout;
pub use crate::training::run_files::StepRecord;
use crate::training::run_files::{non_finite, RunFiles};
use crate::training::warm_start::frozen;
use crate::training::weighting;
use crate::Denoiser;

/// A training step's batch, timesteps ([B]) and noise ([B * N * D]).
type Draws = (Batch, Vec<usize>, Vec<f32>);

/// A step's settings every replica uses: the seed of its draws, and (clip, learning rate, EMA
/// decay).
#[derive(Clone, Copy)]
struct StepCtx {
    step_seed: u64,
    hyper: (f64, f64, f64),
}

/// Where a run's replicas live: the one of a one-device run on this thread, or one per device
/// on its own thread.
enum Learners<'s> {
    One(Box<Replica>),
    Many(Workers<'s>),
}

impl Learners<'_> {
    /// Replica 0's weights for validation (its EMA when there is one); borrowed where they are
    /// on this thread's host.
    fn eval_weights(&mut self) -> Result<Cow<'_, [Vec<f32>]>> {
        match self {
            Learners::One(r) => Ok(r.optim.eval_weights(r.model())),
            Learners::Many(w) => {
                w.first(|r| r.optim.eval_weights(r.model()).into_owned()).map(Cow::Owned)
            }
        }
    }

    /// Replica 0's weights, EMA and moments for a checkpoint.
    fn snapshot(&mut self) -> Result<Snapshot> {
        match self {
            Learners::One(r) => Ok(r.optim.snapshot(r.model())),
            Learners::Many(w) => w.first(|r| r.optim.snapshot(r.model())),
        }
    }
}

/// A step's loss and its terms (each term unweighted, as `Losses` has it).
#[derive(Clone, Copy, Debug)]
struct Terms {
    total: f64,
    simple: f64,
    key: Option<f64>,
    smooth: Option<f64>,
    pos: Option<f64>,
    vel: Option<f64>,
    foot: Option<f64>,
}

impl Terms {
    /// The batch's terms from its shards' (each already weighted by its share).
    fn add(self, o: Terms) -> Terms {
        let plus = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| a + b);
        Terms {
            total: self.total + o.total,
            simple: self.simple + o.simple,
            key: plus(self.key, o.key),
            smooth: plus(self.smooth, o.smooth),
            pos: plus(self.pos, o.pos),
            vel: plus(self.vel, o.vel),
            foot: plus(self.foot, o.foot),
        }
    }
}

pub enum Event<'a> {
    Step(&'a StepRecord),
    Checkpoint(usize, &'a Path),
    /// A fresh run took its weights from `Trainer::init`: the parameters it had no tensor for
    /// (they keep their initialisation), and the feed-forward ones it widened.
    WarmStart {
        fresh: Vec<String>,
        widened: Vec<String>,
    },
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
    /// Train data-parallel on these devices (`device` is then the first of them).
    pub parallel: Option<DataParallel>,
}

/// How a training call ended.
#[derive(Debug)]
pub struct TrainOutcome {
    pub start_step: usize,
    pub end_step: usize,
    pub stopped_early: bool,
    pub last: Option<StepRecord>,
}

fn scalar(t: Tensor<1>) -> f64 {
    t.into_data().convert::<f64>().try_to_vec::<f64>().expect("scalar")[0]
}

impl Trainer<'_> {
    /// The batch's text embeddings, [B * text_dim]; a dropped text is the zero embedding.
    fn text_of(&self, b: &Batch) -> Vec<f32> {
        b.captions
            .iter()
            .zip(&b.text_dropped)
            .flat_map(|(c, &dropped)| {
                let e = self.text.get(c).unwrap_or_else(|| panic!("caption not embedded: {c}"));
                if dropped {
                    vec![0.0; e.len()]
                } else {
                    e.to_vec()
                }
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

    /// The batch, timesteps and noise of training step `step` (a function of the seed and the
    /// step only, so it can be drawn ahead, on another thread).
    fn draws(&self, loader: &Loader, steps: usize, step: usize) -> Draws {
        let per_epoch = loader.batches_per_epoch().max(1);
        let b = loader.batch((step / per_epoch) as u64, step % per_epoch);
        let (t, noise) = self.draw(0x7EA1, step as u64, [b.batch_size, b.frames, b.dim], steps);
        (b, t, noise)
    }

    /// Timesteps and noise ([B * N * D]) of a step, from (seed, stream, index) only.
    fn draw(
        &self,
        stream: u64,
        index: u64,
        [b, n, d]: [usize; 3],
        steps: usize,
    ) -> (Vec<usize>, Vec<f32>) {
        let mut r = Rng::derive(self.cfg.training.seed, stream, index);
        let t: Vec<usize> = (0..b).map(|_| r.below(steps)).collect();
        let noise: Vec<f32> = (0..b * n * d).map(|_| r.normal() as f32).collect();
        (t, noise)
    }

    /// Loss of the model on a batch at the given timesteps and noise ([B * N * D]); `train`:
    /// the training objective (with `training.rollout_prob`), not validation's.
    #[allow(clippy::too_many_arguments)]
    fn batch_loss(
        &self,
        model: &Denoiser,
        schedule: &Schedule,
        b: &Batch,
        t: &[usize],
        noise: &[f32],
        device: &Device,
        train: bool,
    ) -> Losses {
        let noised = (schedule, t, noise);
        let mut tb = to_tensors(b, &self.text_of(b), self.text.dim, noised, device);
        let tc = &self.cfg.training;
        if train && tc.rollout_prob > 0.0 {
            let rolled = rollout::chosen(tc.seed, tc.rollout_prob, t, noise);
            let shape = [b.batch_size, b.frames, b.dim];
            let noise = Tensor::<1>::from_floats(noise, device).reshape(shape);
            let (x0, x_t) = (tb.x0.clone(), tb.x_t.clone());
            let (gap, steps) = (tc.rollout_gap, tc.rollout_steps);
            let step = rollout::Step { t, rolled: &rolled, gap, steps };
            tb.x_t = rollout::rolled_x_t(model, schedule, &tb.cond, x0, noise, x_t, step);
        }
        let pred = model.forward(tb.x_t, t, &tb.cond);
        let w = weighting::sqrt_weights(&self.cfg.training, b.dim, device);
        losses(tb.x0, pred, tb.cond.kf_mask, tb.valid, w, &self.kinematic())
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
        let mut sum: Vec<Vec<f32>> = Vec::new();
        for sh in data_parallel::shards(b.clone(), t.to_vec(), noise.to_vec(), shards) {
            let l = self.batch_loss(model, &schedule, &sh.batch, sh.t(), sh.noise(), &device, true);
            let shares = Shares::of(&sh.mine, &sh.all, sh.shards, combine);
            let obj = shard_objective(&l, &self.kinematic(), &shares);
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
        // Whole keys, as every text is kept: validation losses compare across configs.
        let keys = KeyframeConfig { part_prob: 0.0, ..self.cfg.keyframes.clone() };
        let loader = Loader::new(self.ds, val, tc.batch_size, tc.seed ^ 0x5A17, keys);
        let dev = self.device.clone();
        let n = tc.val_batches.min(loader.batches_per_epoch()).max(1);
        let mut total = 0.0;
        for k in 0..n {
            let b = loader.batch(0, k);
            let (t, noise) =
                self.draw(0xFA11, k as u64, [b.batch_size, b.frames, b.dim], schedule.steps);
            let l = self.batch_loss(&model, schedule, &b, &t, &noise, &dev, false);
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
    ) -> Result<TrainOutcome> {
        let tc = &self.cfg.training;
        let schedule = self.checked_schedule(max_steps)?;
        if let Some(dp) = self.parallel.as_ref().filter(|dp| dp.devices().len() > tc.batch_size) {
            return Err(ModelError::Config(format!(
                "training.batch_size {} is smaller than the {} devices of a data-parallel run",
                tc.batch_size,
                dp.devices().len()
            )));
        }
        if self.parallel.is_some() && !tc.trainable.is_empty() {
            return Err(ModelError::Config(
                "training.trainable: a data-parallel run trains every parameter; leave it empty"
                    .into(),
            ));
        }
        std::fs::create_dir_all(&self.run_dir).map_err(ModelError::io(&self.run_dir))?;
        let device = self.device.clone().autodiff();
        device.seed(tc.seed);
        let (model, optim, start) = self.starting_point(resume, &device, on_event)?;
        let mut files = RunFiles::open(&self.run_dir, self.cfg, &model, start)?;
        let steps = start..max_steps;
        match &self.parallel {
            None => {
                let mut one = Learners::One(Box::new(Replica::new(device, model, optim)));
                self.train_loop(&mut one, &mut files, &schedule, steps, stop, on_event)
            }
            Some(dp) => {
                // The context of Burn's all-reduce outlives the replicas' threads.
                let (reps, _comm) = dp.replicas(self.cfg, optim.snapshot(&model));
                drop(model);
                std::thread::scope(|scope| {
                    let mut many = Learners::Many(Workers::spawn(scope, reps));
                    self.train_loop(&mut many, &mut files, &schedule, steps, stop, on_event)
                })
            }
        }
    }

    /// The steps `steps` (from its start, where the run stands) on `learners`, with validation,
    /// metrics and checkpoints.
    fn train_loop<'s>(
        &'s self,
        learners: &mut Learners<'s>,
        files: &mut RunFiles,
        schedule: &'s Schedule,
        steps: std::ops::Range<usize>,
        stop: &dyn Fn() -> bool,
        on_event: &mut dyn FnMut(Event),
    ) -> Result<TrainOutcome> {
        let tc = &self.cfg.training;
        let (start, max_steps) = (steps.start, steps.end);
        let loader = self.loader();
        let (mut step, mut last, mut stopped) = (start, None, false);
        // The next step's batch and noise are drawn on another thread while this one trains
        // (single-threaded work that would otherwise leave a core idle).
        let ahead = |s: usize| (s < max_steps).then(|| self.draws(&loader, schedule.steps, s));
        let mut pending: Option<Draws> = None;
        // Validation lines without a training loss: before the first step of a fresh run, and
        // where a run is stopped early, so start and end are always measured.
        if start == 0 && tc.val_every > 0 && step < max_steps {
            files.validation(0, self.validate(&learners.eval_weights()?, schedule))?;
        }
        while step < max_steps {
            if stop() {
                stopped = true;
                if tc.val_every > 0 && step > start {
                    files.validation(step, self.validate(&learners.eval_weights()?, schedule))?;
                }
                break;
            }
            let draws = pending.take().unwrap_or_else(|| self.draws(&loader, schedule.steps, step));
            let (rec, next) = std::thread::scope(|scope| {
                let next = scope.spawn(|| ahead(step + 1));
                let rec = self.step(learners, draws, schedule, step, files);
                (rec, next.join().expect("drawing a batch does not panic"))
            });
            let mut rec = rec?;
            pending = next;
            step += 1;
            if tc.val_every > 0 && (step % tc.val_every == 0 || step == max_steps) {
                rec.val_loss = self.validate(&learners.eval_weights()?, schedule);
            }
            files.record(&rec)?;
            on_event(Event::Step(&rec));
            if step % tc.checkpoint_every.max(1) == 0 || step == max_steps {
                let p = files.checkpoint(step, learners.snapshot()?)?;
                on_event(Event::Checkpoint(step, &p));
            }
            last = Some(rec);
        }
        if stopped
            && step > start
            && !Checkpoint::list(&self.run_dir).iter().any(|(s, _)| *s == step)
        {
            let p = files.checkpoint(step, learners.snapshot()?)?;
            on_event(Event::Checkpoint(step, &p));
        }
        Ok(TrainOutcome { start_step: start, end_step: step, stopped_early: stopped, last })
    }

    /// The training split's batches, with the config's key and text-drop draws.
    fn loader(&self) -> Loader<'_> {
        let tc = &self.cfg.training;
        Loader {
            text_drop_prob: tc.text_drop_prob,
            text_drop_prob_unkeyed: tc.text_drop_prob_unkeyed,
            ..Loader::new(self.ds, self.train, tc.batch_size, tc.seed, self.cfg.keyframes.clone())
        }
    }

    /// The schedule, after the checks a run must pass before it writes anything.
    fn checked_schedule(&self, max_steps: usize) -> Result<Schedule> {
        self.cfg.training.check_stop(max_steps)?;
        self.cfg.diffusion.schedule()
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
        // By name, so the same for any weights the model gets below.
        let frozen = frozen(&model, &self.cfg.training.trainable)?;
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
                return Ok((model, optim.with_frozen(frozen), start));
            }
        }
        if let Some(path) = &self.init {
            let ck = crate::run::load::checkpoint_at(path)?;
            let w = crate::training::warm_start::warm_start(model, &ck, path)?;
            model = w.model;
            on_event(Event::WarmStart { fresh: w.fresh, widened: w.widened });
        }
        let optim = Optimiser::new(&model, self.optimiser, keep_ema).with_frozen(frozen);
        Ok((model, optim, 0))
    }

    /// One optimisation step from `step` (its batch, timesteps, noise and dropout derived from
    /// the seed and the step) on every replica, each on its shard of the batch: the step's record.
    fn step<'s>(
        &'s self,
        learners: &mut Learners<'s>,
        (b, t, noise): Draws,
        schedule: &'s Schedule,
        step: usize,
        files: &RunFiles,
    ) -> Result<StepRecord> {
        let ctx = self.step_ctx(step);
        let lr = ctx.hyper.1;
        let host_sum = self.parallel.as_ref().is_some_and(|dp| dp.sum() == GradSum::Host);
        let outs: Vec<ReplicaPart<Terms>> = match learners {
            Learners::One(r) => {
                let sh = data_parallel::shards(b, t, noise, 1).remove(0);
                vec![self.replica_step(r, &sh, schedule, &StepSync::new(1, false), ctx)]
            }
            Learners::Many(w) => {
                let shards = data_parallel::shards(b, t, noise, w.len());
                let sync = Arc::new(StepSync::new(shards.len(), host_sum));
                let (tr, schedule) = (self, schedule);
                w.each(
                    shards,
                    Arc::new(move |r: &mut Replica, sh: Shard| {
                        tr.replica_step(r, &sh, schedule, &sync, ctx)
                    }),
                )?
            }
        };
        let outs = outs.into_iter().collect::<Option<Vec<_>>>().ok_or_else(|| {
            ModelError::Config(format!("step {}: a replica's forward pass panicked", step + 1))
        })?;
        let terms = outs.iter().map(|o| o.0).reduce(Terms::add).expect("a replica");
        if !terms.total.is_finite() {
            // Stopped before the step is taken: the weights and every checkpoint stay finite.
            return Err(non_finite(step + 1, "loss", terms.total, &self.run_dir));
        }
        let grad_norm = outs[0].1.expect("every replica descends when the loss is finite");
        if !grad_norm.is_finite() {
            return Err(non_finite(step + 1, "gradient norm", grad_norm, &self.run_dir));
        }
        Ok(StepRecord {
            step: step + 1,
            loss: terms.total,
            l_simple: terms.simple,
            l_key: terms.key,
            l_smooth: terms.smooth,
            l_pos: terms.pos,
            l_vel: terms.vel,
            l_foot: terms.foot,
            lr,
            grad_norm,
            wall_s: files.elapsed(),
            val_loss: None,
            device_memory: device_memory(&self.device),
        })
    }

    /// Step `step`'s seed and its (gradient clip, learning rate, EMA decay).
    fn step_ctx(&self, step: usize) -> StepCtx {
        let tc = &self.cfg.training;
        let lr = learning_rate(tc.lr, step, tc.warmup_steps, tc.cosine_decay, tc.max_steps);
        StepCtx {
            step_seed: tc.seed.wrapping_mul(0x9E37_79B9).wrapping_add(step as u64),
            // Early in training the EMA follows closely (as in common EMA warm-ups).
            hyper: (tc.grad_clip, lr, tc.ema_decay.min((1.0 + step as f64) / (10.0 + step as f64))),
        }
    }

    /// One replica's part of a step: its shard's forward pass and, once every replica's loss is
    /// known to be finite (`sync`), its backward pass, the gradient sum and the update.
    fn replica_step(
        &self,
        r: &mut Replica,
        sh: &Shard,
        schedule: &Schedule,
        sync: &StepSync,
        ctx: StepCtx,
    ) -> ReplicaPart<Terms> {
        let fwd = catch_unwind(AssertUnwindSafe(|| {
            r.device.seed(ctx.step_seed);
            crate::network::dropout::seed_shard(ctx.step_seed, sh.first, sh.batch.batch_size);
            self.shard_loss(r, schedule, sh)
        }));
        let ok = matches!(&fwd, Ok((_, terms)) if terms.total.is_finite());
        let go = sync.arrive(ok);
        let (obj, terms) = fwd.ok()?;
        Some((terms, go.then(|| r.descend(obj, ctx.hyper, sync.host.as_ref()))))
    }

    /// A replica's objective on its shard (the batch's loss when it is the only one) and the
    /// values of its terms, each weighted by the shard's share of the batch.
    fn shard_loss(&self, r: &Replica, schedule: &Schedule, sh: &Shard) -> (Tensor<1>, Terms) {
        let l =
            self.batch_loss(r.model(), schedule, &sh.batch, sh.t(), sh.noise(), &r.device, true);
        let k = self.kinematic();
        let (obj, shares) = if sh.shards == 1 {
            (l.total(&k), Shares::ONE)
        } else {
            let shares = Shares::of(&sh.mine, &sh.all, sh.shards, Combine::ByCounts);
            (shard_objective(&l, &k, &shares), shares)
        };
        let [key, smooth, pos, vel, foot] = l
            .terms(&k)
            .map(|(t, _, over)| t.as_ref().map(|x| scalar(x.clone()) * shares.of_term(over)));
        let terms = Terms {
            total: scalar(obj.clone()),
            simple: scalar(l.simple.clone()) * shares.free,
            key,
            smooth,
            pos,
            vel,
            foot,
        };
        (obj, terms)
    }
}

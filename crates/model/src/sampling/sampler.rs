//! Reverse diffusion: each step one decoder call (keyframe classifier-free guidance batches its
//! two branches, `guidance`), the guidance shift (transition and place guidance), and the
//! sampler's update (`scheduler`: DDPM, DDIM, DPM-Solver++(2M)). Meeting the keyframes exactly
//! afterwards is `fit`'s job.

use burn::prelude::*;
use diffkfc_data::motion::root_key::ROOT_CHANNELS;
use diffkfc_data::motion::root_track;
use diffkfc_data::rng::Rng;

use crate::diffusion::scheduler::{self, timesteps, Sampler};
use crate::diffusion::Schedule;
use crate::network::inference::{self, DecoderPlan};
use crate::network::params::host;
use crate::sampling::guidance::Guidance;
use crate::sampling::place::PlaceGuidance;
use crate::sampling::transition;
use crate::{Condition, Denoiser, Encoded};

/// Steps by default, with the default sampler [`DEFAULT_SAMPLER`] (DDIM): on the reference
/// model trained on its own sampler steps (`training.rollout_steps`), DDIM-20 is within 5% of
/// DDIM-50 on every metric of the 3 x 256 table and walks the six keyed walks at 0.87x their
/// speed; DDIM-10 loses stride (0.83x), DPM-Solver++(2M)-10 speed (0.84x, the slowest walk
/// 0.67x) (docs/sampling.md, "The default sampler").
pub const DEFAULT_STEPS: usize = 20;

/// The default sampler.
pub const DEFAULT_SAMPLER: Sampler = Sampler::Ddim(DEFAULT_STEPS);

/// Transition guidance strength r by default. The paper's 100 overshoots here (its loss is a sum
/// over the 263 normalised channels): on the reference model at DDIM-10 r = 100 doubles FID,
/// while r = 10 lowers K-TranS by 5% at equal FID (docs/reference-model.md).
pub const DEFAULT_TRANSITION: f64 = 10.0;

/// Keyframe guidance scale s (1: the keyframe branch alone).
pub const DEFAULT_KF_GUIDANCE: f64 = 1.0;

/// Transition guidance's half window (frames each side of a key) and its DCT bases.
pub const DEFAULT_TG_WINDOW: usize = 2;
pub const DEFAULT_TG_BASES: usize = 3;

/// How the transition-guidance gradient is taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TgMode {
    /// With respect to the predicted x0 (cheap: no backward pass).
    X0,
    /// With respect to x_t through the denoiser (the paper's Eq. 5; needs an autodiff device).
    Exact,
}

#[derive(Clone, Debug)]
pub struct Options {
    pub sampler: Sampler,
    /// Keyframe guidance scale s: X = X(C, none) + s (X(C, kf) - X(C, none)); 1 = conditional
    /// only (one forward per step instead of a doubled batch).
    pub kf_guidance: f64,
    /// Text guidance scale (MDM's): X = X(no text) + s (X(text) - X(no text)); 1 = off. Only
    /// for models trained with `training.text_drop_prob`.
    pub text_guidance: f64,
    /// Transition guidance strength r (0 = off).
    pub transition: f64,
    /// Half window l and number of DCT bases m of transition guidance.
    pub window: usize,
    pub dct_bases: usize,
    pub seed: u64,
    pub tg_mode: TgMode,
    /// The MDM-inp baseline: no keyframe branch; observed features pasted into x0 every step.
    pub inpaint: bool,
    /// Place guidance: the root path of each step's x0 pulled towards the keyed places.
    pub place: Option<PlaceGuidance>,
    /// Observed root-track features (`root_track::TRACK_DIMS`) replace the prediction at every
    /// step, so x_t carries the track the network is asked to follow.
    pub impose_track: bool,
}

impl Default for Options {
    fn default() -> Self {
        // Not the paper's s = 2.5 and r = 100 (tuned for 1000 DDPM steps): on our models both
        // cost FID, ADE and R-precision (docs/reference-model.md).
        Options {
            sampler: DEFAULT_SAMPLER,
            kf_guidance: DEFAULT_KF_GUIDANCE,
            text_guidance: 1.0,
            transition: DEFAULT_TRANSITION,
            window: DEFAULT_TG_WINDOW,
            dct_bases: DEFAULT_TG_BASES,
            seed: 0,
            tg_mode: TgMode::X0,
            inpaint: false,
            place: None,
            impose_track: false,
        }
    }
}

/// What to generate: B motions of up to N frames (normalised feature space).
#[derive(Clone, Debug)]
pub struct Request {
    pub batch: usize,
    pub frames: usize,
    pub dim: usize,
    /// [B, text_dim]
    pub text: Vec<f32>,
    pub text_dim: usize,
    /// [B, N, D] keyframe values (normalised), zero where unobserved.
    pub kf: Vec<f32>,
    /// [B, N, D] 1 where observed.
    pub mask: Vec<f32>,
    /// [B, N, ROOT_CHANNELS] keyed root place and heading (`root_key::RootKey::channels`), zero
    /// where unobserved, and its mask.
    pub root: Vec<f32>,
    pub root_mask: Vec<f32>,
    pub lengths: Vec<usize>,
    /// [B, N, D] the keys' linear interpolation (normalised), where every motion's keys allow
    /// one (`sampling::interpolation`): what the fit's balance falls back on.
    pub interpolation: Option<Vec<f32>>,
    /// [B, N, D] the network's own sample of this request before a root track was imposed
    /// (the track fit's first stage, normalised): where it missed the keys also counts against
    /// trusting the network (`sampling::balance`).
    pub unaided: Option<Vec<f32>>,
}

impl Request {
    /// A request with no keyframes: B motions of the given lengths, texts [B, text_dim].
    pub fn text_only(
        frames: usize,
        dim: usize,
        text: Vec<f32>,
        text_dim: usize,
        lengths: Vec<usize>,
    ) -> Request {
        let b = lengths.len();
        let r = ROOT_CHANNELS;
        Request {
            batch: b,
            frames,
            dim,
            text,
            text_dim,
            kf: vec![0.0; b * frames * dim],
            mask: vec![0.0; b * frames * dim],
            root: vec![0.0; b * frames * r],
            root_mask: vec![0.0; b * frames * r],
            lengths,
            interpolation: None,
            unaided: None,
        }
    }

    /// Frames of sample `b` whose pose is observed (any feature but a root track's).
    pub fn key_frames(&self, b: usize) -> Vec<usize> {
        let (n, d) = (self.frames, self.dim);
        (0..self.lengths[b])
            .filter(|&f| root_track::is_pose_key(&self.mask[(b * n + f) * d..(b * n + f + 1) * d]))
            .collect()
    }

    /// The network's condition of this request.
    pub fn condition(&self, device: &Device) -> Condition {
        let (b, n, d) = (self.batch, self.frames, self.dim);
        let real = (0..b * n).map(|f| f % n < self.lengths[f / n]).collect();
        let text =
            Tensor::<1>::from_floats(self.text.as_slice(), device).reshape([b, self.text_dim]);
        let kf = Tensor::<1>::from_floats(self.kf.as_slice(), device).reshape([b, n, d]);
        let kf_mask = Tensor::<1>::from_floats(self.mask.as_slice(), device).reshape([b, n, d]);
        Condition::new(text, kf, kf_mask, &self.mask, &self.root, &self.root_mask, real, device)
    }
}

/// Generate; returns normalised features [B, N, D] (frames past each length are zero).
/// `progress(done, total)` after every step.
pub fn sample(
    model: &Denoiser,
    schedule: &Schedule,
    req: &Request,
    opts: &Options,
    mut progress: impl FnMut(usize, usize),
) -> Vec<f32> {
    let device = model.devices().first().cloned().unwrap_or_else(Device::flex);
    let (b, n, d) = (req.batch, req.frames, req.dim);
    let cond = req.condition(&device);
    let keys: Vec<Vec<usize>> = (0..b).map(|i| req.key_frames(i)).collect();
    let any_keys = keys.iter().any(|k| !k.is_empty());
    let guidance = Guidance::new(opts.kf_guidance, opts.text_guidance, any_keys, opts.inpaint);
    let exact = opts.tg_mode == TgMode::Exact && opts.transition > 0.0 && any_keys;
    assert!(
        !exact || device.is_autodiff(),
        "exact transition guidance needs the model on an autodiff device"
    );
    let cond = if opts.inpaint { cond.without_keyframes() } else { cond };
    let mut decoder = Decoder::new(model, &guidance.condition(&cond), exact);
    let imposed = Imposed::new(req, opts, decoder.tensor_device().as_ref());
    let mut rng = Rng::new(opts.seed);
    let mut x: Vec<f32> = (0..b * n * d).map(|_| rng.normal() as f32).collect();
    let ts = timesteps(schedule, opts.sampler);
    let mut scheduler = scheduler::for_sampler(opts.sampler, schedule, rng);
    for (k, &t) in ts.iter().enumerate() {
        let (x0, x0_t) = decoder.predict(&x, t, &guidance, imposed.as_ref(), [b, n, d]);
        match ts.get(k + 1).copied() {
            None => x = x0,
            Some(prev) => {
                let (ab, ab_prev) = (schedule.alphas_cumprod[t], schedule.alphas_cumprod[prev]);
                // Posterior variance of the jump t -> prev: guidance moves x_t by it.
                let var = (1.0 - ab_prev) / (1.0 - ab) * (1.0 - ab / ab_prev);
                let exact = x0_t.filter(|_| exact);
                let step = Step { x0: &x0, exact, var };
                let shift = guidance_shift(req, opts, &keys, step);
                scheduler.step(&mut x, &x0, &shift, t, prev);
            }
        }
        progress(k + 1, ts.len());
    }
    finish(&mut x, req);
    x
}

/// The denoiser as a sample runs it: the host decoder where it serves (flex without autodiff),
/// else the tensor path, which exact transition guidance differentiates through. Either
/// encodes the condition once; the guidance branches share each decoder call.
enum Decoder<'a> {
    Host(Box<DecoderPlan>),
    /// The encoder's output is detached so per-step backward passes never reach into it; with
    /// exact transition guidance (true) each step's x_t takes a gradient. (Both boxed: with
    /// the GPU backends compiled in, tensors and the plan's views are large.)
    Tensor(&'a Denoiser, Box<Encoded>, bool),
}

impl<'a> Decoder<'a> {
    /// The device of the tensor path (None on the host decoder).
    fn tensor_device(&self) -> Option<Device> {
        match self {
            Decoder::Host(_) => None,
            Decoder::Tensor(_, enc, _) => Some(enc.tokens.device()),
        }
    }

    fn new(model: &'a Denoiser, guided: &Condition, exact: bool) -> Decoder<'a> {
        if !exact && inference::serves(&guided.kf.device()) {
            Decoder::Host(Box::new(DecoderPlan::new(model, guided)))
        } else {
            Decoder::Tensor(model, Box::new(model.encode(guided).detach()), exact)
        }
    }

    /// x0 predicted from x_t [B, N, D] at timestep t, the guidance branches combined and the
    /// imposed features put back; on the tensor path also as a tensor, with the x_t it was
    /// predicted from (differentiable in exact mode).
    fn predict(
        &mut self,
        x: &[f32],
        t: usize,
        guidance: &Guidance,
        imposed: Option<&Imposed<'_>>,
        [b, n, d]: [usize; 3],
    ) -> (Vec<f32>, Option<(Tensor<3>, Tensor<3>)>) {
        match self {
            Decoder::Host(plan) => {
                let mut x0 = guidance.combine_host(plan.decode(x, t));
                if let Some(i) = imposed {
                    impose_host(&mut x0, i.kf, &i.mask);
                }
                (x0, None)
            }
            Decoder::Tensor(model, enc, exact) => {
                let device = enc.tokens.device();
                let mut xt = Tensor::<1>::from_floats(x, &device).reshape([b, n, d]);
                if *exact {
                    xt = xt.require_grad();
                }
                let branches = guidance.branches();
                let x0_t = if branches > 1 {
                    let xs = Tensor::cat(vec![xt.clone(); branches], 0);
                    guidance.combine(model.decode(xs, &vec![t; branches * b], enc))
                } else {
                    model.decode(xt.clone(), &vec![t; b], enc)
                };
                let x0_t = match imposed.and_then(|i| i.tensors.as_ref()) {
                    Some((kf, mask)) => impose(x0_t, kf, mask),
                    None => x0_t,
                };
                (host(x0_t.clone().detach()), Some((x0_t, xt)))
            }
        }
    }
}

/// Features a request imposes on every step's prediction (MDM-inp's observed features, an
/// imposed track's root velocities): the request's values and where they are imposed, and for
/// the tensor path both as tensors.
struct Imposed<'a> {
    kf: &'a [f32],
    mask: Vec<f32>,
    tensors: Option<(Tensor<3>, Tensor<3>)>,
}

impl<'a> Imposed<'a> {
    /// `device`: the tensor path's (None: the host decoder, which needs no tensors).
    fn new(req: &'a Request, opts: &Options, device: Option<&Device>) -> Option<Imposed<'a>> {
        let d = req.dim;
        let mask: Vec<f32> = if opts.inpaint {
            req.mask.clone()
        } else if opts.impose_track {
            let track = |k: usize| root_track::TRACK_DIMS.contains(&(k % d));
            req.mask.iter().enumerate().map(|(k, &m)| if track(k) { m } else { 0.0 }).collect()
        } else {
            return None;
        };
        let shape = [req.batch, req.frames, d];
        let tensors = device.map(|device| {
            let tensor = |v: &[f32]| Tensor::<1>::from_floats(v, device).reshape(shape);
            (tensor(&req.kf), tensor(&mask))
        });
        Some(Imposed { kf: &req.kf, mask, tensors })
    }
}

/// The sampler's result with the frames past each length zeroed.
fn finish(x: &mut [f32], req: &Request) {
    let (n, d) = (req.frames, req.dim);
    for i in 0..req.batch {
        for f in req.lengths[i]..n {
            x[(i * n + f) * d..(i * n + f + 1) * d].iter_mut().for_each(|v| *v = 0.0);
        }
    }
}

/// The prediction's observed features put back where the request imposes them: MDM-inp pastes
/// every observed feature at every step, an imposed track its root velocities.
fn impose(x0_t: Tensor<3>, kf: &Tensor<3>, m: &Tensor<3>) -> Tensor<3> {
    x0_t * (m.ones_like() - m.clone()) + kf.clone() * m.clone()
}

/// [`impose`] on host values (the same operations, the same bits).
fn impose_host(x0: &mut [f32], kf: &[f32], mask: &[f32]) {
    for ((x, k), m) in x0.iter_mut().zip(kf).zip(mask) {
        *x = *x * (1.0 - m) + k * m;
    }
}

/// One step's prediction, for the guidance terms.
struct Step<'a> {
    /// Predicted x0 on the host, [B * N * D].
    x0: &'a [f32],
    /// For transition guidance through the denoiser (the paper's Eq. 5) rather than on x0:
    /// the same x0 as a tensor, differentiable with respect to the x_t it holds second.
    exact: Option<(Tensor<3>, Tensor<3>)>,
    /// Posterior variance of the jump to the next timestep.
    var: f64,
}

/// What guidance subtracts from a step's update: r * var * dL_tr/dx for transition guidance
/// (the x0 gradient, or chained through the denoiser in exact mode) plus place guidance's
/// strength * var * dL_place/dx on the root channels.
fn guidance_shift(req: &Request, opts: &Options, keys: &[Vec<usize>], step: Step) -> Vec<f32> {
    let (b, n, d) = (req.batch, req.frames, req.dim);
    let mut shift = vec![0f32; step.x0.len()];
    if opts.transition > 0.0 && step.var > 0.0 {
        let mut grad = vec![0f32; step.x0.len()];
        for (i, key) in keys.iter().enumerate() {
            let r = i * n * d..(i + 1) * n * d;
            let (_, g) = transition::loss_and_grad(
                &step.x0[r.clone()],
                &req.kf[r.clone()],
                &req.mask[r.clone()],
                key,
                req.lengths[i],
                d,
                opts.window,
                opts.dct_bases,
            );
            grad[r].copy_from_slice(&g);
        }
        if let Some((x0_t, xt)) = step.exact {
            // Chain rule through the denoiser: d L / d x_t = J^T (d L / d x0).
            let device = xt.device();
            let g = Tensor::<1>::from_floats(grad.as_slice(), &device).reshape([b, n, d]);
            let grads = (x0_t * g).sum().backward();
            grad = xt.grad(&grads).map(host).unwrap_or(grad);
        }
        for (s, gv) in shift.iter_mut().zip(grad) {
            *s = (opts.transition * step.var) as f32 * gv;
        }
    }
    if let (Some(pg), true) = (&opts.place, step.var > 0.0) {
        for i in 0..b {
            let (r, rr) =
                (i * n * d..(i + 1) * n * d, i * n * ROOT_CHANNELS..(i + 1) * n * ROOT_CHANNELS);
            let (_, g) = pg.loss_and_grad(
                &step.x0[r.clone()],
                &req.root[rr.clone()],
                &req.root_mask[rr],
                req.lengths[i],
                d,
            );
            for (s, gv) in shift[r].iter_mut().zip(g) {
                *s += (pg.strength * step.var) as f32 * gv;
            }
        }
    }
    shift
}

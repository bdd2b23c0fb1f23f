//! Benchmark workloads shared by `diffkfc bench` and the criterion benches, so both time the
//! same work: a training step (forward, backward, clipping, Adam, weights reloaded: what the
//! trainer does per step), a sampling call with keyframe guidance (both branches in one batch;
//! with or without the encoder), and a full DDIM sample with both guidances.

pub mod flops;

use std::cell::RefCell;

use burn::prelude::*;
use diffkfc_data::keyframes;
use diffkfc_data::rng::Rng;

use crate::diffusion::scheduler::Sampler;
use crate::diffusion::Schedule;
use crate::network::inference::{self, DecoderPlan};
use crate::sampling::guidance::Guidance;
use crate::sampling::sampler::{self, Options, Request};
use crate::training::optim::{Optimiser, StateLocation};
use crate::{network::params, Condition, Denoiser, DiffKfcConfig, Encoded};

/// Random inputs of a fixed seed: `batch` motions of `frames` frames with 5% uniform keyframes.
pub fn request(cfg: &DiffKfcConfig, batch: usize, frames: usize, seed: u64) -> Request {
    let (n, d) = (frames, cfg.feat_dim);
    let mut r = Rng::new(seed);
    let keys = keyframes::uniform(n, keyframes::count(n, 0.05));
    let mut mask = vec![0f32; batch * n * d];
    let mut kf = vec![0f32; batch * n * d];
    for b in 0..batch {
        for &f in &keys {
            for c in 0..d {
                mask[(b * n + f) * d + c] = 1.0;
                kf[(b * n + f) * d + c] = r.normal() as f32;
            }
        }
    }
    let text = (0..batch * cfg.text_width()).map(|_| 0.05 * r.normal() as f32).collect();
    Request { kf, mask, ..Request::text_only(n, d, text, cfg.text_width(), vec![n; batch]) }
}

/// The encoder blocks' work for `cond` (see `flops::forward_planned`), on the sampling path's
/// encoder (`query_rows`) or the tensor path's (`DmaPlan::work`).
fn block_work(
    cfg: &DiffKfcConfig,
    cond: &crate::Condition,
    query_rows: bool,
) -> Vec<crate::network::keyframe_encoder::BlockWork> {
    let [b, n, _] = cond.kf.dims();
    crate::network::keyframe_encoder::DmaPlan::new(
        &cond.kf_frames,
        &cond.real,
        b,
        n,
        &cfg.dma_sizes,
    )
    .work(query_rows)
}

/// A [B, N, D] tensor of standard normals from `r`.
fn normal_tensor(r: &mut Rng, shape: [usize; 3], device: &Device) -> Tensor<3> {
    let v: Vec<f32> = (0..shape.iter().product::<usize>()).map(|_| r.normal() as f32).collect();
    Tensor::<1>::from_floats(v.as_slice(), device).reshape(shape)
}

/// The training-step workload: model on an autodiff device and its optimiser.
pub struct TrainStep {
    model: Option<Denoiser>,
    optim: Optimiser,
    req: Request,
    x0: Tensor<3>,
    noise: Tensor<3>,
    t: Vec<usize>,
    schedule: Schedule,
    device: Device,
    /// Seconds of the last step in forward + loss, backward, and the host-side update.
    pub phases: [f64; 3],
}

impl TrainStep {
    pub fn new(cfg: &DiffKfcConfig, batch: usize, frames: usize, device: &Device) -> TrainStep {
        let device = device.clone().autodiff();
        device.seed(0);
        crate::network::dropout::seed(0);
        let model = cfg.init(&device);
        let optim = Optimiser::new(&model, StateLocation::for_device(&device), false);
        let req = request(cfg, batch, frames, 1);
        let mut r = Rng::new(2);
        let shape = [batch, frames, cfg.feat_dim];
        let (x0, noise) =
            (normal_tensor(&mut r, shape, &device), normal_tensor(&mut r, shape, &device));
        let t = (0..batch).map(|i| (97 * i + 500) % 1000).collect();
        TrainStep {
            model: Some(model),
            optim,
            req,
            x0,
            noise,
            t,
            schedule: Schedule::cosine(1000),
            device,
            phases: [0.0; 3],
        }
    }

    /// Matrix-product FLOPs of one step as computed (encoder blocks on their gathered rows).
    pub fn flops(&self, cfg: &DiffKfcConfig) -> f64 {
        let cond = self.req.condition(&self.device);
        let [b, n, _] = cond.kf.dims();
        crate::bench::flops::train_step(cfg, b, n, &block_work(cfg, &cond, false))
    }

    /// One step; returns the loss (its value forces the work to finish).
    pub fn step(&mut self) -> f64 {
        let model = self.model.take().expect("model");
        let t0 = std::time::Instant::now();
        let cond = self.req.condition(&self.device);
        let x_t = self.schedule.q_sample(self.x0.clone(), &self.t, self.noise.clone());
        let loss = (model.forward(x_t, &self.t, &cond) - self.x0.clone()).powf_scalar(2.0).mean();
        let value = params::host(loss.clone())[0] as f64;
        let forward = t0.elapsed().as_secs_f64();
        let (model, _, [backward, update]) = self.optim.descend_timed(model, loss, 1.0, 1e-4);
        self.phases = [forward, backward, update];
        self.model = Some(model);
        value
    }
}

/// The sampling workloads: one request of `batch` motions, keyframe guidance doubling the batch.
pub struct Sampling<'a> {
    pub model: &'a Denoiser,
    pub req: Request,
    pub encoded: Encoded,
    /// The host decoder of `encoded`, where sampling runs it (`inference::serves`).
    plan: Option<RefCell<DecoderPlan>>,
    x: Tensor<3>,
    /// x on the host, as sampling holds it.
    x_host: Vec<f32>,
    t: Vec<usize>,
}

/// Keyframe guidance scale of the timed sampling: the paper's.
const PAPER_KF_GUIDANCE: f64 = 2.5;

/// The guidance the timed calls run: keyframe guidance, both branches in one batch.
fn paper_guidance() -> Guidance {
    Guidance::new(PAPER_KF_GUIDANCE, 1.0, true, false)
}

/// A condition as the guided call batches it, [c; c without keyframes].
fn guided(c: &Condition) -> Condition {
    paper_guidance().condition(c)
}

impl<'a> Sampling<'a> {
    pub fn new(
        model: &'a Denoiser,
        cfg: &DiffKfcConfig,
        batch: usize,
        frames: usize,
    ) -> Sampling<'a> {
        let device = model.devices().first().cloned().unwrap_or_else(Device::flex);
        let req = request(cfg, batch, frames, 3);
        let encoded = model.encode(&guided(&req.condition(&device)));
        let mut r = Rng::new(4);
        let rows = paper_guidance().branches() * batch;
        let x = normal_tensor(&mut r, [rows, frames, cfg.feat_dim], &device);
        let plan = inference::serves(&device)
            .then(|| RefCell::new(DecoderPlan::new(model, &guided(&req.condition(&device)))));
        let x_host = params::host(x.clone());
        Sampling { model, req, encoded, plan, x, x_host, t: vec![500; rows] }
    }

    /// Which decoder the calls run: "host" (`network::inference`) or "tensor".
    pub fn decoder(&self) -> &'static str {
        if self.plan.is_some() {
            "host"
        } else {
            "tensor"
        }
    }

    /// Matrix-product FLOPs of one guided call as computed (see `TrainStep::flops`).
    pub fn flops(&self, cfg: &DiffKfcConfig) -> crate::bench::flops::Flops {
        let cond = guided(&self.req.condition(&self.x.device()));
        let [b, n, _] = cond.kf.dims();
        crate::bench::flops::forward_planned(
            cfg,
            b,
            n,
            &block_work(cfg, &cond, self.plan.is_some()),
        )
    }

    /// One guided denoising call as sampling makes it: decoder only (encoder output cached, and
    /// on the host decoder its buffers, as in every step after the first) or encoder + decoder
    /// (the host decoder's set-up included).
    pub fn call(&self, with_encoder: bool) -> Vec<f32> {
        let device = self.x.device();
        if let Some(plan) = &self.plan {
            let x = &self.x_host;
            if with_encoder {
                let c = guided(&self.req.condition(&device));
                return DecoderPlan::new(self.model, &c).decode(x, self.t[0]).to_vec();
            }
            return plan.borrow_mut().decode(x, self.t[0]).to_vec();
        }
        let out = if with_encoder {
            let enc = self.model.encode(&guided(&self.req.condition(&self.x.device())));
            self.model.decode(self.x.clone(), &self.t, &enc)
        } else {
            self.model.decode(self.x.clone(), &self.t, &self.encoded)
        };
        params::host(out)
    }

    /// A full sample: DDIM with keyframe guidance 2.5 and transition guidance 100 (x0 mode).
    pub fn sample(&self, steps: usize) -> Vec<f32> {
        let schedule = Schedule::cosine(1000);
        let opts = Options {
            sampler: Sampler::Ddim(steps),
            kf_guidance: PAPER_KF_GUIDANCE,
            transition: 100.0,
            ..Options::default()
        };
        sampler::sample(self.model, &schedule, &self.req, &opts, |_, _| {})
    }
}

/// The machine a timing ran on: CPU model, the vector extensions that set the matrix-product
/// peak (AVX2/FMA vs AVX-512 differ about 4x), threads, and the single-precision matrix-product
/// rate measured through the same gemm the fused kernels use (best of `reps` n x n products on
/// all threads), so timings from different machines compare as fractions of their peak.
pub fn machine(n: usize, reps: usize) -> serde_json::Value {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |k: &str| {
        info.lines()
            .find(|l| l.starts_with(k))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
            .unwrap_or_default()
    };
    let flags = field("flags");
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    serde_json::json!({
        "case": "machine",
        "cpu": field("model name"),
        "avx2": has("avx2"),
        "fma": has("fma"),
        "avx512f": has("avx512f"),
        "threads": rayon::current_num_threads(),
        "matmul_n": n,
        "matmul_peak_gflops": matmul_peak(n, reps),
    })
}

/// The single-precision matrix-product rate (GFLOP/s) on all threads: the best of `reps` n x n
/// products through the gemm the fused kernels use.
pub fn matmul_peak(n: usize, reps: usize) -> f64 {
    let (x, w, b) = (vec![0.5f32; n * n], vec![0.25f32; n * n], vec![0f32; n]);
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t0 = std::time::Instant::now();
        std::hint::black_box(crate::kernels::host::linear_forward(&x, &w, &b));
        best = best.min(t0.elapsed().as_secs_f64());
    }
    2.0 * (n * n * n) as f64 / best / 1e9
}

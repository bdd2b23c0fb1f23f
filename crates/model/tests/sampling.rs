//! Sampling: guidance identities, exact keyframes, determinism (tiny random-weight model).

use burn::prelude::*;
use diffkfc_model::diffusion::scheduler::{timesteps, Sampler};
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::sampling::fit::{fit_sample, Fit, KeyframeFit};
use diffkfc_model::sampling::sampler::{sample, Options, Request};
use diffkfc_model::DiffKfcConfig;

fn request() -> Request {
    let (b, n, d) = (2, 24, 263);
    let mut r = diffkfc_data::rng::Rng::new(3);
    let mut kf = vec![0f32; b * n * d];
    let mut mask = vec![0f32; b * n * d];
    for (s, frames) in [(0usize, vec![0usize, 10, 19]), (1, vec![5])] {
        for f in frames {
            for c in 0..d {
                let k = (s * n + f) * d + c;
                kf[k] = r.normal() as f32;
                mask[k] = 1.0;
            }
        }
    }
    let text = (0..b * 384).map(|_| r.normal() as f32 * 0.05).collect();
    Request { kf, mask, ..Request::text_only(n, d, text, 384, vec![20, 24]) }
}

fn run(model: &diffkfc_model::Denoiser, opts: &Options) -> Vec<f32> {
    sample(model, &Schedule::cosine(1000), &request(), opts, |_, _| {})
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn guidance_identities_and_exact_keyframes() {
    let model = DiffKfcConfig::tiny().init(&Device::flex());
    let run = |o: &Options| run(&model, o);
    let base = Options {
        sampler: Sampler::Ddim(8),
        kf_guidance: 1.0,
        transition: 0.0,
        window: 2,
        dct_bases: 3,
        seed: 4,
        ..Options::default()
    };
    let a = run(&base);
    // s = 1 (conditional branch alone) vs the batched guided path at s = 1 + 1e-6.
    let b = run(&Options { kf_guidance: 1.0 + 1e-6, ..base.clone() });
    assert!(max_diff(&a, &b) < 1e-3, "{}", max_diff(&a, &b));
    // r = 0 vs a vanishing r: the guidance path adds nothing else.
    let c = run(&Options { transition: 1e-9, ..base.clone() });
    assert!(max_diff(&a, &c) < 1e-4);
    // Same seed, same motion; another seed, another.
    assert_eq!(a, run(&base));
    assert_ne!(a, run(&Options { seed: 5, ..base.clone() }));
    // Padding is zero; with a paste or a warp the keyframes are hit exactly.
    let req = request();
    assert!(a[20 * 263..24 * 263].iter().all(|&v| v == 0.0));
    let (mean, std) = (vec![0.1f32; 263], vec![0.5f32; 263]);
    for fit in [KeyframeFit::Paste, KeyframeFit::Warp] {
        for i in 0..2 {
            let done = fit_sample(
                &a,
                &req,
                i,
                &mean,
                &std,
                &diffkfc_data::T2M,
                Fit { keyframes: fit, foot_lock: false, rigid: false, ..Fit::default() },
            );
            let (f, corr) = (done.features, done.corrections);
            // Foot locking leaves the keyed frames as the fit made them.
            let locked = fit_sample(
                &a,
                &req,
                i,
                &mean,
                &std,
                &diffkfc_data::T2M,
                Fit { keyframes: fit, foot_lock: true, rigid: false, ..Fit::default() },
            )
            .features;
            for (k, (x, y)) in f.iter().zip(&locked).enumerate() {
                if req.mask[i * 24 * 263 + k] > 0.0 {
                    assert_eq!(x, y, "{fit:?} sample {i} element {k}");
                }
            }
            assert_eq!(f.len(), req.lengths[i] * 263);
            assert_eq!(corr.len(), if i == 0 { 3 } else { 1 }, "{fit:?}");
            for (k, &v) in f.iter().enumerate() {
                let src = i * 24 * 263 + k;
                // Root velocities (0..3) are rewritten by the warp; contacts are not blended.
                let c = k % 263;
                if req.mask[src] > 0.0 && (fit == KeyframeFit::Paste || (3..259).contains(&c)) {
                    let want = req.kf[src] * 0.5 + 0.1;
                    assert!(
                        (v - want).abs() < 1e-5,
                        "{fit:?} sample {i} element {k}: {v} vs {want}"
                    );
                }
            }
        }
    }
    // Guidance changes the result, and everything stays finite under both samplers.
    let g = run(&Options { kf_guidance: 2.5, transition: 100.0, ..base.clone() });
    assert!(g.iter().all(|v| v.is_finite()) && max_diff(&a, &g) > 0.0);
}

#[test]
fn ddpm_runs_and_ddim_steps_are_spaced() {
    let s = Schedule::cosine(1000);
    assert_eq!(timesteps(&s, Sampler::Ddim(5)), vec![999, 749, 500, 250, 0]);
    // One step predicts from pure noise, at the last timestep (it used to run at t = 0).
    assert_eq!(timesteps(&s, Sampler::Ddim(1)), vec![999]);
    assert_eq!(timesteps(&s, Sampler::Ddpm).len(), 1000);
    let s20 = Schedule::cosine(20);
    let dev = Device::flex();
    let model = DiffKfcConfig::tiny().init(&dev);
    let out = sample(
        &model,
        &s20,
        &request(),
        &Options { sampler: Sampler::Ddpm, ..Default::default() },
        |_, _| {},
    );
    assert!(out.iter().all(|v| v.is_finite()));
}

/// DPM-Solver++(2M) takes DDIM's steps; its first step is DDIM's, so over two steps the two
/// agree (to rounding), and from the third step on its second-order correction makes them differ.
#[test]
fn dpm_solver_starts_as_ddim_then_corrects() {
    let s = Schedule::cosine(1000);
    assert_eq!(timesteps(&s, Sampler::DpmSolver(5)), timesteps(&s, Sampler::Ddim(5)));
    let model = DiffKfcConfig::tiny().init(&Device::flex());
    let run = |sampler| {
        sample(
            &model,
            &s,
            &request(),
            &Options { sampler, transition: 0.0, ..Default::default() },
            |_, _| {},
        )
    };
    let e = max_diff(&run(Sampler::DpmSolver(2)), &run(Sampler::Ddim(2)));
    assert!(e < 1e-4, "first-order DPM-Solver differs from DDIM by {e}");
    let (a, b) = (run(Sampler::DpmSolver(6)), run(Sampler::Ddim(6)));
    assert!(a.iter().all(|v| v.is_finite()) && max_diff(&a, &b) > 1e-4);
}

//! The network on flex (with the fused kernels) against another backend (Burn's composed ops)
//! with the same weights: one forward, one training step (backward, clipping, Adam, and Adam
//! with its state on the device) and a guided DDIM sample agree. The other backends are ndarray
//! (`--features diffkfc-model/ndarray`), wgpu (`--features diffkfc-model/wgpu`; in CI on
//! Mesa's lavapipe, a software Vulkan: `VK_ICD_FILENAMES=.../lvp_icd.x86_64.json`) and cuda, one test
//! each, so one build with both features serves both (`.ci/run` builds them once through
//! `scripts/gpu-check.sh wgpu --quick --features diffkfc/ndarray`).
#![cfg(any(feature = "ndarray", feature = "wgpu", feature = "cuda"))]
#![allow(deprecated)] // Burn marks its ndarray backend deprecated; it is the reference here

use burn::prelude::*;
use diffkfc_model::diffusion::scheduler::Sampler;
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::network::params;
use diffkfc_model::sampling::sampler::{sample, Options, Request};
use diffkfc_model::training::optim::{clip_grad_norm, Adam, Optimiser, StateLocation};
use diffkfc_model::{Denoiser, DiffKfcConfig};

fn request() -> Request {
    let (b, n, d) = (2, 24, 263);
    let mut r = diffkfc_data::rng::Rng::new(3);
    let (mut kf, mut mask) = (vec![0f32; b * n * d], vec![0f32; b * n * d]);
    for (s, f) in [(0usize, 0usize), (0, 10), (1, 5)] {
        for c in 0..d {
            kf[(s * n + f) * d + c] = r.normal() as f32;
            mask[(s * n + f) * d + c] = 1.0;
        }
    }
    let text = (0..b * 384).map(|_| r.normal() as f32 * 0.05).collect();
    Request { kf, mask, ..Request::text_only(n, d, text, 384, vec![20, 24]) }
}

/// The same weights on `device`.
fn model_on(device: &Device, weights: &[Vec<f32>]) -> Denoiser {
    params::load(DiffKfcConfig::tiny().with_dropout(0.0).init(device), weights)
}

fn rel(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den.max(1e-30)).sqrt()
}

/// ndarray runs the same f32 arithmetic on the CPU (measured 2e-7 forward and 3e-6 sample).
#[cfg(feature = "ndarray")]
#[test]
fn flex_and_ndarray_agree() {
    agree("ndarray", Device::ndarray(), 1e-5, 1e-4);
}

/// A GPU's reductions and transcendental functions differ more (the bounds: 1e-4 and 1e-3).
#[cfg(feature = "wgpu")]
#[test]
fn flex_and_wgpu_agree() {
    agree("wgpu", Device::wgpu(burn::tensor::DeviceKind::DefaultDevice), 1e-4, 1e-3);
}

#[cfg(feature = "cuda")]
#[test]
fn flex_and_cuda_agree() {
    agree("cuda", Device::cuda(0), 1e-4, 1e-3);
}

/// Flex against `nd` (called `name`), with the bounds of the forward and sample differences.
fn agree(name: &str, nd: Device, fwd_bound: f64, sample_bound: f64) {
    let flex = Device::flex();
    eprintln!("flex against {name}");
    flex.seed(1);
    let init = DiffKfcConfig::tiny().with_dropout(0.0).init(&flex);
    let weights: Vec<Vec<f32>> = params::values(&init).into_iter().map(|(_, v)| v).collect();
    let req = request();
    let (b, n, d) = (req.batch, req.frames, req.dim);
    let mut r = diffkfc_data::rng::Rng::new(7);
    let x: Vec<f32> = (0..b * n * d).map(|_| r.normal() as f32).collect();
    let x0: Vec<f32> = (0..b * n * d).map(|_| r.normal() as f32 * 0.5).collect();
    let t = [600, 40];

    // One forward.
    let fwd = |device: &Device| {
        let m = model_on(device, &weights);
        let xt = Tensor::<1>::from_floats(x.as_slice(), device).reshape([b, n, d]);
        params::host(m.forward(xt, &t, &req.condition(device)))
    };
    let e = rel(&fwd(&flex), &fwd(&nd));
    eprintln!("forward: relative difference {e:.2e}");
    assert!(e < fwd_bound, "forward differs by {e}");

    // The model on an autodiff device and its MSE to x0.
    let loss_on = |device: &Device| {
        let device = device.clone().autodiff();
        let m = model_on(&device, &weights);
        let xt = Tensor::<1>::from_floats(x.as_slice(), &device).reshape([b, n, d]);
        let target = Tensor::<1>::from_floats(x0.as_slice(), &device).reshape([b, n, d]);
        let loss = (m.forward(xt, &t, &req.condition(&device)) - target).powf_scalar(2.0).mean();
        (m, loss)
    };
    // One training step: backward, gradients to the host, clipping, Adam.
    let step = |device: &Device| {
        let (m, loss) = loss_on(device);
        let grads = burn::optim::GradientsParams::from_grads(loss.backward(), &m);
        let mut g = params::grads(&m, &grads);
        let raw = g.clone();
        let norm = clip_grad_norm(&mut g, 1.0);
        let mut vals = weights.clone();
        Adam::new(&vals.iter().map(Vec::len).collect::<Vec<_>>()).update(&mut vals, &g, 1e-3);
        (raw, norm, vals.concat())
    };
    let ((ga, na, va), (gb, nb, vb)) = (step(&flex), step(&nd));
    let (eg, ew) = (rel(&ga.concat(), &gb.concat()), rel(&va, &vb));
    // Where the difference sits: each parameter's share (absolute, and relative to its own size).
    let mut parts: Vec<(f64, usize, usize, f64)> = ga
        .iter()
        .zip(&gb)
        .enumerate()
        .map(|(i, (a, b))| {
            let d: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
            let own: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
            (d.sqrt(), i, a.len(), (d / own.max(1e-30)).sqrt())
        })
        .collect();
    parts.sort_by(|a, b| b.0.total_cmp(&a.0));
    eprintln!(
        "training step: largest differences (abs, parameter, size, relative): {:?}",
        &parts[..3]
    );
    eprintln!("training step: gradients differ by {eg:.2e} (norms {na:.6} vs {nb:.6}), weights after Adam by {ew:.2e}");
    // Measured 4.4e-5 and 1.0e-5: float32 summation orders and the fused kernels' polynomial exp
    // and erf, spread over every parameter (no one op off; a wrong backward would be O(1)).
    assert!(eg < 1e-4 && ew < 1e-4, "gradients {eg}, weights {ew}");

    // The device-resident optimiser (the GPU backends' path) in Burn's ops on the other
    // backend: the same step as the host path there, and as flex's.
    let (m, loss) = loss_on(&nd);
    let mut o = Optimiser::new(&m, StateLocation::Device, false);
    let (m, norm) = o.descend(m, loss, 1.0, 1e-3);
    let vd: Vec<f32> = params::values(&m).into_iter().flat_map(|(_, v)| v).collect();
    let (ed, edf) = (rel(&vd, &vb), rel(&vd, &va));
    eprintln!("device-state Adam on {name}: weights differ from its host Adam by {ed:.2e}, from flex's by {edf:.2e} (norm {norm:.6})");
    assert!((norm - nb).abs() <= 1e-5 * nb && ed < 1e-6 && edf < 1e-4, "{ed} {edf} {norm} {nb}");

    // A DDIM sample with keyframe and transition guidance (5 steps).
    let opts = Options {
        sampler: Sampler::Ddim(5),
        kf_guidance: 2.5,
        transition: 10.0,
        ..Options::default()
    };
    let smp = |device: &Device| {
        sample(&model_on(device, &weights), &Schedule::cosine(1000), &req, &opts, |_, _| {})
    };
    let e = rel(&smp(&flex), &smp(&nd));
    eprintln!("DDIM-5 sample: relative difference {e:.2e}");
    assert!(e < sample_bound, "sample differs by {e}");
}

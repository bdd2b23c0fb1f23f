//! Invariants of the DiffKFC network (tiny config, flex CPU backend).

use burn::module::{ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::Distribution;
use diffkfc_data::motion::root_key::ROOT_CHANNELS;
use diffkfc_model::network::keyframe_encoder::{DmaBlock, DmaPlan};
use diffkfc_model::{Condition, DiffKfcConfig};

const N: usize = 24;
const D: usize = 263;

fn device() -> Device {
    Device::flex()
}

fn to_vec<const K: usize>(t: Tensor<K>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// A condition for `b` samples: sample k has `lens[k]` real frames and keyframes at `keys[k]`.
fn condition(
    lens: &[usize],
    keys: &[Vec<usize>],
    dev: &Device,
    seed: u64,
) -> (Tensor<3>, Condition) {
    let b = lens.len();
    dev.seed(seed);
    let x = Tensor::<3>::random([b, N, D], Distribution::Normal(0.0, 1.0), dev);
    let mut mask = vec![0f32; b * N * D];
    let mut kf_frames = vec![false; b * N];
    let mut real = vec![false; b * N];
    for s in 0..b {
        for f in 0..lens[s] {
            real[s * N + f] = true;
        }
        for &f in &keys[s] {
            kf_frames[s * N + f] = true;
            mask[(s * N + f) * D..(s * N + f + 1) * D].iter_mut().for_each(|m| *m = 1.0);
        }
    }
    let kf_mask = Tensor::<1>::from_floats(mask.as_slice(), dev).reshape([b, N, D]);
    let valid = Tensor::<1>::from_floats(
        real.iter().map(|&r| r as i32 as f32).collect::<Vec<_>>().as_slice(),
        dev,
    )
    .reshape([b, N, 1]);
    let x = x * valid;
    let text = Tensor::<2>::random([b, 384], Distribution::Normal(0.0, 0.05), dev);
    let root = vec![0f32; b * N * ROOT_CHANNELS];
    let mut cond =
        Condition::new(text, x.clone() * kf_mask.clone(), kf_mask, &mask, &root, &root, real, dev);
    cond.kf_frames = kf_frames;
    (x, cond)
}

/// `model` with every all-zero tensor (zero-initialised extensions, LayerNorm offsets) made
/// non-zero, so that the invariants are checked through them; `expected` names a tensor that
/// must be among them.
fn perturbed(model: diffkfc_model::Denoiser, expected: &str) -> diffkfc_model::Denoiser {
    use diffkfc_model::network::params;
    let names = params::names(&model);
    let mut hit = false;
    let vals: Vec<Vec<f32>> = params::values(&model)
        .into_iter()
        .zip(&names)
        .map(|((_, v), name)| {
            if !v.iter().all(|&x| x == 0.0) {
                return v;
            }
            hit |= name.contains(expected);
            (0..v.len()).map(|i| ((i + 1) as f32 * 0.37).sin() * 0.5).collect()
        })
        .collect();
    assert!(hit, "{expected} was found zero and perturbed");
    params::load(model, &vals)
}

/// The tiny network, and the tiny network with a temporal convolution and with the per-frame
/// key input (both zero-initialised, perturbed so that they do something).
fn tiny_models(dev: &Device) -> Vec<diffkfc_model::Denoiser> {
    vec![
        DiffKfcConfig::tiny().init(dev),
        perturbed(DiffKfcConfig::tiny().with_temporal_kernel(3).init(dev), "temporal"),
        perturbed(DiffKfcConfig::tiny().with_key_input(true).init(dev), "key_in"),
    ]
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn sample_alone_equals_sample_in_batch() {
    let dev = device();
    for model in tiny_models(&dev) {
        let (x, c) = condition(&[20, 24, 12], &[vec![0, 10], vec![5], vec![]], &dev, 1);
        let out = to_vec(model.forward(x.clone(), &[10, 500, 999], &c));
        // The middle sample alone.
        let one = Condition {
            text: c.text.clone().slice([1..2, 0..384]),
            kf: c.kf.clone().slice([1..2, 0..N, 0..D]),
            kf_mask: c.kf_mask.clone().slice([1..2, 0..N, 0..D]),
            root: c.root.clone().slice([1..2, 0..N, 0..ROOT_CHANNELS]),
            root_mask: c.root_mask.clone().slice([1..2, 0..N, 0..ROOT_CHANNELS]),
            kf_frames: c.kf_frames[N..2 * N].to_vec(),
            real: c.real[N..2 * N].to_vec(),
        };
        let alone = to_vec(model.forward(x.slice([1..2, 0..N, 0..D]), &[500], &one));
        let e = max_diff(&out[N * D..2 * N * D], &alone);
        assert!(e < 1e-5, "{e}");
    }
}

#[test]
fn padding_never_changes_real_frames() {
    let dev = device();
    for model in tiny_models(&dev) {
        let (x, c) = condition(&[15], &[vec![3, 14]], &dev, 2);
        let base = to_vec(model.forward(x.clone(), &[100], &c));
        // Garbage in the padding of x_t and of the keyframe inputs.
        let noise = Tensor::<3>::random([1, N, D], Distribution::Normal(0.0, 5.0), &dev);
        let pad: Vec<f32> = (0..N).map(|f| if f >= 15 { 1.0 } else { 0.0 }).collect();
        let pad = Tensor::<1>::from_floats(pad.as_slice(), &dev).reshape([1, N, 1]);
        let c2 = Condition { kf: c.kf.clone() + noise.clone() * pad.clone(), ..c.clone() };
        let out = to_vec(model.forward(x + noise * pad, &[100], &c2));
        assert!(max_diff(&base[..15 * D], &out[..15 * D]) < 1e-5);
    }
}

#[test]
fn zero_keyframes_give_finite_outputs() {
    let dev = device();
    let model = DiffKfcConfig::tiny().init(&dev);
    let (x, c) = condition(&[24, 7], &[vec![], vec![]], &dev, 3);
    let out = to_vec(model.forward(x, &[0, 999], &c));
    assert!(out.iter().all(|v| v.is_finite()));
    // Dropping keyframes of a keyed condition equals never having had any.
    let (x, c) = condition(&[24], &[vec![2, 9]], &dev, 4);
    let dropped = c.without_keyframes();
    let (_, empty) = condition(&[24], &[vec![]], &dev, 4);
    let a = to_vec(model.forward(x.clone(), &[50], &dropped));
    let b = to_vec(model.forward(x, &[50], &Condition { text: c.text.clone(), ..empty }));
    assert!(max_diff(&a, &b) < 1e-5);
}

/// In a DMA block, changing a token that is not yet valid changes no other token's output.
#[test]
fn invalid_tokens_do_not_leak_within_a_block() {
    let dev = device();
    let d = 32;
    let block = DmaBlock::new(d, 4, 64, &dev);
    let n = 20;
    let keys: Vec<bool> = (0..n).map(|i| i == 5).collect();
    let real = vec![true; n];
    let plan = DmaPlan::new(&keys, &real, 1, n, &[2]);
    let l = n + 1;
    let blocked = diffkfc_model::kernels::Mask::Full(plan.blocked[0].clone());
    let active = plan.active[0].as_slice();
    let z = Tensor::<3>::random([1, l, d], Distribution::Normal(0.0, 1.0), &dev);
    let base = to_vec(block.forward(z.clone(), blocked.clone(), active, plan.valid_before(0)));
    // Token of frame 6 (adjacent to the keyframe: active but not valid yet) and frame 15 (inactive).
    for tok in [7usize, 16] {
        let bump: Vec<f32> = (0..l * d).map(|k| if k / d == tok { 3.0 } else { 0.0 }).collect();
        let z2 = z.clone() + Tensor::<1>::from_floats(bump.as_slice(), &dev).reshape([1, l, d]);
        let out = to_vec(block.forward(z2, blocked.clone(), active, plan.valid_before(0)));
        for i in (0..l).filter(|&i| i != tok) {
            assert!(
                max_diff(&base[i * d..(i + 1) * d], &out[i * d..(i + 1) * d]) < 1e-5,
                "token {i} changed when {tok} did"
            );
        }
    }
    // An inactive token passes through unchanged.
    let zin = to_vec(z);
    assert!(max_diff(&zin[16 * d..17 * d], &base[16 * d..17 * d]) == 0.0);
}

struct CountParams(usize);
impl ModuleVisitor for CountParams {
    fn visit_float<const K: usize>(&mut self, _p: &Param<Tensor<K>>) {
        self.0 += 1;
    }
}

#[test]
fn gradients_reach_every_parameter() {
    let dev = device().autodiff();
    for model in tiny_models(&dev) {
        let (x, c) = condition(&[24, 18], &[vec![1, 12], vec![4]], &dev, 5);
        let loss = model.forward(x, &[7, 300], &c).powf_scalar(2.0).mean();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        let mut count = CountParams(0);
        model.visit(&mut count);
        assert_eq!(grads.len(), count.0, "parameters without gradient");
    }
}

#[test]
fn paper_config_has_about_47m_parameters() {
    let model = DiffKfcConfig::paper().init(&device());
    let total = model.num_params();
    for (name, n) in model.param_counts() {
        eprintln!("paper config: {name}: {n}");
    }
    assert!((total as f64 - 47e6).abs() / 47e6 < 0.10, "{total}");
}

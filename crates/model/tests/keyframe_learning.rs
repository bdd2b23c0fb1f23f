//! The keyframe path must learn: on a handful of clips whose captions all embed to the same
//! vector (the text cannot tell them apart), a tiny model trained for a few hundred steps
//! reproduces a clip from 5% of its frames far better than from its text alone. No fit or paste
//! after sampling: the errors are those of the network's own output, on the frames that are not
//! keyframes.
//!
//! It also measures (prints, does not assert) whether keyframes that carry their places bring
//! the root nearer the clip's path than the same keyframes without them, on a model with the
//! root path hint: the reference model ignored places, and no configuration has yet passed a
//! 0.75 ratio here (docs/reference-model.md), so the check is not an assertion until one does.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::{Dataset, MAX_FRAMES};
use diffkfc_data::keyframes;
use diffkfc_data::motion::root_key::{self, ROOT_CHANNELS};
use diffkfc_data::rng::Rng;
use diffkfc_model::diffusion::scheduler::Sampler;
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::run::config::RunConfig;
use diffkfc_model::run::load::load_for_inference;
use diffkfc_model::sampling::sampler::{sample, Options, Request};
use diffkfc_model::text::cache::EmbeddingCache;
use diffkfc_model::training::optim::StateLocation;
use diffkfc_model::training::trainer::Trainer;
use diffkfc_synth::SynthSpec;

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Every caption embeds to one fixed vector: text carries no information about the clip.
fn one_embedding(split: &PackedSplit) -> EmbeddingCache {
    let mut r = Rng::new(11);
    let e: Vec<f32> = (0..384).map(|_| r.normal() as f32 * 0.05).collect();
    let map: HashMap<String, Vec<f32>> = split
        .items
        .iter()
        .flat_map(|it| it.captions.iter().map(|c| (c.clone(), e.clone())))
        .collect();
    EmbeddingCache { dim: 384, map }
}

fn root_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("diffkfc-kflearn-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Mean absolute error of the de-normalised root-relative joint positions (features 4..67) of
/// `gen` against `gt` over `frames`.
fn ric_error(ds: &Dataset, gen: &[f32], gt: &[f32], frames: &[usize]) -> f64 {
    let d = ds.dim();
    let ric = 4..4 + 3 * (ds.skeleton.num_joints() - 1);
    let mut sum = 0.0;
    for &f in frames {
        for c in ric.clone() {
            let k = f * d + c;
            sum += ((gen[k] - gt[k]) * ds.std[c]).abs() as f64;
        }
    }
    sum / (frames.len() * ric.len()) as f64
}

/// Mean ground-plane distance between the roots of normalised features `gen` and `gt` over
/// their first `len` frames (both start at the origin facing +Z).
fn root_path_error(ds: &Dataset, gen: &[f32], gt: &[f32], len: usize) -> f64 {
    let d = ds.dim();
    let path = |x: &[f32]| {
        let mut x = x[..len * d].to_vec();
        ds.denormalise(&mut x);
        root_key::root_trajectory(&x, d)
    };
    let (a, b) = (path(gen), path(gt));
    let dist = |p: [f64; 2], q: [f64; 2]| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
    a.iter().zip(&b).map(|(p, q)| dist(p.place.unwrap(), q.place.unwrap())).sum::<f64>()
        / len as f64
}

#[test]
fn keyframes_reproduce_a_clip_far_better_than_text() {
    let steps = env_or("DIFFKFC_KFTEST_STEPS", 400);
    let root = root_dir();
    diffkfc_synth::write_dataset(&root.join("data"), &SynthSpec::legacy(24, 5), 2, &|_, _| {})
        .unwrap();
    let ds = Dataset::open(root.join("data")).unwrap();
    let train =
        PackedSplit::open(&ds, "train", &root.join("data/.diffkfc-cache"), |_, _| {}).unwrap();
    let text = one_embedding(&train);
    let mut cfg =
        RunConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/tiny.json"))
            .unwrap();
    cfg.training.batch_size = 16;
    cfg.training.max_steps = steps;
    cfg.training.warmup_steps = 20;
    cfg.training.lr = 1e-3;
    cfg.training.ema_decay = 0.99;
    cfg.training.checkpoint_every = steps;
    cfg.training.val_every = 0;
    if let Some(w) = std::env::var("DIFFKFC_KFTEST_KEYLOSS").ok().and_then(|v| v.parse().ok()) {
        cfg.training.keyframe_loss = w;
    }
    let run_dir = root.join("run");
    let t0 = std::time::Instant::now();
    let tr = Trainer {
        cfg: &cfg,
        ds: &ds,
        train: &train,
        val: None,
        text: &text,
        device: Device::flex(),
        optimiser: StateLocation::Host,
        run_dir: run_dir.clone(),
        init: None,
        parallel: None,
    };
    tr.run(false, steps, &|| false, &mut |_| {}).unwrap();
    let train_s = t0.elapsed().as_secs_f64();

    let device = Device::flex();
    let (cfg, model, _) = load_for_inference(&run_dir, &device).unwrap();
    let schedule = Schedule::by_name(&cfg.diffusion.schedule, cfg.diffusion.steps).unwrap();
    let d = ds.dim();
    let items: Vec<usize> = (0..train.items.len().min(12)).collect();
    // Keyframe guidance at the paper's s = 2.5 is measured too (printed, not asserted).
    let (mut with_keys, mut text_only, mut guided) = (0.0, 0.0, 0.0);
    let (mut placed, mut unplaced) = (0.0, 0.0);
    for &i in &items {
        let spec = &train.items[i];
        let len = (spec.len.min(MAX_FRAMES) / 4) * 4;
        let mut gt = train.item_frames(i)[..len * d].to_vec();
        ds.normalise(&mut gt);
        let mut rng = Rng::new(100 + i as u64);
        let keys = keyframes::select(keyframes::Strategy::Random, len, 0.05, &gt, d, &mut rng);
        let others: Vec<usize> = (0..len).filter(|f| !keys.contains(f)).collect();
        let mut raw = gt.clone();
        ds.denormalise(&mut raw);
        let gt_root = root_key::root_channels(&raw, d);
        let (mut errs, mut root_errs) = ([0.0; 4], [0.0; 4]);
        // Keys with places; no keys; keys with places at s = 2.5; keys without places.
        for (slot, (observed, s, places)) in [
            (keys.clone(), 1.0, true),
            (vec![], 1.0, false),
            (keys.clone(), 2.5, true),
            (keys.clone(), 1.0, false),
        ]
        .into_iter()
        .enumerate()
        {
            let (n, r) = (MAX_FRAMES, ROOT_CHANNELS);
            let (mut root, mut root_mask) = (vec![0f32; n * r], vec![0f32; n * r]);
            for &f in observed.iter().filter(|_| places) {
                root[f * r..(f + 1) * r].copy_from_slice(&gt_root[f * r..(f + 1) * r]);
                root_mask[f * r..(f + 1) * r].fill(1.0);
            }
            let mut kf = vec![0f32; n * d];
            let mask = keyframes::frame_mask(n, &observed, &vec![true; d]);
            for &f in &observed {
                kf[f * d..(f + 1) * d].copy_from_slice(&gt[f * d..(f + 1) * d]);
            }
            let req = Request {
                kf: kf.repeat(2),
                mask: mask.repeat(2),
                root: root.repeat(2),
                root_mask: root_mask.repeat(2),
                ..Request::text_only(
                    n,
                    d,
                    text.get(&spec.captions[0]).unwrap().repeat(2),
                    384,
                    vec![len; 2],
                )
            };
            let opts = Options {
                sampler: Sampler::Ddim(20),
                kf_guidance: s,
                transition: 0.0,
                seed: i as u64,
                ..Options::default()
            };
            let out = sample(&model, &schedule, &req, &opts, |_, _| {});
            errs[slot] = (0..2)
                .map(|s| ric_error(&ds, &out[s * n * d..(s * n + len) * d], &gt, &others))
                .sum::<f64>()
                / 2.0;
            root_errs[slot] = (0..2)
                .map(|s| root_path_error(&ds, &out[s * n * d..(s * n + len) * d], &gt, len))
                .sum::<f64>()
                / 2.0;
        }
        placed += root_errs[0] / items.len() as f64;
        unplaced += root_errs[3] / items.len() as f64;
        with_keys += errs[0] / items.len() as f64;
        text_only += errs[1] / items.len() as f64;
        guided += errs[2] / items.len() as f64;
    }
    eprintln!(
        "keyframe learning ({steps} steps, {train_s:.0} s, {} train items): root-relative joint error off the keyframes, 5% keyframes {with_keys:.4} m vs text only {text_only:.4} m (ratio {:.2}); with keyframe guidance s = 2.5: {guided:.4} m",
        train.items.len(),
        with_keys / text_only
    );
    eprintln!(
        "keyframe places (measured, not asserted): the root's mean distance from the clip's path, keys with places {placed:.3} m vs the same keys without {unplaced:.3} m (ratio {:.2})",
        placed / unplaced
    );
    std::fs::remove_dir_all(&root).unwrap();
    assert!(
        with_keys < 0.75 * text_only,
        "keyframes do not help: {with_keys:.4} vs {text_only:.4}"
    );
}

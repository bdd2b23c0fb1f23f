//! Stage 2 of the track fit must follow a root track: a tiny model trained a few hundred steps
//! with dense root tracks in its mask schedule is given the whole root track of clips it never
//! saw; the generated pelvis must stay on that path and the feet the network itself labels as
//! planted must not slide along it (the legs step at the track's speed).

use std::path::{Path, PathBuf};

use burn::prelude::*;
use diffkfc_data::cache::PackedSplit;
use diffkfc_data::dataset::{Dataset, MAX_FRAMES};
use diffkfc_data::representation::recover_from_ric;
use diffkfc_data::root_track;
use diffkfc_data::warp::{self, ROOT_CHANNELS};
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::optim::Home;
use diffkfc_model::run_config::RunConfig;
use diffkfc_model::sampler::{sample, Options, Request};
use diffkfc_model::text::cache::EmbeddingCache;
use diffkfc_model::trainer::{load_for_inference, Trainer};

fn env_or(name: &str, default: usize) -> usize {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn root_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("diffkfc-track-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// One embedding per caption, shared by every caption (the track is the signal under test).
fn one_embedding(splits: &[&PackedSplit]) -> EmbeddingCache {
    let e: Vec<f32> = (0..384).map(|k| ((k * 37 % 11) as f32 - 5.0) * 0.01).collect();
    let map = splits
        .iter()
        .flat_map(|s| s.items.iter())
        .flat_map(|it| it.captions.iter().map(|c| (c.clone(), e.clone())))
        .collect();
    EmbeddingCache { dim: 384, map }
}

/// The request observing the whole root track of de-normalised features `raw` [len, D].
fn track_request(ds: &Dataset, raw: &[f32], len: usize, text: Vec<f32>) -> Request {
    let (n, d, r) = (MAX_FRAMES, ds.dim(), ROOT_CHANNELS);
    let mut x = raw.to_vec();
    ds.normalise(&mut x);
    let mut req = Request::text_only(n, d, text, 384, vec![len]);
    let frames: Vec<usize> = (0..len).collect();
    root_track::observe(
        &x,
        &warp::root_channels(raw, d),
        d,
        &frames,
        &mut req.kf,
        &mut req.mask,
        &mut req.root[..n * r],
        &mut req.root_mask[..n * r],
    );
    req
}

#[test]
fn a_dense_root_track_is_followed_by_the_pelvis_and_the_feet() {
    let steps = env_or("DIFFKFC_TRACKTEST_STEPS", 400);
    let root = root_dir();
    diffkfc_data::synth::write_dataset(&root.join("data"), 60, 5, 2, &|_, _| {}).unwrap();
    let ds = Dataset::open(root.join("data")).unwrap();
    let cache = root.join("data/.diffkfc-cache");
    let train = PackedSplit::open(&ds, "train", &cache, |_, _| {}).unwrap();
    let test = PackedSplit::open(&ds, "test", &cache, |_, _| {}).unwrap();
    let text = one_embedding(&[&train, &test]);
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/tiny.json");
    let mut cfg = RunConfig::load(&manifest).unwrap();
    cfg.model.key_input = true;
    cfg.keyframes.dense_root_prob = 0.5;
    cfg.training.batch_size = 16;
    cfg.training.max_steps = steps;
    cfg.training.warmup_steps = 20;
    cfg.training.lr = 1e-3;
    cfg.training.ema_decay = 0.99;
    cfg.training.checkpoint_every = steps;
    cfg.training.val_every = 0;
    let run_dir = root.join("run");
    let tr = Trainer {
        cfg: &cfg,
        ds: &ds,
        train: &train,
        val: None,
        text: &text,
        device: Device::flex(),
        optimiser: Home::Host,
        run_dir: run_dir.clone(),
        init: None,
    };
    tr.run(false, steps, &|| false, &mut |_| {}).unwrap();

    let device = Device::flex();
    let (cfg, model, _) = load_for_inference(&run_dir, &device).unwrap();
    let schedule = Schedule::by_name(&cfg.diffusion.schedule, cfg.diffusion.steps).unwrap();
    let (d, skel) = (ds.dim(), ds.skeleton);
    let contacts = diffkfc_data::Layout::of(skel).contacts();
    let (mut path_err, mut toe_speed, mut src_toe_speed) = (0.0, 0.0, 0.0);
    let items = test.items.len().min(4);
    assert!(items >= 2, "held-back clips: {}", test.items.len());
    for i in 0..items {
        let spec = &test.items[i];
        let len = (spec.len.min(MAX_FRAMES) / 4) * 4;
        let raw = test.item_frames(i)[..len * d].to_vec();
        let req = track_request(&ds, &raw, len, text.get(&spec.captions[0]).unwrap().to_vec());
        let opts = Options { seed: i as u64, impose_track: true, ..Options::default() };
        let mut out = sample(&model, &schedule, &req, &opts, |_, _| {})[..len * d].to_vec();
        ds.denormalise(&mut out);
        let (a, b) = (warp::root_trajectory(&out, d), warp::root_trajectory(&raw, d));
        path_err += a
            .iter()
            .zip(&b)
            .map(|(p, q)| {
                let (p, q) = (p.place.unwrap(), q.place.unwrap());
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()
            })
            .sum::<f64>()
            / (len * items) as f64;
        // Toe speed on the frames the motion labels as planted (m/s at 20 fps).
        let planted_speed = |x: &[f32]| {
            let j = recover_from_ric(skel, &x.iter().map(|&v| v as f64).collect::<Vec<_>>());
            let (mut sum, mut count) = (0.0, 0);
            for (c, toe) in [(1, skel.feet_left[1]), (3, skel.feet_right[1])] {
                for f in 0..len - 1 {
                    if x[f * d + contacts.start + c] > 0.5 {
                        let (p, q) = (j[f][toe], j[f + 1][toe]);
                        sum += ((p[0] - q[0]).powi(2) + (p[2] - q[2]).powi(2)).sqrt() * skel.fps;
                        count += 1;
                    }
                }
            }
            sum / count.max(1) as f64
        };
        toe_speed += planted_speed(&out) / items as f64;
        src_toe_speed += planted_speed(&raw) / items as f64;
    }
    eprintln!(
        "track following ({steps} steps, {items} held-back clips): pelvis {path_err:.4} m from the track; planted toes move {toe_speed:.3} m/s (the clips' own {src_toe_speed:.3})"
    );
    assert!(path_err < 0.05, "pelvis strays {path_err:.3} m from the observed track");
    assert!(toe_speed < 0.2, "planted toes slide at {toe_speed:.3} m/s");
    let _ = std::fs::remove_dir_all(&root);
}

//! Stage 2 of the track fit must follow a root track: the reference model (or the run named by
//! DIFFKFC_TRACK_MODEL) is given the whole root track of synthetic clips it never saw (another
//! seed than its training set's), imposed as the track fit imposes it; the generated pelvis must
//! stay on that path (within 5 cm) and the toes the network itself labels as planted must move
//! slower than the previous reference model's did.
//!
//! The goal is 0.2 m/s; the reference model does not reach it (0.53 m/s here, the clips' own
//! 0.04): it labels nearly every frame of a walk as planted and its legs glide rather than step
//! at the track's speed. The bound below is the level the committed model
//! holds, so a model or sampler change that makes the legs follow the track less fails.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::{denormalise, normalise, Dataset, MAX_FRAMES};
use diffkfc_data::motion::representation::recover_from_ric;
use diffkfc_data::motion::root_key::{self, ROOT_CHANNELS};
use diffkfc_data::motion::root_track;
use diffkfc_model::diffusion::Schedule;
use diffkfc_model::run::load::load_for_inference;
use diffkfc_model::sampling::sampler::{sample, Options, Request};
use diffkfc_model::text::{self, minilm::MiniLm, TextEncoder};
use diffkfc_synth::SynthSpec;

fn root_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("diffkfc-track-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The request observing the whole root track of de-normalised features `raw` [len, D], in the
/// model's normalisation.
fn track_request(raw: &[f32], len: usize, mean: &[f32], std: &[f32], text: Vec<f32>) -> Request {
    let (n, d, r) = (MAX_FRAMES, mean.len(), ROOT_CHANNELS);
    let mut x = raw.to_vec();
    normalise(&mut x, mean, std);
    let mut req = Request::text_only(n, d, text, 384, vec![len]);
    let frames: Vec<usize> = (0..len).collect();
    root_track::observe(
        &x,
        &root_key::root_channels(raw, d),
        d,
        &frames,
        &mut req.kf,
        &mut req.mask,
        &mut req.root[..n * r],
        &mut req.root_mask[..n * r],
    );
    req
}

/// Mean ground speed (m/s) of the toes on the frames features `x` [T, D] label as planted.
fn planted_toe_speed(ds: &Dataset, x: &[f32]) -> f64 {
    let (d, skel) = (ds.dim(), ds.skeleton);
    let t = x.len() / d;
    let contacts = diffkfc_data::Layout::of(skel).contacts();
    let j = recover_from_ric(skel, &x.iter().map(|&v| v as f64).collect::<Vec<_>>());
    let (mut sum, mut count) = (0.0, 0);
    for (c, toe) in [(1, skel.feet_left[1]), (3, skel.feet_right[1])] {
        for f in 0..t - 1 {
            if x[f * d + contacts.start + c] > 0.5 {
                let (p, q) = (j[f][toe], j[f + 1][toe]);
                sum += (p[0] - q[0]).hypot(p[2] - q[2]) * skel.fps;
                count += 1;
            }
        }
    }
    sum / count.max(1) as f64
}

/// Mean ground distance (m) between the roots of de-normalised features `a` and `b`.
fn path_distance(a: &[f32], b: &[f32], d: usize) -> f64 {
    let (a, b) = (root_key::root_trajectory(a, d), root_key::root_trajectory(b, d));
    let dist = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    a.iter().zip(&b).map(|(p, q)| dist(p.place.unwrap(), q.place.unwrap())).sum::<f64>()
        / a.len() as f64
}

#[test]
fn a_dense_root_track_is_followed_by_the_pelvis_and_the_feet() {
    let model_dir = std::env::var("DIFFKFC_TRACK_MODEL")
        .map(PathBuf::from)
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth"));
    let enc = match MiniLm::load(&text::default_dir(), &Device::flex()) {
        Ok(m) => m,
        Err(e) if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") => {
            panic!("text encoder required (DIFFKFC_REQUIRE_FIXTURES=1): {e}")
        }
        Err(e) => return eprintln!("SKIPPED: {e}"),
    };
    let root = root_dir();
    diffkfc_synth::write_dataset(&root.join("data"), &SynthSpec::legacy(60, 77), 2, &|_, _| {})
        .unwrap();
    let ds = Dataset::open(root.join("data")).unwrap();
    let clips =
        PackedSplit::open(&ds, "train", &root.join("data/.diffkfc-cache"), |_, _| {}).unwrap();
    let device = Device::flex();
    let (cfg, model, _) = load_for_inference(&model_dir, &device).unwrap();
    let read = |f: &str| diffkfc_data::io::npy::read_f32(model_dir.join(f)).unwrap().data;
    let (mean, std) = (read("Mean.npy"), read("Std.npy"));
    let schedule = Schedule::by_name(&cfg.diffusion.schedule, cfg.diffusion.steps).unwrap();
    let d = ds.dim();
    // Clips that travel (over 0.3 m/s on average): a track to follow.
    let moving: Vec<usize> = (0..clips.items.len())
        .filter(|&i| {
            let len = clips.items[i].len.min(MAX_FRAMES);
            let raw = &clips.item_frames(i)[..len * d];
            let path = root_key::root_trajectory(raw, d);
            let [x, z] = path[len - 1].place.unwrap();
            x.hypot(z) / len as f64 * ds.skeleton.fps > 0.3
        })
        .take(6)
        .collect();
    assert!(moving.len() >= 4, "moving clips: {}", moving.len());
    let (mut path_err, mut toe, mut src_toe) = (0.0, 0.0, 0.0);
    for (k, &i) in moving.iter().enumerate() {
        let len = (clips.items[i].len.min(MAX_FRAMES) / 4) * 4;
        let raw = clips.item_frames(i)[..len * d].to_vec();
        let caption = &clips.items[i].captions[0];
        let text = enc.embed(&[caption.as_str()]).unwrap().remove(0);
        let req = track_request(&raw, len, &mean, &std, text);
        let opts = Options { seed: k as u64, impose_track: true, ..Options::default() };
        let mut out = sample(&model, &schedule, &req, &opts, |_, _| {})[..len * d].to_vec();
        denormalise(&mut out, &mean, &std);
        let m = moving.len() as f64;
        path_err += path_distance(&out, &raw, d) / m;
        toe += planted_toe_speed(&ds, &out) / m;
        src_toe += planted_toe_speed(&ds, &raw) / m;
    }
    eprintln!(
        "track following ({}, {} moving clips): pelvis {path_err:.4} m from the track; planted toes move {toe:.3} m/s (the clips' own {src_toe:.3})",
        model_dir.display(),
        moving.len()
    );
    let _ = std::fs::remove_dir_all(&root);
    assert!(path_err < 0.05, "pelvis strays {path_err:.3} m from the observed track");
    // Reference models: before dense tracks 0.614 m/s, with them 0.593, with the foot loss
    // on the observed root 0.526.
    assert!(toe < 0.56, "planted toes slide at {toe:.3} m/s");
}

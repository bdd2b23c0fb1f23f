//! The training loop on a tiny synthetic set: loss goes down, checkpoints are written, and a
//! resumed run equals an uninterrupted one step for step.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_model::run::checkpoint::Checkpoint;
use diffkfc_model::run::config::RunConfig;
use diffkfc_model::text::cache::EmbeddingCache;
use diffkfc_model::training::optim::StateLocation;
use diffkfc_model::training::trainer::{Event, Trainer};

/// Burn's device RNG (dropout, initialisation) is process-wide: tests that train take turns.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn dataset(name: &str, clips: usize) -> PathBuf {
    let d = std::env::temp_dir().join(format!("diffkfc-train-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    diffkfc_synth::write_dataset(&d, &diffkfc_synth::SynthSpec::legacy(clips, 2), 2, &|_, _| {})
        .unwrap();
    d
}

/// Deterministic stand-in embeddings (the loop's mechanics do not depend on text semantics;
/// the real encoder has its own golden test).
fn embeddings(train: &PackedSplit, val: &PackedSplit) -> EmbeddingCache {
    let mut map = HashMap::new();
    for it in train.items.iter().chain(&val.items) {
        for c in &it.captions {
            let mut r = diffkfc_data::rng::Rng::new(
                c.bytes().fold(7u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64)),
            );
            map.insert(c.clone(), (0..384).map(|_| r.normal() as f32 * 0.05).collect());
        }
    }
    EmbeddingCache { dim: 384, map }
}

/// A synthetic dataset with its opened splits and caption embeddings.
struct Prepared {
    root: PathBuf,
    ds: Dataset,
    train: PackedSplit,
    val: PackedSplit,
    text: EmbeddingCache,
}

impl Prepared {
    fn new(name: &str, clips: usize) -> Prepared {
        let root = dataset(name, clips);
        let ds = Dataset::open(&root).unwrap();
        let cache = root.join(".diffkfc-cache");
        let train = PackedSplit::open(&ds, "train", &cache, |_, _| {}).unwrap();
        let val = PackedSplit::open(&ds, "val", &cache, |_, _| {}).unwrap();
        let text = embeddings(&train, &val);
        Prepared { root, ds, train, val, text }
    }

    /// A one-device flex trainer of `cfg` writing to `dir` under the dataset, host optimiser.
    fn trainer<'a>(&'a self, cfg: &'a RunConfig, dir: &str) -> Trainer<'a> {
        Trainer {
            cfg,
            ds: &self.ds,
            train: &self.train,
            val: Some(&self.val),
            text: &self.text,
            device: Device::flex(),
            optimiser: StateLocation::Host,
            run_dir: self.root.join(dir),
            init: None,
            parallel: None,
        }
    }
}

fn config() -> RunConfig {
    RunConfig::parse(
        r#"{"model": {"preset": "tiny", "dma_sizes": [2, 0], "dec_layers": 1, "dropout": 0.1},
        "training": {"batch_size": 4, "lr": 0.001, "max_steps": 6, "checkpoint_every": 3, "keep_checkpoints": 2,
                     "val_every": 3, "val_batches": 1, "lambda_pos": 0.1, "lambda_vel": 0.1, "lambda_foot": 0.1}}"#,
    )
    .unwrap()
}

fn losses(run: &Path) -> Vec<(u64, f64)> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v.get("loss").is_some())
        .map(|v| (v["step"].as_u64().unwrap(), v["loss"].as_f64().unwrap()))
        .collect()
}

#[test]
fn resume_is_exact_and_checkpoints_rotate() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("resume", 24);
    let root = &p.root;
    let cfg = config();
    let mk = |dir: &str| p.trainer(&cfg, dir);
    let never = || false;

    let full = mk("full");
    let out = full.run(false, 6, &never, &mut |_| {}).unwrap();
    assert_eq!((out.start_step, out.end_step), (0, 6));
    let a = losses(&root.join("full"));
    assert_eq!(a.len(), 6);
    assert!(a.iter().all(|(_, l)| l.is_finite()));

    let half = mk("half");
    half.run(false, 3, &never, &mut |_| {}).unwrap();
    let mut ckpts = Vec::new();
    let out = half
        .run(true, 6, &never, &mut |e| {
            if let Event::Checkpoint(s, _) = e {
                ckpts.push(s)
            }
        })
        .unwrap();
    assert_eq!((out.start_step, out.end_step), (3, 6));
    assert_eq!(ckpts, vec![6]);
    let b = losses(&root.join("half"));
    assert_eq!(a, b, "resumed run differs from the uninterrupted one");
    // Two checkpoints kept (steps 3 and 6), no temporary files.
    let names: Vec<_> = std::fs::read_dir(root.join("half"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        Checkpoint::list(&root.join("half")).iter().map(|c| c.0).collect::<Vec<_>>(),
        vec![3, 6]
    );
    assert!(names.iter().all(|n| !n.contains(".tmp")), "{names:?}");

    // A stop request writes a checkpoint at the step reached.
    let stopper = mk("stop");
    let calls = std::cell::Cell::new(0);
    let stop = || {
        calls.set(calls.get() + 1);
        calls.get() > 2
    };
    let out = stopper.run(false, 6, &stop, &mut |_| {}).unwrap();
    assert!(out.stopped_early);
    assert_eq!(out.end_step, 2);
    assert_eq!(Checkpoint::list(&root.join("stop")).last().unwrap().0, 2);
    std::fs::remove_dir_all(root).unwrap();
}

/// Training on the sampler's own step (`training.rollout_prob`): the rolled-out x_t changes
/// the losses from the first step, and such a run resumes exactly like any other.
#[test]
fn rollout_training_changes_x_t_and_resumes_exactly() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("rollout", 24);
    let mut cfg = config();
    cfg.training.rollout_prob = 1.0;
    cfg.training.rollout_gap = 100;
    let never = || false;
    p.trainer(&cfg, "full").run(false, 4, &never, &mut |_| {}).unwrap();
    let half = p.trainer(&cfg, "half");
    half.run(false, 2, &never, &mut |_| {}).unwrap();
    half.run(true, 4, &never, &mut |_| {}).unwrap();
    let (a, b) = (losses(&p.root.join("full")), losses(&p.root.join("half")));
    assert_eq!(a.len(), 4);
    assert_eq!(a, b, "resumed rollout run differs from the uninterrupted one");
    let plain = config();
    p.trainer(&plain, "plain").run(false, 1, &never, &mut |_| {}).unwrap();
    let c = losses(&p.root.join("plain"));
    assert!(a[0].1.is_finite() && a[0].1 != c[0].1, "rolled {} plain {}", a[0].1, c[0].1);
    // Two steps of the network start higher: another x_t, another loss.
    let mut two = cfg.clone();
    two.training.rollout_steps = 2;
    p.trainer(&two, "two").run(false, 1, &never, &mut |_| {}).unwrap();
    let d = losses(&p.root.join("two"));
    assert!(d[0].1.is_finite() && d[0].1 != a[0].1, "two steps {} one {}", d[0].1, a[0].1);
    std::fs::remove_dir_all(&p.root).unwrap();
}

/// Weights, EMA and both Adam moments of two checkpoints within `bound` (relative L2).
fn same_state(a: &Checkpoint, b: &Checkpoint, what: &str, bound: f64) {
    for (part, x, y) in [
        ("weights", &a.model, &b.model),
        ("ema", a.ema.as_ref().unwrap(), b.ema.as_ref().unwrap()),
        ("adam m", &a.adam_m, &b.adam_m),
        ("adam v", &a.adam_v, &b.adam_v),
    ] {
        let r = rel(x, y);
        eprintln!("{part}: {what}: relative L2 {r:e}");
        assert!(r < bound, "{part}: {what}: differ by {r:e} (relative L2)");
    }
}

/// Relative L2 distance of two lists of vectors.
fn rel(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    let (mut d, mut n) = (0.0, 0.0);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        d += ((x - y) as f64).powi(2);
        n += (*x as f64).powi(2);
    }
    assert_eq!(a.iter().map(Vec::len).sum::<usize>(), b.iter().map(Vec::len).sum::<usize>());
    (d / n.max(1e-30)).sqrt()
}

/// The optimiser state kept as device tensors (the GPU path, here on flex) trains like the host
/// path, with clipping and the EMA on, and its checkpoints resume exactly.
#[test]
fn device_resident_optimiser_matches_host_and_resumes_exactly() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("device-optim", 24);
    let root = &p.root;
    let cfg = config();
    let mk = |dir: &str, optimiser: StateLocation| Trainer { optimiser, ..p.trainer(&cfg, dir) };
    let never = || false;
    let mut norms = Vec::new();
    mk("host", StateLocation::Host).run(false, 6, &never, &mut |_| {}).unwrap();
    mk("device", StateLocation::Device)
        .run(false, 6, &never, &mut |e| {
            if let Event::Step(r) = e {
                norms.push(r.grad_norm)
            }
        })
        .unwrap();
    assert!(norms.iter().any(|&n| n > 1.0), "clipping never acted: {norms:?}");
    let (h, d) = (losses(&root.join("host")), losses(&root.join("device")));
    for ((s, a), (_, b)) in h.iter().zip(&d) {
        assert!((a - b).abs() <= 1e-5 * a.abs(), "step {s}: host loss {a}, device loss {b}");
    }
    let last = |dir: &str| Checkpoint::latest(&root.join(dir)).unwrap().unwrap();
    let (ch, cd) = (last("host"), last("device"));
    assert_eq!((ch.step, cd.step, ch.adam_step, cd.adam_step), (6, 6, 6, 6));
    same_state(&ch, &cd, "host vs device after 6 steps", 1e-5);
    // 3 + 3 steps on the device path equal 6, and a host checkpoint resumes on the device.
    mk("split", StateLocation::Device).run(false, 3, &never, &mut |_| {}).unwrap();
    mk("split", StateLocation::Device).run(true, 6, &never, &mut |_| {}).unwrap();
    assert_eq!(losses(&root.join("split")), d, "resumed device run differs");
    assert_eq!(last("split").model, cd.model);
    mk("mixed", StateLocation::Host).run(false, 3, &never, &mut |_| {}).unwrap();
    mk("mixed", StateLocation::Device).run(true, 6, &never, &mut |_| {}).unwrap();
    let r = rel(&last("mixed").model, &cd.model);
    assert!(r < 1e-5, "host-then-device run differs by {r:e}");
    std::fs::remove_dir_all(root).unwrap();
}

/// configs/tiny.json (smaller batches and a short budget) lowers the validation loss.
#[test]
fn tiny_config_lowers_validation_loss() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("learn", 300);
    let root = &p.root;
    let mut cfg =
        RunConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/tiny.json"))
            .unwrap();
    cfg.training.batch_size = 8;
    cfg.training.warmup_steps = 10;
    cfg.training.max_steps = 120;
    cfg.training.checkpoint_every = 120;
    cfg.training.val_every = 120;
    cfg.training.val_batches = 2;
    let tr = p.trainer(&cfg, "run");
    tr.run(false, 120, &|| false, &mut |_| {}).unwrap();
    let vals: Vec<(u64, f64)> = std::fs::read_to_string(root.join("run/metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter_map(|v| Some((v["step"].as_u64()?, v["val_loss"].as_f64()?)))
        .collect();
    assert_eq!(vals.iter().map(|v| v.0).collect::<Vec<_>>(), vec![0, 120]);
    eprintln!(
        "configs/tiny.json, 120 steps of batch 8: validation loss {:.4} -> {:.4}",
        vals[0].1, vals[1].1
    );
    assert!(vals[1].1 < vals[0].1 * 0.9, "{vals:?}");
    std::fs::remove_dir_all(root).unwrap();
}

/// A checkpoint written before keyframes had root channels (its stored config does not name
/// them, its keyframe input is 2 x 263 wide) still loads and samples, with pose-only keyframes.
#[test]
fn checkpoint_without_root_channels_loads() {
    use diffkfc_model::diffusion::scheduler::Sampler;
    use diffkfc_model::run::load::load_for_inference;
    use diffkfc_model::sampling::sampler::{sample, Options, Request};
    let device = Device::flex();
    let cfg = RunConfig::parse(r#"{"model": "tiny"}"#).unwrap();
    let old_model = cfg.model.clone().with_root_channels(0);
    let vals: Vec<(Vec<usize>, Vec<f32>)> =
        diffkfc_model::network::params::values(&old_model.init(&device));
    // The config as the old code wrote it: every model key but root_channels.
    let mut json: serde_json::Value = serde_json::from_str(&cfg.to_json()).unwrap();
    json["model"].as_object_mut().unwrap().remove("root_channels");
    let shapes: Vec<Vec<usize>> = vals.iter().map(|v| v.0.clone()).collect();
    let model: Vec<Vec<f32>> = vals.into_iter().map(|v| v.1).collect();
    let zeros: Vec<Vec<f32>> = model.iter().map(|v| vec![0.0; v.len()]).collect();
    let dir = std::env::temp_dir().join(format!("diffkfc-oldckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let ck = Checkpoint {
        step: 7,
        shapes,
        model,
        ema: None,
        adam_step: 7,
        adam_m: zeros.clone(),
        adam_v: zeros,
        config: json.to_string(),
        seed: 0,
        names: Vec::new(), // written by position, as checkpoints were before names
    };
    ck.save(&dir).unwrap();
    let (loaded, denoiser, step) = load_for_inference(&dir, &device).unwrap();
    assert_eq!((step, loaded.model.root_channels), (7, 0));
    let req = Request::text_only(16, 263, vec![0.01; 384], 384, vec![16]);
    let out = sample(
        &denoiser,
        &diffkfc_model::diffusion::Schedule::cosine(1000),
        &req,
        &Options { sampler: Sampler::Ddim(2), ..Options::default() },
        |_, _| {},
    );
    assert!(out.iter().all(|v| v.is_finite()));
    // A checkpoint whose tensors match neither layout is refused with a message.
    let mut bad = ck.clone();
    bad.shapes[0] = vec![3, 3];
    bad.model[0] = vec![0.0; 9];
    bad.adam_m[0] = vec![0.0; 9];
    bad.adam_v[0] = vec![0.0; 9];
    bad.step = 8;
    bad.save(&dir).unwrap();
    let e = load_for_inference(&dir, &device).err().unwrap();
    assert!(
        matches!(&e, diffkfc_model::error::ModelError::File { msg, .. } if msg.contains("do not match")),
        "{e}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// Data parallelism simulated on the CPU (`diffkfc_model::training::parallel`): a batch of 12 samples of
/// different lengths and keyframes split over 3 "devices", every loss term on (L_simple, the
/// keyframe, smoothness, position, velocity and foot losses), no dropout. Shard gradients
/// weighted by each term's count and summed equal the single-device gradient; the plain mean of
/// the shards' own losses does not.
#[test]
fn shard_gradients_weighted_by_counts_equal_the_batch_gradient() {
    use diffkfc_model::training::parallel::{Combine, Counts};
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("shards", 24);
    let root = &p.root;
    let mut cfg = config();
    cfg.model.dropout = 0.0;
    cfg.training.keyframe_loss = 1.0;
    cfg.training.smooth_loss = 1.0;
    cfg.keyframes.rate = 0.1;
    let tr = p.trainer(&cfg, "run");
    let device = Device::flex().autodiff();
    device.seed(5);
    let model = cfg.model.init(&device);
    let loader =
        diffkfc_data::dataset::batch::Loader::new(&p.ds, &p.train, 12, 3, cfg.keyframes.clone());
    let b = loader.batch(0, 0);
    let parts: Vec<Counts> = (0..3).map(|k| Counts::of(&b.shard(4 * k..4 * k + 4))).collect();
    assert!(parts.windows(2).any(|w| w[0] != w[1]), "shards should differ: {parts:?}");
    let mut r = diffkfc_data::rng::Rng::new(9);
    let t: Vec<usize> = (0..12).map(|_| r.below(1000)).collect();
    let noise: Vec<f32> = (0..b.x0.len()).map(|_| r.normal() as f32).collect();
    let one = tr.shard_gradients(&model, &b, &t, &noise, 1, Combine::ByCounts);
    let three = tr.shard_gradients(&model, &b, &t, &noise, 3, Combine::ByCounts);
    let mean = tr.shard_gradients(&model, &b, &t, &noise, 3, Combine::Mean);
    let diff = |a: &[Vec<f32>], b: &[Vec<f32>]| {
        let (mut num, mut den) = (0f64, 0f64);
        for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
            num += ((x - y) as f64).powi(2);
            den += (*y as f64).powi(2);
        }
        (num / den).sqrt()
    };
    let (by_counts, by_mean) = (diff(&three, &one), diff(&mean, &one));
    eprintln!("relative gradient error over 3 shards: by counts {by_counts:.2e}, plain mean {by_mean:.2e}");
    assert!(by_counts < 1e-5, "{by_counts}");
    assert!(by_mean > 1e-3, "{by_mean}");
    std::fs::remove_dir_all(root).unwrap();
}

/// Data-parallel training (`train --devices`) with two replicas, here both on flex with their
/// gradients summed on the host (Burn's all-reduce exists for CUDA only): each replica trains on
/// its half of every batch with that half's timesteps, noise and dropout masks, and the run
/// follows the one-device run; its checkpoints are the one-device format and resume there.
#[test]
fn data_parallel_replicas_follow_the_one_device_run() {
    use diffkfc_model::training::data_parallel::DataParallel;
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let p = Prepared::new("data-parallel", 24);
    let root = &p.root;
    let cfg = config();
    let mk = |dir: &str, replicas: usize| Trainer {
        parallel: (replicas > 1)
            .then(|| DataParallel::host_sum(vec![Device::flex(); replicas]).unwrap()),
        ..p.trainer(&cfg, dir)
    };
    let never = || false;
    let mut norms = [Vec::new(), Vec::new()];
    for (i, (dir, k)) in [("one", 1), ("two", 2)].into_iter().enumerate() {
        mk(dir, k)
            .run(false, 6, &never, &mut |e| {
                if let Event::Step(r) = e {
                    norms[i].push(r.grad_norm)
                }
            })
            .unwrap();
    }
    let (a, b) = (losses(&root.join("one")), losses(&root.join("two")));
    let worst =
        a.iter().zip(&b).map(|((_, x), (_, y))| (x - y).abs() / x.abs()).fold(0.0, f64::max);
    let worst_norm =
        norms[0].iter().zip(&norms[1]).map(|(x, y)| (x - y).abs() / x).fold(0.0, f64::max);
    eprintln!("one device vs two replicas, 6 steps: loss {worst:.2e}, gradient norm {worst_norm:.2e} (largest relative difference)");
    assert_eq!(a.len(), 6);
    assert!(worst < 1e-5 && worst_norm < 1e-4, "loss {worst:e}, gradient norm {worst_norm:e}");
    let last = |dir: &str| Checkpoint::latest(&root.join(dir)).unwrap().unwrap();
    let (c1, c2) = (last("one"), last("two"));
    assert_eq!((c2.step, c2.adam_step, &c2.names, &c2.shapes), (6, 6, &c1.names, &c1.shapes));
    same_state(&c1, &c2, "one device vs two replicas after 6 steps", 1e-4);
    // Three steps on two replicas resumed on one device continue the same run.
    mk("split", 2).run(false, 3, &never, &mut |_| {}).unwrap();
    mk("split", 1).run(true, 6, &never, &mut |_| {}).unwrap();
    let s = losses(&root.join("split"));
    let worst =
        a.iter().zip(&s).map(|((_, x), (_, y))| (x - y).abs() / x.abs()).fold(0.0, f64::max);
    assert!(worst < 1e-5, "resumed on one device: loss differs by {worst:e}");
    // A batch smaller than the replicas is refused before anything is written.
    let e = Trainer {
        parallel: Some(DataParallel::host_sum(vec![Device::flex(); 5]).unwrap()),
        ..mk("five", 1)
    }
    .run(false, 1, &never, &mut |_| {})
    .unwrap_err()
    .to_string();
    assert!(e.contains("batch_size 4 is smaller than the 5 devices"), "{e}");
    assert!(!root.join("five").exists());
    let _ = std::fs::remove_dir_all(root);
}

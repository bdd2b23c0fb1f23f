//! `diffkfc bench`: one JSON line per case (median milliseconds and achieved GFLOP/s of the
//! matmuls), optionally side by side with the PyTorch reference and the ratios.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use burn::prelude::Device;
use clap::Args;
use diffkfc_model::bench::{matmul_peak, Sampling, TrainStep};
use diffkfc_model::run::config::RunConfig;
use diffkfc_model::training::memory::device_memory;
use diffkfc_model::DiffKfcConfig;
use serde_json::{json, Value};

pub const AFTER_HELP: &str = "\
Cases: train (forward + backward + Adam), call (one guided sampling call: both keyframe-guidance
branches in a batch of 2, encoder included), call-cached (the same, decoder only with the
encoder output cached, as in every denoising step after the first), ddim (a full DDIM sample,
keyframe + transition guidance), loader (packed-cache batches/s; --data, else a generated set),
sample (a whole keyed sample as `diffkfc sample` makes it with the default pipeline: the quick
start's 147-frame walk and wave, synthetic clip 32 of the default set keyed at 5%; --config a
model or run directory).
Examples:
  diffkfc bench --config paper
  diffkfc bench --config paper --torch /path/to/venv/bin/python   (side by side, with ratios)
  diffkfc bench --config paper --cases train,call,call-cached --torch PY --rounds 3
                                                         (alternating, median ratio of 3 rounds)
  diffkfc bench --config tiny --quick                              (smoke test)
  diffkfc bench --config models/mid-synth --cases sample --repeats 5  (the quick start's sample)";

#[derive(Args)]
pub struct BenchArgs {
    /// Model: a preset (paper, small, mid, tiny; torch-tiny is the PyTorch reference's own
    /// small network), a run config file, or a run or model directory (models/mid-synth).
    #[arg(long, default_value = "paper")]
    config: String,
    /// Comma-separated cases: train, call, call-cached, ddim, loader, sample.
    #[arg(long, default_value = "train,call,call-cached,ddim,loader")]
    cases: String,
    /// Training batch size (the sampling cases generate one motion: a guidance batch of 2).
    #[arg(long, default_value_t = 8)]
    batch: usize,
    /// Motion length of the benchmarked cases, frames (196 = HumanML3D's longest).
    #[arg(long, default_value_t = 196)]
    frames: usize,
    /// Timed runs per case after one warm-up (the median is reported).
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Steps of the DDIM sampling case.
    #[arg(long, default_value_t = 50)]
    ddim_steps: usize,
    /// Dataset for the loader case (default: a generated 300-clip set in a temporary folder).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Python with torch: also run the PyTorch reference in this process's run and print ratios.
    #[arg(long)]
    torch: Option<PathBuf>,
    /// With --torch: alternate diffkfc's timed cases and the reference this many times and print
    /// every round's ratios and their median (this machine's timings drift between minutes).
    #[arg(long, default_value_t = 1)]
    rounds: usize,
    /// The PyTorch reference: scripts/torch_reference.py runs ../shared/bench's network at every
    /// preset (eager, or compiled with --torch-compile); ../shared/bench/reference_diffkfc.py
    /// itself knows only paper and torch-tiny.
    #[arg(long, default_value = "scripts/torch_reference.py")]
    reference: PathBuf,
    /// With --torch: run the reference under torch.compile (inductor; its first step, the
    /// compilation, is reported apart and not timed).
    #[arg(long, requires = "torch")]
    torch_compile: bool,
    /// Smoke test: one run per case, 2 DDIM steps, 20 loader batches.
    #[arg(long)]
    quick: bool,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

/// Every case `--cases` knows.
const CASES: [&str; 6] = ["train", "call", "call-cached", "ddim", "loader", "sample"];

fn model_config(spec: &str) -> Result<DiffKfcConfig> {
    if let Some(c) = DiffKfcConfig::preset(spec) {
        return Ok(c);
    }
    let path = std::path::Path::new(spec);
    // A run or model directory stands for the network it holds.
    let file = if path.is_dir() { path.join("config.json") } else { path.to_path_buf() };
    if file.is_file() {
        return Ok(RunConfig::load(&file)?.model);
    }
    bail!("--config: '{spec}' is neither a preset (paper, small, mid, tiny, torch-tiny), a config file nor a run or model directory")
}

/// A case's timing: the median wall time (ms) of its timed calls, every call's, and the
/// process's CPU utilisation over them (CPU seconds / wall seconds: 2.0 keeps two cores busy),
/// where the platform reports CPU time.
type Timing = (f64, Vec<f64>, Option<f64>);

/// Times `runs` calls of `f` after one warm-up call.
fn time_ms<T>(runs: usize, f: impl FnMut() -> T) -> Timing {
    time_ms_probed(runs, f, || None).0
}

/// [`time_ms`], with `probe` read after each timed call (outside the timing and the CPU
/// utilisation): its readings in run order.
fn time_ms_probed<T>(
    runs: usize,
    mut f: impl FnMut() -> T,
    mut probe: impl FnMut() -> Option<f64>,
) -> (Timing, Vec<f64>) {
    std::hint::black_box(f());
    let (mut cpu, mut wall, mut ms, mut readings) = (Some(0.0), 0.0, Vec::new(), Vec::new());
    for _ in 0..runs.max(1) {
        let (c0, t0) = (cpu_seconds(), Instant::now());
        std::hint::black_box(f());
        let dt = t0.elapsed().as_secs_f64();
        cpu = cpu.zip(c0.zip(cpu_seconds())).map(|(s, (a, b))| s + b - a);
        wall += dt;
        ms.push(dt * 1e3);
        readings.extend(probe());
    }
    let util = cpu.map(|c| c / f64::max(wall, 1e-9));
    ((median(&ms), ms, util), readings)
}

/// The median of `v` (the mean of the middle two for an even count; NaN when empty).
fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => (v[n / 2 - 1] + v[n / 2]) / 2.0,
    }
}

/// CPU time (user + system, seconds) this process has used, where the platform reports it.
fn cpu_seconds() -> Option<f64> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: getrusage writes one plain struct that we own and read only after success.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } == 0 {
            let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
            return Some(t(u.ru_utime) + t(u.ru_stime));
        }
    }
    None
}

/// This run's measured matrix-product peak (GFLOP/s), for each line's fraction of it.
static PEAK: std::sync::OnceLock<f64> = std::sync::OnceLock::new();

fn line(case: &str, (ms, runs, util): Timing, gflop: f64, extra: Value) -> Value {
    let rate = gflop / (ms / 1e3);
    let mut v = json!({"case": case, "impl": "diffkfc", "ms": ms, "runs_ms": runs, "gflop": gflop, "gflops": rate, "fraction_of_peak": rate / PEAK.get().copied().unwrap_or(f64::NAN), "cpu_utilisation": util});
    if let (Some(o), Value::Object(e)) = (v.as_object_mut(), extra) {
        o.extend(e);
    }
    v
}

/// The reference's name for `--config`: the shared script calls torch-tiny "tiny" and has only
/// that and paper; scripts/torch_reference.py takes every preset by its own name.
fn reference_preset(a: &BenchArgs) -> Result<String> {
    match (a.config.as_str(), shared_reference(a)) {
        (c, false) if ["paper", "small", "mid", "tiny", "torch-tiny"].contains(&c) => Ok(c.into()),
        ("paper", true) => Ok("paper".into()),
        ("torch-tiny", true) => Ok("tiny".into()),
        _ if a.torch.is_none() => Ok(String::new()),
        (c, _) => bail!("--torch: {} has no network for --config {c} (scripts/torch_reference.py has paper, small, mid, tiny, torch-tiny)", a.reference.display()),
    }
}

/// Whether `--reference` is ../shared/bench's own script (its names and flags, not ours).
fn shared_reference(a: &BenchArgs) -> bool {
    a.reference.file_name().is_some_and(|n| n == "reference_diffkfc.py")
}

fn torch_reference(python: &PathBuf, a: &BenchArgs, preset: &str, repeats: usize) -> Result<Value> {
    if !a.reference.exists() {
        bail!("--reference: {} not found", a.reference.display());
    }
    let mut cmd = Command::new(python);
    cmd.arg(&a.reference).args([
        "--config",
        preset,
        "--batch",
        &a.batch.to_string(),
        "--frames",
        &a.frames.to_string(),
        "--steps",
        &repeats.max(1).to_string(),
    ]);
    if a.torch_compile {
        cmd.arg("--compile");
    }
    // On a GPU the reference runs on the GPU too (the first CUDA device; wgpu's adapter is the
    // machine's GPU as well), so the ratio compares like with like.
    if !shared_reference(a) && crate::device::is_gpu(&a.device) {
        cmd.args(["--device", "cuda"]);
    }
    let out = cmd.output().with_context(|| format!("--torch: running {}", python.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().rev().find(|l| l.trim_start().starts_with('{'));
    match (out.status.success(), last) {
        (true, Some(l)) => {
            Ok(serde_json::from_str(l)
                .with_context(|| format!("--torch: unreadable output: {l}"))?)
        }
        _ => bail!(
            "--torch: the reference failed: {}",
            String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("no output")
        ),
    }
}

pub fn run(a: BenchArgs) -> Result<()> {
    let cfg = model_config(&a.config)?;
    let cases = checked_cases(&a, &cfg)?;
    let device = crate::device::parse(&a.device)?;
    let runs = if a.quick { 1 } else { a.repeats };
    let preset = reference_preset(&a)?;
    // Every run records the machine: CPU, vector extensions, threads, matrix-product peak; each
    // model case's GFLOP/s then reads as a fraction of it.
    let machine = diffkfc_model::bench::machine(
        if a.quick { 256 } else { 2048 },
        if a.quick { 2 } else { 4 },
    );
    let peak = machine["matmul_peak_gflops"].as_f64().unwrap_or(f64::NAN);
    emit(machine);
    let _ = PEAK.set(peak);
    let rounds = if a.torch.is_some() { a.rounds } else { 1 };
    let mut ratios: Vec<BTreeMap<&str, f64>> = Vec::new();
    for round in 1..=rounds {
        // DDIM and the loader have no PyTorch counterpart: first round only.
        let ours = model_cases(&a, &cfg, &cases, runs, &device, round == 1)?;
        if round == 1 && cases.contains(&"sample") {
            sample_case(&a, runs)?;
        }
        if round == 1 && cases.contains(&"loader") {
            let items_per_s = loader_case(&a)?;
            if let (Some(&ms), Some(ips)) = (ours.get("train_step"), items_per_s) {
                emit(throughput_line(a.batch, ms, ips));
            }
        }
        let Some(py) = &a.torch else { continue };
        let t = torch_reference(py, &a, &preset, runs)?;
        emit(json!({"case": "pytorch", "round": round, "reference": t}));
        ratios.push(round_ratios(&ours, &t, round));
    }
    if rounds > 1 {
        emit(ratio_summary(&ratios, rounds));
    }
    Ok(())
}

/// The cases asked for, once the arguments are checked against them and the config.
fn checked_cases<'a>(a: &'a BenchArgs, cfg: &DiffKfcConfig) -> Result<Vec<&'a str>> {
    let cases: Vec<&str> = a.cases.split(',').map(str::trim).filter(|c| !c.is_empty()).collect();
    if let Some(bad) = cases.iter().find(|c| !CASES.contains(c)) {
        bail!("--cases: unknown case '{bad}' ({})", CASES.join(", "));
    }
    if cases.contains(&"sample") && !std::path::Path::new(&a.config).is_dir() {
        bail!("--cases sample: --config '{}' must be a model or run directory (its weights generate the sample)", a.config);
    }
    if a.batch == 0 || a.frames == 0 || a.frames > cfg.max_frames {
        bail!("--batch/--frames: need a batch >= 1 and 1..={} frames", cfg.max_frames);
    }
    if a.rounds == 0 {
        bail!("--rounds: need at least 1");
    }
    Ok(cases)
}

/// Cases PyTorch also times, with the key of its time in the reference's output.
const TORCH_KEYS: [(&str, &str); 3] = [
    ("train_step", "train_step_ms"),
    ("sampling_call", "cfg_call_ms"),
    ("sampling_call_cached", "cfg_call_ms"),
];

/// One round's ratios of our times to PyTorch's `t`, printed; returned by case.
fn round_ratios(
    ours: &BTreeMap<&'static str, f64>,
    t: &Value,
    round: usize,
) -> BTreeMap<&'static str, f64> {
    let r: BTreeMap<&str, f64> = TORCH_KEYS
        .iter()
        .filter_map(|&(k, tk)| Some((k, ours.get(k)? / t[tk].as_f64()?)))
        .collect();
    let mut line = json!({"case": "ratio", "round": round, "note": "diffkfc ms / PyTorch ms, same machine, same run (<= 1.0: as fast or faster)"});
    r.iter().for_each(|(k, v)| line[*k] = json!(v));
    emit(line);
    r
}

/// Median, min and max over the rounds of each case's ratio.
fn ratio_summary(ratios: &[BTreeMap<&str, f64>], rounds: usize) -> Value {
    let mut line = json!({"case": "ratio_summary", "rounds": rounds, "note": "median, min and max of the rounds' ratios"});
    for (k, _) in TORCH_KEYS {
        let mut v: Vec<f64> = ratios.iter().filter_map(|r| r.get(k).copied()).collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        line[k] = json!({"median": median(&v), "min": v[0], "max": v[v.len() - 1]});
    }
    line
}

fn emit(v: Value) {
    println!("{v}");
}

/// What a GPU device's memory pools hold after a case (MB; null on the CPU backends): the
/// reserved bytes are the high-water mark of the run so far.
fn memory(device: &Device) -> Value {
    match device_memory(device) {
        Some(m) => {
            json!({"in_use_mb": m.in_use as f64 / 1e6, "reserved_mb": m.reserved as f64 / 1e6})
        }
        None => Value::Null,
    }
}

/// Times the model cases asked for, printing a line each; returns the medians by case name.
fn model_cases(
    a: &BenchArgs,
    cfg: &DiffKfcConfig,
    cases: &[&str],
    runs: usize,
    device: &Device,
    with_ddim: bool,
) -> Result<BTreeMap<&'static str, f64>> {
    let n = a.frames;
    let common =
        json!({"config": a.config, "frames": n, "device": a.device, "threads": rayon_threads()});
    let mut ours = BTreeMap::new();
    let out = |case: &str, t, gflop, extra: Value| emit_case(device, case, t, gflop, extra);
    if cases.contains(&"train") {
        ours.insert("train_step", train_case(a, cfg, runs, device, &common));
    }
    let ddim = with_ddim && cases.contains(&"ddim");
    if !(cases.contains(&"call") || cases.contains(&"call-cached") || ddim) {
        return Ok(ours);
    }
    let model = cfg.init(device);
    let s = Sampling::new(&model, cfg, 1, n);
    let f = s.flops(cfg);
    if cases.contains(&"call") {
        let t = time_ms(runs * 3, || s.call(true));
        ours.insert("sampling_call", t.0);
        out(
            "sampling_call",
            t,
            f.total() / 1e9,
            json!({"batch": 2, "encoder": true, "decoder": s.decoder(), "common": common}),
        );
    }
    if cases.contains(&"call-cached") {
        let t = time_ms(runs * 3, || s.call(false));
        ours.insert("sampling_call_cached", t.0);
        out(
            "sampling_call_cached",
            t,
            f.decoder / 1e9,
            json!({"batch": 2, "encoder": false, "decoder": s.decoder(), "common": common}),
        );
    }
    if ddim {
        let steps = if a.quick { 2 } else { a.ddim_steps };
        let mut finite = true;
        let t = time_ms(runs.min(2), || finite &= s.sample(steps).iter().all(|v| v.is_finite()));
        out(
            "ddim",
            t,
            (f.encoder + steps as f64 * f.decoder) / 1e9,
            json!({"steps": steps, "kf_guidance": 2.5, "transition_guidance": 100.0, "finite": finite, "common": common}),
        );
    }
    Ok(ours)
}

/// The `train` case: training steps of batch --batch, each on the CPU paired with a peak
/// reading taken right after it (other tenants slow both alike, so the pairs' ratio drifts
/// less than one reading's); prints its line, returns the median step (ms).
fn train_case(
    a: &BenchArgs,
    cfg: &DiffKfcConfig,
    runs: usize,
    device: &Device,
    common: &Value,
) -> f64 {
    let mut w = TrainStep::new(cfg, a.batch, a.frames, device);
    let cpu = !crate::device::is_gpu(&a.device);
    let probe_n = if a.quick { 256 } else { 2048 };
    let (t, peaks) = time_ms_probed(runs, || w.step(), || cpu.then(|| matmul_peak(probe_n, 2)));
    let ms = t.0;
    let gflop = w.flops(cfg) / 1e9;
    let paired: Vec<f64> =
        t.1.iter().zip(&peaks).map(|(ms, peak)| gflop / (ms / 1e3) / peak).collect();
    let [f, bw, up] = w.phases.map(|s| s * 1e3);
    let extra = json!({"batch": a.batch, "last_step_phases_ms": {"forward": f, "backward": bw, "host_update": up},
        "adjacent_peaks_gflops": peaks, "fraction_of_adjacent_peak": cpu.then(|| median(&paired)),
        "common": common});
    emit_case(device, "train_step", t, gflop, extra);
    ms
}

/// A model case's line, with the device's memory after it.
fn emit_case(device: &Device, case: &str, t: Timing, gflop: f64, mut extra: Value) {
    extra["device_memory"] = memory(device);
    emit(line(case, t, gflop, extra));
}

/// The `sample` case: the quick start's keyed sample, generated `runs` times after a warm-up
/// (the model, the text encoder and the keys are loaded once, outside the timing).
fn sample_case(a: &BenchArgs, runs: usize) -> Result<()> {
    let tmp = std::env::temp_dir().join(format!("diffkfc-bench-sample-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let (clip, feats) = diffkfc_synth::clip(diffkfc_synth::Body::HumanMl3d, 0, 32);
    let source = tmp.join("000032.npy");
    let d = diffkfc_data::T2M.feature_dim();
    diffkfc_data::io::npy::write(&source, &[feats.len() / d, d], &feats)?;
    let (src, out) = (source.display().to_string(), tmp.join("out").display().to_string());
    let argv = [
        "sample",
        "--checkpoint",
        &a.config,
        "--text",
        &clip.meta.captions[0],
        "--from",
        &src,
        "--keyframe-rate",
        "0.05",
        "--num-samples",
        "1",
        "--out",
        &out,
        "--device",
        &a.device,
    ];
    let prepared = super::sample::Prepared::new(&argv);
    let _ = std::fs::remove_dir_all(&tmp);
    let p = prepared?;
    let mut failed = None;
    let t = time_ms(runs, || {
        if let Err(e) = p.generate() {
            failed = Some(e.to_string());
        }
    });
    if let Some(e) = failed {
        bail!("--cases sample: the sample failed: {e}");
    }
    emit(
        json!({"case": "sample", "impl": "diffkfc", "ms": t.0, "runs_ms": t.1, "cpu_utilisation": t.2,
        "config": a.config, "frames": p.frames, "keys": p.keys, "text": clip.meta.captions[0],
        "pipeline": "default (track fit: DDIM-20 twice, text guidance; rigid refit; feet steps)",
        "threads": rayon_threads()}),
    );
    Ok(())
}

/// Training throughput with the loader, from the two measured cases, their times added: motions
/// per second and hours per 10 000 steps. (The trainer draws the next batch on another thread
/// while a step runs, so on a machine with a core to spare this is a lower bound.)
fn throughput_line(batch: usize, step_ms: f64, loader_items_per_s: f64) -> Value {
    let step_s = step_ms / 1e3 + batch as f64 / loader_items_per_s;
    json!({"case": "train_throughput", "impl": "diffkfc", "batch": batch,
        "motions_per_s": batch as f64 / step_s, "hours_per_10k_steps": step_s * 1e4 / 3600.0,
        "derived_from": ["train_step", "loader"]})
}

/// The loader case; its batches' items per second.
fn loader_case(a: &BenchArgs) -> Result<Option<f64>> {
    let tmp = std::env::temp_dir().join(format!("diffkfc-bench-{}", std::process::id()));
    let dir = match &a.data {
        Some(d) => d.clone(),
        None => {
            diffkfc_synth::write_dataset(
                &tmp,
                &diffkfc_synth::SynthSpec::legacy(300, 0),
                2,
                &|_, _| {},
            )?;
            tmp.clone()
        }
    };
    let v = diffkfc_data::dataset::loader_bench::run(
        &dir,
        "train",
        if a.quick { 20 } else { 200 },
        64,
        1,
        crate::progress::bar("caching"),
    );
    let _ = std::fs::remove_dir_all(&tmp);
    let v = v?;
    let items_per_s = v["items_per_s"].as_f64();
    emit(v);
    Ok(items_per_s)
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

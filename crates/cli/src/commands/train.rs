//! `diffkfc train`: diffusion training with keyframe masking, checkpoints and exact resume.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use clap::Args;
use diffkfc_data::dataset::cache::{default_cache_dir, PackedSplit};
use diffkfc_data::dataset::Dataset;
use diffkfc_model::run::checkpoint::Checkpoint;
use diffkfc_model::run::config::RunConfig;
use diffkfc_model::run::dir::RunDir;
use diffkfc_model::run::lock::{Claim, RunLock};
use diffkfc_model::text::cache::{embed_captions, EmbeddingCache};
use diffkfc_model::training::optim::StateLocation;
use diffkfc_model::training::trainer::{Event, TrainOutcome, Trainer};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Args)]
pub struct TrainArgs {
    /// Run config (configs/tiny.json, small.json, paper-humanml3d.json, paper-kit.json).
    #[arg(long, required_unless_present = "recipe")]
    pub(crate) config: Option<PathBuf>,
    /// Train a model's whole recipe instead (configs/mid-synth.recipe.json): its synthetic
    /// sets, then every stage from the one before, into --out (default runs/`<model>`); run
    /// again, it continues where it stopped. Ends with the model exported to `<out>/model`.
    #[arg(long, conflicts_with_all = ["config", "resume", "init", "max_steps", "seed", "data"])]
    pub(crate) recipe: Option<PathBuf>,
    /// Dataset root (overrides data.dir of the config).
    #[arg(long)]
    pub(crate) data: Option<PathBuf>,
    /// Run directory (default: runs/`<config name>`).
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
    /// Continue from the run directory's latest checkpoint.
    #[arg(long, conflicts_with = "init")]
    pub(crate) resume: bool,
    /// Write a new run into a non-empty directory that is not a run (only the run's own file
    /// names are written).
    #[arg(long)]
    pub(crate) force: bool,
    /// Start a new run from these weights (a run or model directory, or a checkpoint file):
    /// every parameter it has with the same name and shape is taken, the model's others
    /// (an extension the source lacks, such as model.key_input) start as initialised.
    #[arg(long, value_name = "CHECKPOINT")]
    pub(crate) init: Option<PathBuf>,
    /// Stop at this step (default: training.max_steps of the config).
    #[arg(long)]
    pub(crate) max_steps: Option<usize>,
    /// Stop cleanly (with a checkpoint) after this long: 90s, 10m, 2h.
    #[arg(long, value_parser = parse_duration)]
    pub(crate) time_budget: Option<Duration>,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    pub(crate) device: String,
    /// Train data-parallel on these devices (cuda:0,cuda:1,...): a replica of the model on
    /// each, a shard of every batch each, gradients summed by Burn's all-reduce (CUDA only in
    /// Burn 0.22). Checkpoints and resume are those of a one-device run.
    #[arg(long, conflicts_with = "device", value_name = "cuda:0,cuda:1,...")]
    pub(crate) devices: Option<String>,
    /// Where Adam's moments and the EMA live: host (one fused pass over host vectors: the
    /// default for flex and ndarray) or device (tensor operations on the device, weights never
    /// leave it: the default for wgpu and cuda). Checkpoints are the same either way.
    #[arg(long, value_name = "host|device")]
    pub(crate) optimiser_state: Option<StateLocation>,
    /// Overrides training.seed.
    #[arg(long)]
    pub(crate) seed: Option<u64>,
}

/// `--time-budget`: humantime's durations (90s, 10m, 1h30m, 2h) or a bare number of seconds.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let t = s.trim();
    let d = match t.parse::<f64>() {
        Ok(secs) if secs.is_finite() && secs > 0.0 => Duration::from_secs_f64(secs),
        Ok(_) => return Err(format!("'{s}' must be positive")),
        Err(_) => humantime::parse_duration(t)
            .map_err(|e| format!("'{s}' is not a duration like 90s, 10m or 2h ({e})"))?,
    };
    if d.is_zero() {
        return Err(format!("'{s}' must be positive"));
    }
    Ok(d)
}

/// Refuse a CPU run whose estimated peak memory exceeds what the machine has free.
fn check_memory(cfg: &RunConfig, device: &str) -> Result<()> {
    if !matches!(device, "flex" | "cpu" | "ndarray") {
        return Ok(());
    }
    use diffkfc_model::training::memory;
    let frames = diffkfc_data::dataset::MAX_FRAMES;
    let need = memory::training_bytes(cfg, frames);
    if let Some(free) = memory::available_bytes() {
        if need > free {
            let fits = ((free * 0.8 - memory::fixed_bytes(cfg))
                / memory::per_sample_bytes(cfg, frames))
            .floor()
            .max(0.0);
            bail!("training.batch_size: {} needs about {:.1} GB but {:.1} GB is available to this process (free memory, cgroup and ulimit limits); at most about {fits} fits", cfg.training.batch_size, need / 1e9, free / 1e9);
        }
    }
    Ok(())
}

pub fn run(a: TrainArgs) -> Result<()> {
    // Clap requires --config without --recipe, and main sends --recipe to `recipe::run`.
    let config = a.config.clone().context("--config: required (or --recipe)")?;
    let (cfg, data, max_steps) = resolve_config(&a, &config)?;
    let run = RunDir::new(a.out.clone().unwrap_or_else(|| {
        let stem = config.file_stem().map(|s| s.to_string_lossy().into_owned());
        PathBuf::from("runs").join(stem.unwrap_or_else(|| "run".into()))
    }));
    let claim = if a.resume { Claim::Resume } else { Claim::New { force: a.force } };
    RunLock::check(&run.path, claim)?;
    if let Some(p) = a.init.as_ref().filter(|p| !p.exists()) {
        bail!("--init: {} does not exist", p.display());
    }
    let parallel = a.devices.as_deref().map(crate::device::parse_many).transpose()?;
    let device = match &parallel {
        Some(dp) => dp.devices()[0].clone(),
        None => crate::device::parse(&a.device)?,
    };
    check_memory(&cfg, if parallel.is_some() { "cuda" } else { &a.device })?;
    let d = TrainingData::open(&cfg, &data)?;
    let _held = RunLock::claim(&run.path, claim)?;
    if a.resume {
        run.check_resumable(&cfg, &d.ds.mean)?;
    }
    let init = init_weights(&a, &run);
    run.prepare(&cfg, &d.ds.mean, &d.ds.std)?;
    if !a.resume {
        run.record_init(init.as_deref())?;
    }

    let signal = crate::signals::StopSignal::install()?;
    let started = Instant::now();
    let budget = a.time_budget;
    let stop = || signal.requested() || budget.is_some_and(|b| started.elapsed() >= b);
    let pb = progress_bar(max_steps);
    let trainer = Trainer {
        cfg: &cfg,
        ds: &d.ds,
        train: &d.train,
        val: d.val.as_ref(),
        text: &d.text,
        optimiser: a.optimiser_state.unwrap_or_else(|| StateLocation::for_device(&device)),
        device,
        run_dir: run.path.clone(),
        init: init.clone(),
        parallel,
    };
    let mut first: Option<(usize, f64)> = None;
    let outcome = trainer.run(a.resume, max_steps, &stop, &mut |e| {
        show_event(&pb, e, &mut first, init.as_deref())
    })?;
    pb.finish_and_clear();
    run.write_loss_plot()?;
    finish(&run, &outcome, first, &signal, started.elapsed().as_secs_f64());
    Ok(())
}

/// The run's summary; an interrupted run then exits with the signal's code.
fn finish(
    run: &RunDir,
    outcome: &TrainOutcome,
    first: Option<(usize, f64)>,
    signal: &crate::signals::StopSignal,
    secs: f64,
) {
    let why = if signal.requested() {
        " (interrupted)"
    } else if outcome.stopped_early {
        " (time budget reached)"
    } else {
        ""
    };
    print_summary(run, outcome, first, why, secs);
    if let Some(code) = signal.exit_code() {
        // A script must be able to tell an interrupted run (checkpoint written) from a finished one.
        eprintln!(
            "{}: checkpoint written at step {}; `--resume` continues",
            signal.name(),
            outcome.end_step
        );
        std::process::exit(code);
    }
}

/// The weights the run starts from: `--init`, or, resuming a run killed before its first
/// checkpoint (which starts it again at step 0, as the user meant), the `--init` it was started
/// with.
fn init_weights(a: &TrainArgs, run: &RunDir) -> Option<PathBuf> {
    if !(a.resume && Checkpoint::list(&run.path).is_empty()) {
        return a.init.clone();
    }
    let init = run.recorded_init();
    let from = init.as_ref().map_or(String::new(), |p| format!(" from --init {}", p.display()));
    eprintln!(
        "--resume: {} holds no checkpoint yet; starting it at step 0{from}",
        run.path.display()
    );
    init
}

fn progress_bar(max_steps: usize) -> ProgressBar {
    let pb = ProgressBar::new(max_steps as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] step {pos}/{len} {per_sec} ETA {eta}")
            .expect("template")
            .progress_chars("=> "),
    );
    pb
}

/// A training event on the progress bar: the step's loss (and device memory), or the warm
/// start's fresh parameters.
fn show_event(
    pb: &ProgressBar,
    e: Event,
    first: &mut Option<(usize, f64)>,
    init: Option<&std::path::Path>,
) {
    match e {
        Event::Step(r) => {
            first.get_or_insert((r.step, r.loss));
            pb.set_position(r.step as u64);
            let mem = r.device_memory.map_or(String::new(), |m| {
                format!(
                    ", device memory {:.0} MB in use, {:.0} MB reserved",
                    m.in_use as f64 / 1e6,
                    m.reserved as f64 / 1e6
                )
            });
            pb.set_message(format!("loss {:.4}{mem}", r.loss));
        }
        Event::Checkpoint(_, _) => {}
        Event::WarmStart { fresh, widened } => pb.suspend(|| {
            let list = |v: &[String]| if v.is_empty() { "none".to_string() } else { v.join(", ") };
            eprintln!(
                "started from {}; initialised: {}",
                init.map_or(String::new(), |p| p.display().to_string()),
                list(&fresh)
            );
            if !widened.is_empty() {
                eprintln!(
                    "feed-forward blocks widened (new units add nothing yet): {}",
                    list(&widened)
                );
            }
        }),
    }
}

/// The config with the flags applied, the dataset it trains on and the step it stops at.
fn resolve_config(a: &TrainArgs, config: &Path) -> Result<(RunConfig, PathBuf, usize)> {
    let mut cfg = RunConfig::load(config)?;
    if let Some(s) = a.seed {
        cfg.training.seed = s;
    }
    if let Some(d) = &a.data {
        cfg.data.dir = Some(d.display().to_string());
    }
    let data = cfg.data.dir.clone().map(PathBuf::from).context(
        "--data: no dataset given (make one with `diffkfc data synth --out work/synth`)",
    )?;
    let max_steps = a.max_steps.unwrap_or(cfg.training.max_steps);
    if max_steps == 0 {
        let flag = if a.max_steps.is_some() { "--max-steps" } else { "training.max_steps" };
        bail!("{flag}: 0 trains nothing and writes no checkpoint; give at least 1");
    }
    cfg.training.check_stop(max_steps)?;
    Ok((cfg, data, max_steps))
}

/// A dataset ready for training: its packed train and validation splits and the captions'
/// text embeddings.
struct TrainingData {
    ds: Dataset,
    train: PackedSplit,
    val: Option<PackedSplit>,
    text: EmbeddingCache,
}

impl TrainingData {
    fn open(cfg: &RunConfig, data: &std::path::Path) -> Result<TrainingData> {
        let ds = Dataset::open(data)?;
        if ds.dim() != cfg.model.feat_dim {
            bail!(
                "{}: features are {}-dimensional but model.feat_dim is {}",
                data.display(),
                ds.dim(),
                cfg.model.feat_dim
            );
        }
        let cache_dir = default_cache_dir(&ds);
        let split = |name: &str, what: &str| {
            PackedSplit::open(&ds, name, &cache_dir, crate::progress::bar(what))
        };
        let train = split(&cfg.data.train_split, "caching train")?;
        if train.items.is_empty() {
            bail!(
                "{}: split '{}' has no usable items (run `diffkfc data check`)",
                data.display(),
                cfg.data.train_split
            );
        }
        let val = split(&cfg.data.val_split, "caching val").ok();
        for (id, why) in train.skipped.iter().take(3) {
            eprintln!("warning: skipped clip {id}: {why}");
        }
        let mut splits = vec![&train];
        splits.extend(val.as_ref());
        let words = cfg.model.text_words;
        let text = embed_captions(&ds, &splits, words, crate::progress::bar("embedding"))?;
        if text.dim != cfg.model.text_width() {
            bail!(
                "model.text_dim is {} but the text encoder gives {}",
                cfg.model.text_dim,
                text.dim / (1 + words)
            );
        }
        Ok(TrainingData { ds, train, val, text })
    }
}

/// What a training call did: steps, time, first and last training loss, validation loss.
fn print_summary(
    run: &RunDir,
    outcome: &TrainOutcome,
    first: Option<(usize, f64)>,
    why: &str,
    secs: f64,
) {
    let steps = outcome.end_step - outcome.start_step;
    println!(
        "{}: steps {}..{}{why} in {secs:.1} s ({:.2} s/step)",
        run.path.display(),
        outcome.start_step,
        outcome.end_step,
        secs / steps.max(1) as f64
    );
    if let (Some((s0, l0)), Some(last)) = (first, &outcome.last) {
        println!("  train loss: step {s0} {l0:.4} -> step {} {:.4}", last.step, last.loss);
    }
    let vals: Vec<(usize, f64)> =
        run.metrics().iter().filter_map(|m| Some((m.step, m.val_loss?))).collect();
    if let (Some(a), Some(b)) = (vals.first(), vals.last()) {
        println!(
            "  validation loss (EMA weights): step {} {:.4} -> step {} {:.4}",
            a.0, a.1, b.0, b.1
        );
    }
    println!("  checkpoints, metrics.jsonl, loss.svg in {}", run.path.display());
}

#[cfg(test)]
mod tests {
    use super::parse_duration;
    use std::time::Duration;

    #[test]
    fn durations_with_units_or_bare_seconds() {
        assert_eq!(parse_duration("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("10m"), Ok(Duration::from_secs(600)));
        assert_eq!(parse_duration("1h 30m"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration(" 2.5 "), Ok(Duration::from_secs_f64(2.5)));
        for bad in ["soon", "-3", "0", "0s", "10 parsecs", "nan"] {
            let e = parse_duration(bad).unwrap_err();
            assert!(e.contains(&format!("'{bad}'")), "{bad}: {e}");
        }
    }
}

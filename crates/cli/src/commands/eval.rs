//! `diffkfc eval`: evaluate a checkpoint (Tables 2 and 4); `eval train-evaluator`: the
//! text-motion evaluator it needs.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use diffkfc_data::dataset::cache::{default_cache_dir, PackedSplit};
use diffkfc_data::dataset::Dataset;
use diffkfc_data::io::ownership::{self, Output};
use diffkfc_data::keyframes::Strategy;
use diffkfc_eval::evaluator::{eval_length, ContrastiveEvaluator, TextMotionEvaluator};
use diffkfc_eval::protocol::{self, Protocol, Setting};
use diffkfc_eval::report;
use diffkfc_eval::t2m::{split_captions, T2mEvaluator};
use diffkfc_eval::text_motion::Gaussian;
use diffkfc_eval::train_evaluator::embed_split;
use diffkfc_model::sampling::sampler;
use diffkfc_model::sampling::session::Session;
use diffkfc_model::text::cache::embed_captions;
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::{FitArgs, KeyframeMode, SamplerArg, TgModeArg, MAX_GENERATION_BATCH};

pub const AFTER_HELP: &str = "\
Examples:
  diffkfc eval train-evaluator --data work/synth --out work/evaluator
  diffkfc eval --checkpoint work/runs/tiny --evaluator work/evaluator --data work/synth --compare --sweep-rates 0,0.02,0.05,0.1
  diffkfc eval --checkpoint work/runs/tiny --evaluator work/evaluator --data work/synth --num-items 64 --replications 2 --steps 10   (a quick look)

Metrics (our definitions of the keyframe metrics; the paper gives them in words):
  FID, R-Precision top-1/2/3 (batches of 32), MM-Dist, Diversity (300 pairs), MultiModality
    (--multimodality: 30 generations per text, 10 pairs) on the evaluator's embeddings.
  ADE: min over --samples-for-ade samples of the mean L2 joint error (metres) on non-keyframe frames.
  K-Err: mean L2 joint error at keyframes (global, and root-relative).
  K-TranS: mean |x[j+1] - 2x[j] + x[j-1]| within 2 frames of a keyframe (real motion = reference).
  Foot skate: share of toe-contact frames (below 5 cm) moving faster than 0.5 m/s.
Generation uses the ground-truth lengths; keyframes are drawn as in training with a fixed seed
per replication (the same for every method). Reports: <out>/report.json and <out>/report.md.";

#[derive(Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct EvalArgs {
    #[command(subcommand)]
    command: Option<EvalCommand>,
    #[command(flatten)]
    run: RunArgs,
}

#[derive(Args)]
struct RunArgs {
    /// Run directory of `diffkfc train` (newest checkpoint, EMA weights when present).
    #[arg(long, required = true)]
    checkpoint: Option<PathBuf>,
    /// Output directory of `diffkfc eval train-evaluator`, or `t2m:DIR`: the official T2M
    /// evaluator converted by scripts/convert-t2m-evaluator.py (numbers comparable with papers).
    #[arg(long, required = true)]
    evaluator: Option<PathBuf>,
    /// Dataset root (HumanML3D layout).
    #[arg(long, required = true)]
    data: Option<PathBuf>,
    /// Split whose items are generated and compared (test, val, train).
    #[arg(long, default_value = "test")]
    split: String,
    /// Replications: each draws its own items, keyframes and seeds; rows give mean +- 95%.
    #[arg(long, default_value_t = 20)]
    replications: usize,
    /// Test items per replication (at least 32: R-precision ranks batches of 32).
    #[arg(long, default_value_t = 1024)]
    num_items: usize,
    /// Fraction of frames that are keyframes (the paper's main setting: 5%).
    #[arg(long, default_value_t = 0.05)]
    keyframe_rate: f64,
    /// How keyframes are picked: random, uniform (evenly spaced) or mdo (KeyMotion's
    /// maximum-distance-optimal).
    #[arg(long, default_value = "random", value_name = "random|uniform|mdo")]
    keyframe_strategy: String,
    #[arg(long, value_enum, default_value = "diffkfc")]
    keyframe_mode: KeyframeMode,
    /// Transition guidance strength r (0 = off; the paper: 100).
    #[arg(long, default_value_t = sampler::DEFAULT_TRANSITION)]
    transition_guidance: f64,
    /// Place guidance strength (see `diffkfc sample --help`; 0 = off).
    #[arg(long, default_value_t = 0.0)]
    place_guidance: f64,
    /// Keyframe guidance scale s (1 = the keyframe branch alone; the paper: 2.5).
    #[arg(long, default_value_t = sampler::DEFAULT_KF_GUIDANCE)]
    kf_guidance: f64,
    /// Text guidance scale s (MDM's classifier-free guidance over the text): X(no text) +
    /// s (X(text) - X(no text)); 1 = off. Default: 2.5 for a model trained with text drop
    /// (`training.text_drop_prob`), 1 for others (which refuse any other value). A scale other
    /// than 1 adds a branch to every denoiser call.
    #[arg(long)]
    text_guidance: Option<f64>,
    /// How the transition-guidance gradient is taken: x0 (on the predicted x0) or exact (through
    /// the denoiser, paper Eq. 5: a backward pass per step).
    #[arg(long, value_enum, default_value = "x0")]
    tg_mode: TgModeArg,
    /// ddim or dpm (DPM-Solver++(2M)) over --steps evenly spaced steps, or ddpm (every step of
    /// the schedule).
    #[arg(long, value_enum, default_value_t = SamplerArg::DEFAULT)]
    sampler: SamplerArg,
    /// Steps of ddim and dpm (DDPM runs every step of the schedule).
    #[arg(long, default_value_t = sampler::DEFAULT_STEPS)]
    steps: usize,
    /// Generations per item for ADE (the minimum over them is kept).
    #[arg(long, default_value_t = 10)]
    samples_for_ade: usize,
    /// Also measure MultiModality (30 generations for each of --mm-texts texts).
    #[arg(long)]
    multimodality: bool,
    /// Texts for MultiModality (with --multimodality).
    #[arg(long, default_value_t = 100)]
    mm_texts: usize,
    /// Table 2: also run DiffKFC without transition guidance and the MDM-inp baseline.
    #[arg(long)]
    compare: bool,
    /// Also the two-stage row (`keyframes suggest` then `sample --keyframes`): keyframes at the
    /// MDO frames of a text-only motion of each caption, in-filled; its ADE and K-Err compare
    /// with that proposal.
    #[arg(long)]
    two_stage: bool,
    /// Table 4: run the main setting at each of these keyframe rates (e.g. 0,0.02,0.05,0.1).
    #[arg(long)]
    sweep_rates: Option<String>,
    #[command(flatten)]
    fit: FitArgs,
    /// Keyframes observe their pose only, not their place on the ground and their heading.
    #[arg(long)]
    no_root_keys: bool,
    /// Motions generated per denoiser batch.
    #[arg(long, default_value_t = 32)]
    batch_size: usize,
    /// Random seed of the first replication (replication i uses seed + i).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output folder: report.json, report.md (the tables) and a sheet of generated motions. A
    /// folder holding other files (or another kind of diffkfc output) is refused unless --force.
    #[arg(long, default_value = "out/eval")]
    out: PathBuf,
    /// Write the report into a --out folder that holds other files.
    #[arg(long)]
    force: bool,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

#[derive(Subcommand)]
enum EvalCommand {
    /// Train the contrastive text-motion evaluator on a dataset's train split and report its
    /// R-precision on real motions of --split (chance: 1/32, 2/32, 3/32).
    #[command(
        after_help = "Example:\n  diffkfc eval train-evaluator --data work/synth --out work/evaluator --max-steps 2000"
    )]
    TrainEvaluator(crate::commands::train_evaluator::TrainEvaluatorArgs),
    /// The in-betweening benchmark: keys every G seconds (and at 5%) from each clip of a
    /// HumanML3D-format folder, one sample per clip by the network alone and by the pipeline,
    /// scored beside linear interpolation of the same keys and the clip's own realism.
    #[command(after_help = crate::commands::inbetween::AFTER_HELP)]
    Inbetween(crate::commands::inbetween::InbetweenArgs),
}

pub fn run(a: EvalArgs) -> Result<()> {
    match a.command {
        None => evaluate(a.run),
        Some(EvalCommand::TrainEvaluator(t)) => crate::commands::train_evaluator::run(t),
        Some(EvalCommand::Inbetween(b)) => crate::commands::inbetween::run(b),
    }
}

/// Bounds of eval's counts: a mistyped count refuses at once rather than running for days or
/// failing to allocate.
const MAX_REPLICATIONS: usize = 100;

/// Bounds of `train-evaluator`'s flags, checked before any work.
fn parse_rate(v: f64, flag: &str) -> Result<f64> {
    if !(0.0..=1.0).contains(&v) {
        bail!("{flag}: {v} is not a keyframe rate in [0, 1]");
    }
    Ok(v)
}

/// The rows to run (`protocol::Rows`), from the flags.
fn settings(a: &RunArgs) -> Result<Vec<Setting>> {
    let rate = parse_rate(a.keyframe_rate, "--keyframe-rate")?;
    crate::args::check_guidance(
        a.kf_guidance,
        a.text_guidance.unwrap_or(1.0),
        a.place_guidance,
        a.transition_guidance,
        a.steps,
    )?;
    let mut sweep = Vec::new();
    if let Some(spec) = &a.sweep_rates {
        for p in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let r: f64 =
                p.parse().map_err(|_| anyhow::anyhow!("--sweep-rates: '{p}' is not a number"))?;
            sweep.push(parse_rate(r, "--sweep-rates")?);
        }
        if sweep.is_empty() {
            bail!("--sweep-rates: '{spec}' lists no rate (e.g. 0,0.02,0.05,0.1)");
        }
    }
    let rows = protocol::Rows {
        rate,
        inpaint: matches!(a.keyframe_mode, KeyframeMode::Inpaint),
        transition: a.transition_guidance,
        compare: a.compare,
        two_stage: a.two_stage,
        sweep,
    };
    Ok(rows.settings())
}

/// The counts in their bounds; the keyframe strategy.
fn check_counts(a: &RunArgs) -> Result<Strategy> {
    a.fit.check()?;
    for (v, flag, max, why) in [
        (a.replications, "--replications", MAX_REPLICATIONS, "each generates --num-items motions"),
        (a.samples_for_ade, "--samples-for-ade", 100, "each generates every item again"),
        (a.mm_texts, "--mm-texts", 10_000, "each generates 30 motions"),
        (a.batch_size, "--batch-size", MAX_GENERATION_BATCH, "motions generated at once"),
    ] {
        if v == 0 || v > max {
            bail!("{flag}: {v} must be 1 to {max} ({why})");
        }
    }
    a.keyframe_strategy
        .parse()
        .map_err(|e: diffkfc_data::UnknownChoice| anyhow::anyhow!("--keyframe-strategy: {e}"))
}

/// `--evaluator`: a directory of `eval train-evaluator`, or `t2m:DIR` (the official one).
fn load_evaluator<'a>(
    eval_dir: &std::path::Path,
    ds: &Dataset,
    split: &str,
    text: &'a diffkfc_model::text::cache::EmbeddingCache,
    device: &burn::prelude::Device,
) -> Result<Box<dyn TextMotionEvaluator + 'a>> {
    let ev: Box<dyn TextMotionEvaluator + 'a> =
        match eval_dir.to_str().and_then(|s| s.strip_prefix("t2m:")) {
            Some(dir) => Box::new(T2mEvaluator::load(
                std::path::Path::new(dir),
                &split_captions(ds, split)?,
                device,
            )?),
            None => Box::new(ContrastiveEvaluator::load(eval_dir, text, device)?),
        };
    if ev.feature_dim() != ds.dim() {
        bail!(
            "--evaluator: {} reads {}-d features, {} has {}",
            eval_dir.display(),
            ev.feature_dim(),
            ds.root.display(),
            ds.dim()
        );
    }
    Ok(ev)
}

/// The protocol's options from the flags.
fn options(a: &RunArgs, num_items: usize, strategy: Strategy) -> protocol::ProtocolOptions {
    protocol::ProtocolOptions {
        replications: a.replications,
        num_items,
        samples_for_ade: a.samples_for_ade,
        multimodality: if a.multimodality { a.mm_texts } else { 0 },
        sampler: a.sampler.sampler(a.steps),
        kf_guidance: a.kf_guidance,
        text_guidance: a.text_guidance.unwrap_or(1.0),
        tg_mode: a.tg_mode.mode(),
        fit: a.fit.fit(),
        place_guidance: a.place_guidance,
        root_keys: !a.no_root_keys,
        strategy,
        batch: a.batch_size,
        seed: a.seed,
    }
}

/// The items evaluated (at most --num-items, at least one R-precision batch), all of lengths the
/// model was built for.
fn check_split(a: &RunArgs, split: &PackedSplit, max_frames: usize) -> Result<usize> {
    let (data, run_dir) = (
        a.data.as_deref().unwrap_or(Path::new("")),
        a.checkpoint.as_deref().unwrap_or(Path::new("")),
    );
    let num_items = a.num_items.min(split.items.len());
    if num_items < protocol::R_BATCH {
        bail!("--num-items: {num_items} items (split '{}' of {} has {}); R-precision needs at least {}", a.split, data.display(), split.items.len(), protocol::R_BATCH);
    }
    // Items are generated at their ground-truth lengths: the model must be built for them.
    let longest = split.items.iter().map(|it| eval_length(it.len)).max().unwrap_or(0);
    if longest > max_frames {
        bail!("--checkpoint: {} was built for motions of at most {max_frames} frames (model.max_frames), but split '{}' of {} has items of {longest}", run_dir.display(), a.split, data.display());
    }
    Ok(num_items)
}

fn evaluate(mut a: RunArgs) -> Result<()> {
    let (Some(run_dir), Some(eval_dir), Some(data)) =
        (a.checkpoint.clone(), a.evaluator.clone(), a.data.clone())
    else {
        bail!("eval: needs --checkpoint, --evaluator and --data")
    };
    let settings = settings(&a)?;
    let strategy = check_counts(&a)?;
    ownership::check(&a.out, Output::Report, a.force, "--out")?;
    let device = a.tg_mode.device(crate::device::parse(&a.device)?);
    let ds = Dataset::open(&data)?;
    let session = Session::load(&run_dir, &device, ds.skeleton)?;
    let loaded = &session.loaded;
    let (cfg, step) = (&loaded.cfg, loaded.step);
    // From here on the scale is the one used: the flag's or the model's default.
    a.text_guidance = Some(diffkfc_model::sampling::guidance::text_guidance(
        "--text-guidance",
        a.text_guidance,
        &loaded.cfg,
    )?);
    check_dim(&ds, &data, &run_dir, cfg.model.feat_dim)?;
    let split =
        PackedSplit::open(&ds, &a.split, &default_cache_dir(&ds), crate::progress::bar("caching"))?;
    let num_items = check_split(&a, &split, cfg.model.max_frames)?;
    // The split's captions are embedded in batches and cached on disk (thousands of them),
    // not one by one through the session. The evaluator reads pooled embeddings; a model with
    // word states reads its own input.
    let text = embed_captions(&ds, &[&split], 0, crate::progress::bar("embedding"))?;
    let words = cfg.model.text_words;
    let model_text = (words > 0)
        .then(|| embed_captions(&ds, &[&split], words, crate::progress::bar("embedding words")))
        .transpose()?;
    let ev = load_evaluator(&eval_dir, &ds, &a.split, &text, &device)?;
    let (_, real) = embed_split(ev.as_ref(), &ds, &split)?;
    let reference = Gaussian::fit(&real);
    let sampler = a.sampler.sampler(a.steps);
    let p = Protocol {
        gen: session.generator(),
        ds: &ds,
        split: &split,
        text: model_text.as_ref().unwrap_or(&text),
        evaluator: ev.as_ref(),
        opts: options(&a, num_items, strategy),
    };
    let pb = announce(&a, &p, &settings, num_items, sampler);
    let t0 = std::time::Instant::now();
    let rows = p.run(&settings, &reference, &mut || pb.inc(1))?;
    let captions = p.captions();
    pb.finish_and_clear();
    let secs = t0.elapsed().as_secs_f64();
    let run = Ran {
        run_dir: &run_dir,
        step,
        eval_dir: &eval_dir,
        evaluator: ev.name(),
        data: &data,
        captions: &captions,
    };
    write_report(&a, &run, &rows, &settings, num_items, real.len(), secs)
}

/// The dataset's feature width against the checkpoint's.
fn check_dim(ds: &Dataset, data: &Path, run_dir: &Path, feat_dim: usize) -> Result<()> {
    if ds.dim() != feat_dim {
        bail!(
            "--data: {} has {}-d features, the checkpoint {} expects {feat_dim}",
            data.display(),
            ds.dim(),
            run_dir.display(),
        );
    }
    Ok(())
}

/// Prints what the evaluation will run and its time estimate; the progress bar of its steps.
fn announce(
    a: &RunArgs,
    p: &Protocol,
    settings: &[Setting],
    num_items: usize,
    sampler: diffkfc_model::diffusion::scheduler::Sampler,
) -> ProgressBar {
    let total = p.planned_steps(settings);
    let estimate = p.estimate_seconds(settings);
    println!(
        "eval: {} setting(s) x {} replication(s) x {num_items} items x {} sample(s), {sampler:?}: {total} denoising steps (batches of up to {}); estimate {:.1} min",
        settings.len(),
        a.replications,
        a.samples_for_ade,
        a.batch_size,
        estimate / 60.0
    );
    ProgressBar::new(total as u64).with_style(
        ProgressStyle::with_template("generating [{bar:30}] {pos}/{len} steps {elapsed} ETA {eta}")
            .expect("template")
            .progress_chars("=> "),
    )
}

/// What an evaluation ran on, for its report.
struct Ran<'a> {
    run_dir: &'a std::path::Path,
    step: usize,
    eval_dir: &'a std::path::Path,
    evaluator: String,
    data: &'a std::path::Path,
    /// Per replication, each item's clip and caption (the order of report.json's per-item values).
    captions: &'a [Vec<(String, String)>],
}

/// report.json (every replication's value and the settings) and report.md (the tables under a
/// header saying what produced them) in `--out`, and the tables on stdout.
fn write_report(
    a: &RunArgs,
    run: &Ran,
    rows: &[protocol::RowResult],
    settings: &[Setting],
    num_items: usize,
    reference_motions: usize,
    secs: f64,
) -> Result<()> {
    let (sampler, fit, step) = (a.sampler.sampler(a.steps), a.fit.fit(), run.step);
    let meta = serde_json::json!({
        "checkpoint": run.run_dir.display().to_string(), "checkpoint_step": step, "evaluator": run.eval_dir.display().to_string(), "evaluator_name": run.evaluator,
        "data": run.data.display().to_string(), "split": a.split, "replications": a.replications, "num_items": num_items,
        "samples_for_ade": a.samples_for_ade, "sampler": format!("{sampler:?}"), "kf_guidance": a.kf_guidance, "text_guidance": a.text_guidance.unwrap_or(1.0), "place_guidance": a.place_guidance,
        "keyframe_strategy": a.keyframe_strategy, "keyframe_fit": fit.keyframes, "foot_lock": fit.foot_lock, "foot_lock_reach_m": fit.lock_reach, "root_keys": !a.no_root_keys, "multimodality_texts": if a.multimodality { a.mm_texts } else { 0 },
        "seed": a.seed, "seconds": secs, "reference_motions": reference_motions,
        "items": run.captions.iter().map(|rep| rep.iter().map(|(clip, text)| serde_json::json!({"clip": clip, "caption": text})).collect::<Vec<_>>()).collect::<Vec<_>>(),
    });
    let header = format!(
        "Checkpoint `{}` (step {step}), evaluator: {}, split `{}` of `{}`: {} replication(s) x {num_items} items, {sampler:?}, keyframe guidance {}, text guidance {}, {} keyframes, ADE over {} sample(s), keyframe fit {:?}, foot lock {}, root keyframes {}; {:.0} s.",
        run.run_dir.display(),
        run.evaluator,
        a.split,
        run.data.display(),
        a.replications,
        a.kf_guidance,
        a.text_guidance.unwrap_or(1.0),
        a.keyframe_strategy,
        a.samples_for_ade,
        fit.keyframes,
        if fit.foot_lock { "on" } else { "off" },
        if a.no_root_keys { "off" } else { "on" },
        secs
    );
    let md = report::to_markdown(rows, &header, settings[0].rate, &settings[0].name);
    let owned = ownership::check(&a.out, Output::Report, a.force, "--out")?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("--out: creating {}", a.out.display()))?;
    if owned {
        Output::Report.mark(&a.out)?;
    }
    super::report_files::write(&a.out, &report::to_json(rows, meta), &md)
}

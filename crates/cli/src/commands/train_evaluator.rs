//! `diffkfc eval train-evaluator`: the contrastive text-motion evaluator trained on a dataset's
//! train split, its R-precision reported on real motions.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use diffkfc_data::dataset::cache::{default_cache_dir, PackedSplit};
use diffkfc_data::dataset::Dataset;
use diffkfc_data::io::ownership::{self, Output};
use diffkfc_eval::evaluator::EvaluatorConfig;
use diffkfc_eval::train_evaluator::{EvaluatorReport, EvaluatorTraining};
use diffkfc_model::text::cache::{embed_captions, EmbeddingCache};
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::MAX_GENERATION_BATCH;

#[derive(Args)]
pub struct TrainEvaluatorArgs {
    /// Dataset root (HumanML3D layout); trains on its train split.
    #[arg(long)]
    data: PathBuf,
    /// Output folder: the evaluator's weights, config and report.json. A folder holding other
    /// files (or another kind of diffkfc output, such as a model) is refused unless --force.
    #[arg(long)]
    out: PathBuf,
    /// Write the evaluator into a --out folder that holds other files (never an exported
    /// model's).
    #[arg(long)]
    force: bool,
    /// Training steps.
    #[arg(long, default_value_t = 2000)]
    max_steps: usize,
    /// Text-motion pairs per step (each batch's other pairs are its negatives).
    #[arg(long, default_value_t = 32)]
    batch_size: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 3e-4)]
    lr: f64,
    /// Random seed (initialisation and batches).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Split whose real motions the report's R-precision is measured on.
    #[arg(long, default_value = "test")]
    split: String,
    /// Compute device: flex (the CPU default), or ndarray, wgpu, cuda in builds with that
    /// cargo feature.
    #[arg(long, default_value = "flex", value_name = "flex|ndarray|wgpu|cuda")]
    device: String,
}

fn check_flags(a: &TrainEvaluatorArgs) -> Result<()> {
    let (max_steps, batch_size, lr) = (a.max_steps, a.batch_size, a.lr);
    if max_steps == 0 || max_steps > 10_000_000 {
        bail!("--max-steps: {max_steps} must be 1 to 10000000");
    }
    if !(2..=MAX_GENERATION_BATCH).contains(&batch_size) {
        bail!("--batch-size: {batch_size} must be 2 to {MAX_GENERATION_BATCH} (a batch's other pairs are each pair's negatives)");
    }
    if !(lr.is_finite() && lr > 0.0 && lr <= 1.0) {
        bail!("--lr: {lr} must be a learning rate above 0 and at most 1 (the default: 3e-4)");
    }
    Ok(())
}

/// The dataset, its train split and the reported split, and their captions' embeddings.
fn open_data(
    a: &TrainEvaluatorArgs,
) -> Result<(Dataset, PackedSplit, PackedSplit, EmbeddingCache)> {
    let ds = Dataset::open(&a.data)?;
    let cache = default_cache_dir(&ds);
    let train = PackedSplit::open(&ds, "train", &cache, crate::progress::bar("caching train"))?;
    let test = PackedSplit::open(&ds, &a.split, &cache, crate::progress::bar("caching"))?;
    if train.items.is_empty() || test.items.len() < 32 {
        bail!(
            "{}: needs training items and at least 32 items in split '{}' (has {})",
            a.data.display(),
            a.split,
            test.items.len()
        );
    }
    let text = embed_captions(&ds, &[&train, &test], 0, crate::progress::bar("embedding"))?;
    Ok((ds, train, test, text))
}

pub fn run(a: TrainEvaluatorArgs) -> Result<()> {
    check_flags(&a)?;
    let owned = ownership::check(&a.out, Output::Evaluator, a.force, "--out")?;
    let device = crate::device::parse(&a.device)?;
    let (ds, train, test, text) = open_data(&a)?;
    if owned {
        std::fs::create_dir_all(&a.out)
            .with_context(|| format!("--out: creating {}", a.out.display()))?;
        Output::Evaluator.mark(&a.out)?;
    }
    let cfg = EvaluatorConfig::new().with_motion_dim(ds.dim() - 4).with_text_dim(text.dim);
    let pb = ProgressBar::new(a.max_steps as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] step {pos}/{len} {per_sec} ETA {eta}")
            .expect("template")
            .progress_chars("=> "),
    );
    let t0 = std::time::Instant::now();
    let job = EvaluatorTraining {
        cfg,
        ds: &ds,
        train: &train,
        test: &test,
        text: &text,
        device,
        out: a.out.clone(),
        batch_size: a.batch_size,
        steps: a.max_steps,
        lr: a.lr,
        seed: a.seed,
    };
    let r = job.run(|s, l| {
        pb.set_position(s as u64);
        pb.set_message(format!("InfoNCE {l:.3}"));
    })?;
    pb.finish_and_clear();
    report(&a, &r, t0.elapsed().as_secs_f64())
}

/// report.json beside the weights, and the numbers on stdout.
fn report(a: &TrainEvaluatorArgs, r: &EvaluatorReport, secs: f64) -> Result<()> {
    let report = serde_json::json!({"steps": r.steps, "seconds": secs, "first_loss": r.first_loss, "last_loss": r.last_loss,
        "split": a.split, "items": r.items, "r_precision_top1": r.r_precision[0], "r_precision_top2": r.r_precision[1], "r_precision_top3": r.r_precision[2],
        "mm_dist": r.mm_dist, "chance": [1.0 / 32.0, 2.0 / 32.0, 3.0 / 32.0]});
    diffkfc_data::write_atomic(
        &a.out.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    println!(
        "{}: {} steps in {secs:.1} s, InfoNCE {:.3} -> {:.3}",
        a.out.display(),
        r.steps,
        r.first_loss,
        r.last_loss
    );
    println!(
        "  R-precision on {} real '{}' motions: top-1 {:.3}, top-2 {:.3}, top-3 {:.3} (chance 0.031, 0.062, 0.094); MM-dist {:.3}",
        r.items, a.split, r.r_precision[0], r.r_precision[1], r.r_precision[2], r.mm_dist
    );
    Ok(())
}

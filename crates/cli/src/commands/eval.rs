//! `diffkfc eval ...`: the text-motion evaluator.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};
use diffkfc_data::cache::{default_cache_dir, PackedSplit};
use diffkfc_data::dataset::Dataset;
use diffkfc_eval::evaluator::EvaluatorConfig;
use diffkfc_eval::train_evaluator::EvaluatorTraining;
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Args)]
pub struct EvalArgs {
    #[command(subcommand)]
    command: EvalCommand,
}

#[derive(Subcommand)]
enum EvalCommand {
    /// Train the contrastive text-motion evaluator on a dataset's train split and report its
    /// R-precision on real motions of --split (chance: 1/32, 2/32, 3/32).
    #[command(after_help = "Example:\n  diffkfc eval train-evaluator --data work/synth --out work/evaluator --max-steps 2000")]
    TrainEvaluator {
        #[arg(long)]
        data: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value_t = 2000)]
        max_steps: usize,
        #[arg(long, default_value_t = 32)]
        batch_size: usize,
        #[arg(long, default_value_t = 3e-4)]
        lr: f64,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value = "test")]
        split: String,
        #[arg(long, default_value = "flex")]
        device: String,
    },
}

pub fn run(a: EvalArgs) -> Result<()> {
    match a.command {
        EvalCommand::TrainEvaluator { data, out, max_steps, batch_size, lr, seed, split, device } => {
            let device = crate::device::parse(&device)?;
            let ds = Dataset::open(&data)?;
            let cache = default_cache_dir(&ds);
            let train = PackedSplit::open(&ds, "train", &cache, crate::progress::bar("caching train"))?;
            let test = PackedSplit::open(&ds, &split, &cache, crate::progress::bar("caching"))?;
            if train.items.is_empty() || test.items.len() < 32 {
                anyhow::bail!("{}: needs training items and at least 32 items in split '{split}' (has {})", data.display(), test.items.len());
            }
            let text = super::train::embed_captions(&ds, &[&train, &test])?;
            let cfg = EvaluatorConfig::new().with_motion_dim(ds.dim() - 4).with_text_dim(text.dim);
            let pb = ProgressBar::new(max_steps as u64);
            pb.set_style(ProgressStyle::with_template("{msg} [{bar:30}] step {pos}/{len} {per_sec} ETA {eta}").expect("template").progress_chars("=> "));
            let t0 = std::time::Instant::now();
            let job = EvaluatorTraining { cfg, ds: &ds, train: &train, test: &test, text: &text, device, out: out.clone(), batch_size, steps: max_steps, lr, seed };
            let r = job
                .run(|s, l| {
                    pb.set_position(s as u64);
                    pb.set_message(format!("InfoNCE {l:.3}"));
                })
                .map_err(anyhow::Error::msg)?;
            pb.finish_and_clear();
            let report = serde_json::json!({"steps": r.steps, "seconds": t0.elapsed().as_secs_f64(), "first_loss": r.first_loss, "last_loss": r.last_loss,
                "split": split, "items": r.items, "r_precision_top1": r.r_precision[0], "r_precision_top2": r.r_precision[1], "r_precision_top3": r.r_precision[2],
                "mm_dist": r.mm_dist, "chance": [1.0 / 32.0, 2.0 / 32.0, 3.0 / 32.0]});
            diffkfc_data::write_atomic(&out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
            println!("{}: {} steps in {:.1} s, InfoNCE {:.3} -> {:.3}", out.display(), r.steps, t0.elapsed().as_secs_f64(), r.first_loss, r.last_loss);
            println!("  R-precision on {} real '{split}' motions: top-1 {:.3}, top-2 {:.3}, top-3 {:.3} (chance 0.031, 0.062, 0.094); MM-dist {:.3}", r.items, r.r_precision[0], r.r_precision[1], r.r_precision[2], r.mm_dist);
            Ok(())
        }
    }
}

//! `train --recipe`: a shipped model retrained by one command. The recipe's synthetic sets are
//! drawn into the output folder, then each stage trains into its own run directory from the
//! stage before (`--init`); a stage already at its end is skipped and one cut short is resumed,
//! so the same command continues a recipe that was stopped. The last stage is exported to
//! `<out>/model`, which `--checkpoint` loads.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use diffkfc_model::run::checkpoint::{self, Checkpoint};
use diffkfc_model::run::lock::is_run;
use diffkfc_model::run::recipe::{Recipe, Stage};
use diffkfc_synth::write_dataset;

use super::train::TrainArgs;

pub fn run(a: TrainArgs) -> Result<()> {
    let path = a.recipe.clone().context("--recipe: no recipe given")?;
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("--recipe: {}", path.display()))?;
    let recipe = Recipe::parse(&text).with_context(|| format!("--recipe: {}", path.display()))?;
    let stages = recipe.stages().with_context(|| format!("--recipe: {}", path.display()))?;
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from("runs").join(&recipe.model));
    if out.exists() && !out.join(RECIPE_COPY).exists() && std::fs::read_dir(&out)?.next().is_some()
    {
        bail!(
            "--out: {} is not empty and holds no recipe run; choose a new or empty directory",
            out.display()
        );
    }
    std::fs::create_dir_all(&out).with_context(|| format!("--out: {}", out.display()))?;
    diffkfc_data::write_atomic(&out.join(RECIPE_COPY), text.as_bytes())?;
    eprintln!("recipe {}: {} stages into {}", recipe.model, stages.len(), out.display());
    let started = std::time::Instant::now();
    let mut previous: Option<PathBuf> = None;
    for stage in &stages {
        let run = out.join(stage.dir_name());
        let reached = Checkpoint::list(&run).last().map_or(0, |(s, _)| *s);
        if reached >= stage.end_step {
            eprintln!("stage {}: done (step {reached})", stage.dir_name());
        } else {
            // --time-budget bounds the whole recipe: each stage gets what is left.
            let left = a.time_budget.map(|b| b.saturating_sub(started.elapsed()));
            if left.is_some_and(|l| l.is_zero()) {
                eprintln!("recipe stopped before stage {} (time budget reached); run the same command to continue", stage.dir_name());
                return Ok(());
            }
            let data = synth_set(&recipe, stage, &out)?;
            let args = TrainArgs { time_budget: left, ..stage_args(&a, stage, &run, &data, &out)? };
            let args =
                TrainArgs { init: if args.resume { None } else { previous.clone() }, ..args };
            super::train::run(args)?;
            let reached = Checkpoint::list(&run).last().map_or(0, |(s, _)| *s);
            if reached < stage.end_step {
                eprintln!("recipe stopped in stage {} at step {reached} of {}; run the same command to continue", stage.dir_name(), stage.end_step);
                return Ok(());
            }
        }
        previous = Some(run);
    }
    let last = previous.context("a recipe has stages")?;
    let model = out.join("model");
    checkpoint::export(&last, &model, true, false)?;
    println!(
        "{}: the model of recipe {} (`--checkpoint {}`)",
        model.display(),
        recipe.model,
        model.display()
    );
    Ok(())
}

/// The recipe as given, kept in its output (and marking the folder as a recipe's).
const RECIPE_COPY: &str = "recipe.json";

/// The stage's synthetic set in `out/data-<name>`, drawn when not there yet.
fn synth_set(recipe: &Recipe, stage: &Stage, out: &Path) -> Result<PathBuf> {
    let dir = out.join(format!("data-{}", stage.data));
    if dir.join("manifest.json").exists() {
        return Ok(dir);
    }
    let spec = recipe.data[&stage.data].spec().map_err(anyhow::Error::msg)?;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let bar = std::sync::Mutex::new(crate::progress::bar(&format!("drawing set {}", stage.data)));
    let _ = std::fs::remove_dir_all(&dir); // a set cut short before its manifest
    write_dataset(&dir, &spec, threads, &|d, n| (bar.lock().unwrap())(d, n))?;
    Ok(dir)
}

/// One stage as `train` runs it: its config written beside its run, its own run resumed
/// where it stopped or else a new one (the caller sets `init`, the stage before).
fn stage_args(
    a: &TrainArgs,
    stage: &Stage,
    run: &Path,
    data: &Path,
    out: &Path,
) -> Result<TrainArgs> {
    let config = out.join(format!("{}.config.json", stage.dir_name()));
    diffkfc_data::write_atomic(&config, serde_json::to_string_pretty(&stage.config)?.as_bytes())?;
    let resume = is_run(run);
    let what = if resume { "resuming" } else { "training" };
    eprintln!("stage {}: {what} to step {}", stage.dir_name(), stage.end_step);
    Ok(TrainArgs {
        config: Some(config),
        recipe: None,
        data: Some(data.to_path_buf()),
        out: Some(run.to_path_buf()),
        resume,
        force: false,
        init: None,
        max_steps: Some(stage.end_step),
        time_budget: a.time_budget,
        device: a.device.clone(),
        devices: a.devices.clone(),
        optimiser_state: a.optimiser_state,
        seed: None,
    })
}

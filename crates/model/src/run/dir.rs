//! A training run's directory and its files: `config.json`, `Mean.npy`/`Std.npy` (the
//! normalisation the model was trained with), `ckpt-*.safetensors`, `metrics.jsonl` (one line
//! per step, with validation losses) and `loss.svg` (its plot: training loss light, moving
//! average dark, validation points, log-scaled y) and, for a warm start, `init-from.txt` (the
//! `--init` weights' path).

use std::path::{Path, PathBuf};

use crate::error::{ModelError, Result};
use crate::run::config::RunConfig;

/// One line of metrics.jsonl, as far as readers need it.
#[derive(Clone, Debug, PartialEq)]
pub struct Metric {
    pub step: usize,
    pub loss: Option<f64>,
    pub val_loss: Option<f64>,
}

/// The metrics lines of a metrics.jsonl text (lines that do not parse are skipped).
pub fn parse_metrics(text: &str) -> Vec<(Metric, &str)> {
    text.lines()
        .filter_map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).ok()?;
            Some((
                Metric {
                    step: v["step"].as_u64()? as usize,
                    loss: v["loss"].as_f64(),
                    val_loss: v["val_loss"].as_f64(),
                },
                l,
            ))
        })
        .collect()
}

/// Where a run records the `--init` weights it started from.
const INIT_FILE: &str = "init-from.txt";

#[derive(Clone, Debug)]
pub struct RunDir {
    pub path: PathBuf,
}

impl RunDir {
    pub fn new(path: impl Into<PathBuf>) -> RunDir {
        RunDir { path: path.into() }
    }

    /// The run of `path`: a run (or model) directory, or the directory of one of its checkpoints.
    pub fn of(path: &Path) -> RunDir {
        RunDir::new(if path.is_file() { path.parent().unwrap_or(Path::new(".")) } else { path })
    }

    pub fn config_path(&self) -> PathBuf {
        self.path.join("config.json")
    }

    pub fn metrics_path(&self) -> PathBuf {
        self.path.join("metrics.jsonl")
    }

    pub fn plot_path(&self) -> PathBuf {
        self.path.join("loss.svg")
    }

    /// A resumed run must keep its model, its training recipe (all but `max_steps`) and its
    /// normalisation: checked before any run file is rewritten, so a refused resume leaves the
    /// run as it was.
    pub fn check_resumable(&self, cfg: &RunConfig, mean: &[f32]) -> Result<()> {
        let stored = self.config_path();
        if let Ok(old) = RunConfig::load(&stored) {
            if old.model != cfg.model {
                return Err(ModelError::Refused(format!("--resume: {} describes another model than --config (model section differs); pass the run's own config or choose another --out", stored.display())));
            }
            let changed = training_changes(&old, cfg);
            if !changed.is_empty() {
                return Err(ModelError::Refused(format!("--resume: {} trained with other training or keyframe settings than --config ({}); an exact resume keeps them: pass the run's own config, or start a new run from it with --init {}", stored.display(), changed.join(", "), self.path.display())));
            }
        }
        let path = self.path.join("Mean.npy");
        if let Ok(m) = diffkfc_data::io::npy::read_f32(&path) {
            if m.data != mean {
                return Err(ModelError::Refused(format!(
                    "--resume: {} differs from the dataset's Mean.npy: the run was trained on another normalisation; resume on its own dataset or choose another --out",
                    path.display()
                )));
            }
        }
        Ok(())
    }

    /// Create the directory and write the config and the normalisation sampling will need
    /// (after `claim`).
    pub fn prepare(&self, cfg: &RunConfig, mean: &[f32], std: &[f32]) -> Result<()> {
        std::fs::create_dir_all(&self.path).map_err(ModelError::io(&self.path))?;
        diffkfc_data::write_atomic(&self.config_path(), cfg.to_json().as_bytes())?;
        for (name, v) in [("Mean.npy", mean), ("Std.npy", std)] {
            diffkfc_data::io::npy::write(self.path.join(name), &[v.len()], v)?;
        }
        Ok(())
    }

    /// The weights a run was started from (`train --init`), recorded so that resuming a run
    /// killed before its first checkpoint starts it as it was started.
    pub fn record_init(&self, init: Option<&Path>) -> Result<()> {
        let path = self.path.join(INIT_FILE);
        match init {
            Some(p) => {
                let p = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
                diffkfc_data::write_atomic(&path, p.to_string_lossy().as_bytes())?;
            }
            None if path.exists() => std::fs::remove_file(&path).map_err(ModelError::io(&path))?,
            None => {}
        }
        Ok(())
    }

    /// The weights recorded by [`RunDir::record_init`], if any.
    pub fn recorded_init(&self) -> Option<PathBuf> {
        std::fs::read_to_string(self.path.join(INIT_FILE)).ok().map(PathBuf::from)
    }

    /// Mean/Std the model was trained with: the run's own copy, or the dataset's the config names.
    pub fn normalisation(&self, cfg: &RunConfig) -> Result<(Vec<f32>, Vec<f32>)> {
        let dir = if self.path.join("Mean.npy").exists() {
            self.path.clone()
        } else {
            PathBuf::from(cfg.data.dir.clone().ok_or_else(|| {
                ModelError::file(&self.path, "no Mean.npy/Std.npy and no data.dir in its config")
            })?)
        };
        Ok(diffkfc_data::dataset::read_normalisation(&dir, Some(cfg.model.feat_dim))?)
    }

    /// Every metrics line so far.
    pub fn metrics(&self) -> Vec<Metric> {
        let text = std::fs::read_to_string(self.metrics_path()).unwrap_or_default();
        parse_metrics(&text).into_iter().map(|(m, _)| m).collect()
    }

    /// Keep only the metrics lines of steps <= `step` (a resumed run rewrites what follows).
    pub fn truncate_metrics(&self, step: usize) -> Result<()> {
        let path = self.metrics_path();
        let Ok(text) = std::fs::read_to_string(&path) else {
            return Ok(());
        };
        let kept: Vec<&str> = parse_metrics(&text)
            .into_iter()
            .filter(|(m, _)| m.step <= step)
            .map(|(_, l)| l)
            .collect();
        let mut out = kept.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        Ok(diffkfc_data::write_atomic(&path, out.as_bytes())?)
    }

    /// Write loss.svg from metrics.jsonl.
    pub fn write_loss_plot(&self) -> Result<()> {
        Ok(diffkfc_data::write_atomic(&self.plot_path(), loss_svg(&self.metrics()).as_bytes())?)
    }
}

/// The `training` and `keyframes` fields of `cfg` that differ from `old`'s, `max_steps` aside
/// (a resume may stop later).
fn training_changes(old: &RunConfig, cfg: &RunConfig) -> Vec<String> {
    // The keyframe schedule draws the batches, so an exact resume keeps it as well.
    let sections = |c: &RunConfig| {
        let mut t = c.training.clone();
        t.max_steps = 0;
        [
            ("training", serde_json::to_value(t).unwrap_or_default()),
            ("keyframes", serde_json::to_value(&c.keyframes).unwrap_or_default()),
        ]
    };
    let mut changes = vec![];
    for ((name, a), (_, b)) in sections(old).into_iter().zip(sections(cfg)) {
        let (Some(a), Some(b)) = (a.as_object(), b.as_object()) else {
            continue;
        };
        let keys = a.keys().chain(b.keys().filter(|k| !a.contains_key(*k)));
        let null = serde_json::Value::Null;
        for k in keys {
            let (va, vb) = (a.get(k).unwrap_or(&null), b.get(k).unwrap_or(&null));
            if va != vb {
                changes.push(format!("{name}.{k} {va} -> {vb}"));
            }
        }
    }
    changes
}

fn loss_svg(metrics: &[Metric]) -> String {
    let train: Vec<(f64, f64)> =
        metrics.iter().filter_map(|m| Some((m.step as f64, m.loss?))).collect();
    let val: Vec<(f64, f64)> =
        metrics.iter().filter_map(|m| Some((m.step as f64, m.val_loss?))).collect();
    let (w, h, m) = (640.0, 360.0, 50.0);
    let all: Vec<f64> = train.iter().chain(&val).map(|p| p.1.max(1e-6)).collect();
    if all.is_empty() {
        return format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}'><text x='20' y='30'>no steps yet</text></svg>");
    }
    let (lo, hi) =
        all.iter().fold((f64::MAX, f64::MIN), |a, &v| (a.0.min(v.ln()), a.1.max(v.ln())));
    let hi = if hi - lo < 1e-9 { lo + 1.0 } else { hi };
    let smax = train.iter().chain(&val).map(|p| p.0).fold(1.0, f64::max);
    let x = |s: f64| m + (w - 2.0 * m) * s / smax;
    let y = |l: f64| h - m - (h - 2.0 * m) * (l.max(1e-6).ln() - lo) / (hi - lo);
    let path = |pts: &[(f64, f64)]| {
        pts.iter()
            .enumerate()
            .map(|(i, p)| format!("{}{:.1},{:.1}", if i == 0 { "M" } else { "L" }, x(p.0), y(p.1)))
            .collect::<String>()
    };
    let k = (train.len() / 50).max(1);
    let smooth: Vec<(f64, f64)> = (0..train.len())
        .map(|i| {
            let a = i.saturating_sub(k);
            let s: f64 = train[a..=i].iter().map(|p| p.1).sum::<f64>() / (i - a + 1) as f64;
            (train[i].0, s)
        })
        .collect();
    let mut s = format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>");
    s += &format!(
        "<rect width='{w}' height='{h}' fill='white'/><line x1='{m}' y1='{}' x2='{}' y2='{}' stroke='black'/><line x1='{m}' y1='{m}' x2='{m}' y2='{}' stroke='black'/>",
        h - m,
        w - m,
        h - m,
        h - m
    );
    s += &format!("<text x='{}' y='{}' text-anchor='middle'>step</text><text x='12' y='{}' transform='rotate(-90 12 {})' text-anchor='middle'>loss (log)</text>", w / 2.0, h - 12.0, h / 2.0, h / 2.0);
    s += &format!(
        "<text x='{m}' y='{}'>{:.3}</text><text x='{m}' y='{}'>{:.3}</text><text x='{}' y='{}' text-anchor='end'>{smax}</text>",
        m - 6.0,
        hi.exp(),
        h - m + 14.0,
        lo.exp(),
        w - m,
        h - m + 14.0
    );
    s += &format!("<path d='{}' fill='none' stroke='#9bb' stroke-width='1'/><path d='{}' fill='none' stroke='#157' stroke-width='2'/>", path(&train), path(&smooth));
    for p in &val {
        s += &format!("<circle cx='{:.1}' cy='{:.1}' r='3.5' fill='#d60'/>", x(p.0), y(p.1));
    }
    s += &format!("<text x='{}' y='20' text-anchor='end' fill='#157'>train (moving average)</text><text x='{}' y='36' text-anchor='end' fill='#d60'>validation</text></svg>", w - m, w - m);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A resume compares the keyframe schedule as well as the recipe, including options that
    /// one config leaves unset; the step budget may change.
    #[test]
    fn training_changes_name_recipe_and_keyframe_differences() {
        let old = RunConfig::parse(r#"{"model": "tiny"}"#).unwrap();
        let mut cfg = old.clone();
        cfg.training.max_steps += 100;
        assert!(training_changes(&old, &cfg).is_empty());
        cfg.keyframes.max_observed_sigma = Some(30.0);
        cfg.keyframes.rate = 0.1;
        let changes = training_changes(&old, &cfg);
        assert_eq!(changes.len(), 2, "{changes:?}");
        assert!(changes.contains(&"keyframes.rate 0.05 -> 0.1".to_string()), "{changes:?}");
        assert!(
            changes.contains(&"keyframes.max_observed_sigma null -> 30.0".to_string()),
            "{changes:?}"
        );
    }
}

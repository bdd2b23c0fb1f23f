//! Run configuration files (`configs/*.json`): sections model, diffusion, data, keyframes,
//! training. Unknown or ill-typed keys are errors that name the key.

use std::path::Path;

use diffkfc_data::batch::KeyframeConfig;
use serde::{Deserialize, Serialize};

use crate::config::DiffKfcConfig;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DiffusionConfig {
    pub steps: usize,
    /// "cosine" (the paper) or "linear".
    pub schedule: String,
}

impl Default for DiffusionConfig {
    fn default() -> Self {
        DiffusionConfig { steps: 1000, schedule: "cosine".into() }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Dataset root; the CLI's --data overrides it.
    pub dir: Option<String>,
    pub train_split: String,
    pub val_split: String,
}

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig { dir: None, train_split: "train".into(), val_split: "val".into() }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainingConfig {
    pub batch_size: usize,
    pub lr: f64,
    pub max_steps: usize,
    pub warmup_steps: usize,
    /// Cosine decay of the learning rate to 0 at max_steps.
    pub cosine_decay: bool,
    /// Gradient-norm clipping (0: off).
    pub grad_clip: f64,
    /// EMA decay of the weights (0: no EMA).
    pub ema_decay: f64,
    pub checkpoint_every: usize,
    pub keep_checkpoints: usize,
    pub val_every: usize,
    pub val_batches: usize,
    pub log_every: usize,
    pub seed: u64,
    /// Weights of the kinematic losses (MDM-style): joint positions, joint velocities, foot contact.
    pub lambda_pos: f64,
    pub lambda_vel: f64,
    pub lambda_foot: f64,
    /// Weight of the reconstruction error on the elements the keyframes observe (the paper's
    /// L_simple leaves them out; 0 = the paper).
    pub keyframe_loss: f64,
}

impl Default for TrainingConfig {
    fn default() -> Self {
        TrainingConfig {
            batch_size: 64,
            lr: 1e-4,
            max_steps: 500_000,
            warmup_steps: 0,
            cosine_decay: false,
            grad_clip: 1.0,
            ema_decay: 0.9999,
            checkpoint_every: 5000,
            keep_checkpoints: 3,
            val_every: 5000,
            val_batches: 8,
            log_every: 50,
            seed: 0,
            lambda_pos: 0.0,
            lambda_vel: 0.0,
            lambda_foot: 0.0,
            keyframe_loss: 0.0,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    pub model: DiffKfcConfig,
    #[serde(default)]
    pub diffusion: DiffusionConfig,
    #[serde(default)]
    pub data: DataConfig,
    #[serde(default)]
    pub keyframes: KeyframeConfig,
    #[serde(default)]
    pub training: TrainingConfig,
}

/// Every key of `v` must exist in `known` (recursively); returns the dotted path of the first
/// that does not.
fn unknown_key(v: &serde_json::Value, known: &serde_json::Value, path: &str) -> Option<String> {
    let (serde_json::Value::Object(a), serde_json::Value::Object(b)) = (v, known) else { return None };
    for (k, val) in a {
        let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
        match b.get(k) {
            None => return Some(p),
            Some(kn) => {
                if let Some(u) = unknown_key(val, kn, &p) {
                    return Some(u);
                }
            }
        }
    }
    None
}

impl RunConfig {
    /// Parse a config file; `"model": "tiny"` (a preset name) or an object of overrides on the
    /// paper defaults (`"preset": "tiny"` inside the object starts from that preset).
    pub fn load(path: &Path) -> Result<RunConfig, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    pub fn parse(text: &str) -> Result<RunConfig, String> {
        let mut v: serde_json::Value = serde_json::from_str(text).map_err(|e| format!("not valid JSON: {e}"))?;
        let model = v.get_mut("model").ok_or("missing section 'model'")?;
        let base = match model {
            serde_json::Value::String(name) => DiffKfcConfig::preset(name).ok_or(format!("model: unknown preset '{name}' (tiny, small, paper)"))?,
            serde_json::Value::Object(m) => match m.remove("preset") {
                Some(serde_json::Value::String(name)) => DiffKfcConfig::preset(&name).ok_or(format!("model.preset: unknown preset '{name}' (tiny, small, paper)"))?,
                Some(other) => return Err(format!("model.preset: expected a preset name, got {other}")),
                None => DiffKfcConfig::paper(),
            },
            other => return Err(format!("model: expected a preset name or an object, got {other}")),
        };
        // Overlay the given model keys on the preset.
        let mut merged = serde_json::to_value(&base).expect("config serialises");
        if let (serde_json::Value::Object(m), serde_json::Value::Object(out)) = (&*model, &mut merged) {
            for (k, val) in m {
                if !out.contains_key(k) {
                    return Err(format!("unknown key 'model.{k}'"));
                }
                out.insert(k.clone(), val.clone());
            }
        }
        *model = merged;
        let known = serde_json::to_value(RunConfig {
            model: base,
            diffusion: Default::default(),
            data: DataConfig { dir: Some(String::new()), ..Default::default() },
            keyframes: Default::default(),
            training: Default::default(),
        })
        .expect("config serialises");
        if let Some(k) = unknown_key(&v, &known, "") {
            return Err(format!("unknown key '{k}'"));
        }
        serde_json::from_value(v).map_err(|e| format!("bad value: {e}"))
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("config serialises")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_overrides_and_errors() {
        let c = RunConfig::parse(r#"{"model": "tiny", "training": {"lr": 0.001}}"#).unwrap();
        assert_eq!(c.model, DiffKfcConfig::tiny());
        assert_eq!(c.training.lr, 0.001);
        assert_eq!(c.training.batch_size, 64);
        let c = RunConfig::parse(r#"{"model": {"preset": "small", "dec_layers": 2}}"#).unwrap();
        assert_eq!(c.model.dec_layers, 2);
        assert_eq!(c.model.d_model, 256);
        let e = RunConfig::parse(r#"{"model": "tiny", "training": {"learning_rate": 1}}"#).unwrap_err();
        assert!(e.contains("training.learning_rate"), "{e}");
        let e = RunConfig::parse(r#"{"model": {"d_modle": 3}}"#).unwrap_err();
        assert!(e.contains("model.d_modle"), "{e}");
        let e = RunConfig::parse(r#"{"model": "tiny", "training": {"lr": "fast"}}"#).unwrap_err();
        assert!(e.contains("bad value"), "{e}");
        let e = RunConfig::parse(r#"{"model": "huge"}"#).unwrap_err();
        assert!(e.contains("unknown preset 'huge'"), "{e}");
        let e = RunConfig::parse(r#"{"model": "tiny", "keyframes": {"strategy": "sometimes"}}"#).unwrap_err();
        assert!(e.contains("bad value") && e.contains("sometimes"), "{e}");
    }

    #[test]
    fn shipped_configs_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        for name in ["tiny", "small", "paper-humanml3d", "paper-kit"] {
            let c = RunConfig::load(&dir.join(format!("{name}.json"))).unwrap();
            let again = RunConfig::parse(&c.to_json()).unwrap();
            assert_eq!(c, again, "{name} does not round-trip");
        }
    }
}

//! Run configuration files (`configs/*.json`): sections model, diffusion, data, keyframes,
//! training. Unknown or ill-typed keys are errors that name the key.

use std::path::Path;

use diffkfc_data::dataset::batch::KeyframeConfig;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::network::config::DiffKfcConfig;

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

impl DiffusionConfig {
    /// The noise schedule this section names.
    pub fn schedule(&self) -> Result<crate::diffusion::Schedule> {
        crate::diffusion::Schedule::by_name(&self.schedule, self.steps).ok_or_else(|| {
            ModelError::Config(format!(
                "diffusion.schedule: unknown '{}' (cosine, linear)",
                self.schedule
            ))
        })
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
    /// Weight of the error of frame-to-frame feature changes (`losses::l_smooth`; 0 = the paper).
    pub smooth_loss: f64,
    /// Weight of the 4 root channels in the reconstruction terms (`training::weighting`; 1 = the paper).
    pub root_loss_weight: f64,
    /// Weight of the 4 foot-contact channels in the reconstruction terms (1 = the paper).
    pub contact_loss_weight: f64,
    /// Probability that a training sample's text is dropped (a zero embedding), so that the
    /// text-free branch of text classifier-free guidance is learned (MDM: 0.1; 0 = off, the paper).
    /// Drawn independently of the keyframes' drop; validation keeps every text.
    pub text_drop_prob: f64,
    /// The text drop's probability for the samples whose keys were dropped
    /// (`keyframes.drop_prob`); unset = `text_drop_prob`. Text-only guidance subtracts the
    /// key-free, text-free branch, which `text_drop_prob` x `drop_prob` of the samples train
    /// (1% at 0.1 x 0.1); this raises that share without dropping keys or text elsewhere.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub text_drop_prob_unkeyed: Option<f64>,
    /// Share of the training samples whose x_t is one DDIM step, made with the network itself,
    /// from x0 noised at t + `rollout_gap` (`training::rollout`: the sampler's own step, so the
    /// network learns to correct its estimate rather than follow it; 0 = off, the paper).
    pub rollout_prob: f64,
    /// Timesteps between the noisier sample and x_t in a rolled-out sample (100: one step of a
    /// 10-step sampler over 1000).
    pub rollout_gap: usize,
    /// DDIM steps of a rolled-out sample, from t + steps * `rollout_gap` down to t (1: one step;
    /// each further step is one more forward pass of the network, without gradients).
    pub rollout_steps: usize,
    /// Substrings of the parameter names training may change (`["word"]`: only the word
    /// conditioning a model grown with `model.text_words` added); the rest keep the weights
    /// `--init` gave them. Empty = every parameter (the paper).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub trainable: Vec<String>,
}

impl TrainingConfig {
    /// Refuses a stop step past `max_steps` when the learning rate decays to 0 there: every
    /// further step would be wasted (a run continued that way once trained 3000 steps at lr 0).
    pub fn check_stop(&self, stop: usize) -> Result<()> {
        if self.cosine_decay && stop > self.max_steps {
            return Err(ModelError::Refused(format!(
                "--max-steps: {stop} is past training.max_steps {} of the config, where the cosine learning rate has decayed to 0; raise training.max_steps in the config instead",
                self.max_steps
            )));
        }
        Ok(())
    }
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
            smooth_loss: 0.0,
            root_loss_weight: 1.0,
            contact_loss_weight: 1.0,
            text_drop_prob: 0.0,
            text_drop_prob_unkeyed: None,
            rollout_prob: 0.0,
            rollout_gap: 100,
            rollout_steps: 1,
            trainable: Vec::new(),
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

impl RunConfig {
    /// Parse a config file; `"model": "tiny"` (a preset name) or an object of overrides on the
    /// paper defaults (`"preset": "tiny"` inside the object starts from that preset).
    pub fn load(path: &Path) -> Result<RunConfig> {
        let text = std::fs::read_to_string(path).map_err(ModelError::io(path))?;
        Self::parse(&text).map_err(|e| e.in_file(path))
    }

    pub fn parse(text: &str) -> Result<RunConfig> {
        let bad = |msg: String| ModelError::Config(msg);
        let mut v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| bad(format!("not valid JSON: {e}")))?;
        super::retired::strip(&mut v)?;
        let model = v.get_mut("model").ok_or(bad("missing section 'model'".into()))?;
        let base = match model {
            serde_json::Value::String(name) => DiffKfcConfig::preset(name)
                .ok_or(bad(format!("model: unknown preset '{name}' (tiny, mid, small, paper)")))?,
            serde_json::Value::Object(m) => match m.remove("preset") {
                Some(serde_json::Value::String(name)) => DiffKfcConfig::preset(&name).ok_or(
                    bad(format!("model.preset: unknown preset '{name}' (tiny, mid, small, paper)")),
                )?,
                Some(other) => {
                    return Err(bad(format!("model.preset: expected a preset name, got {other}")))
                }
                None => DiffKfcConfig::paper(),
            },
            other => {
                return Err(bad(format!("model: expected a preset name or an object, got {other}")))
            }
        };
        // Overlay the given model keys on the preset.
        let mut merged = serde_json::to_value(&base).expect("config serialises");
        if let (serde_json::Value::Object(m), serde_json::Value::Object(out)) =
            (&*model, &mut merged)
        {
            for (k, val) in m {
                if !out.contains_key(k) {
                    return Err(bad(format!("unknown key 'model.{k}'")));
                }
                out.insert(k.clone(), val.clone());
            }
        }
        *model = merged;
        // Every section denies unknown fields: the path names the key at fault.
        let cfg: RunConfig = serde_path_to_error::deserialize(v).map_err(|e| {
            let what = if e.inner().to_string().starts_with("unknown field") {
                "unknown key"
            } else {
                "bad value"
            };
            bad(format!("{}: {what}: {}", e.path(), e.inner()))
        })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Every value in its range, checked before anything is built from it (a zero width or
    /// batch would divide by zero, a huge one exhaust memory, a NaN train silently).
    pub fn validate(&self) -> Result<()> {
        self.check_sizes()?;
        self.check_model_options()?;
        self.check_training()
    }

    /// Sizes: at least 1, heads dividing d_model, small enough to fit any machine; a known schedule.
    fn check_sizes(&self) -> Result<()> {
        let m = &self.model;
        let t = &self.training;
        let positive = [
            ("model.feat_dim", m.feat_dim),
            ("model.text_dim", m.text_dim),
            ("model.d_model", m.d_model),
            ("model.heads", m.heads),
            ("model.ffn", m.ffn),
            ("model.max_frames", m.max_frames),
            ("diffusion.steps", self.diffusion.steps),
            ("training.batch_size", t.batch_size),
        ];
        for (key, v) in positive {
            if v == 0 {
                return bad(key, &v, "must be at least 1");
            }
        }
        self.diffusion.schedule()?;
        if !m.d_model.is_multiple_of(m.heads) {
            return Err(ModelError::Config(format!(
                "model.heads: {} does not divide model.d_model ({})",
                m.heads, m.d_model
            )));
        }
        // Sizes whose products would not fit in memory on any machine this runs on.
        let limits = [
            ("model.d_model", m.d_model, 16_384),
            ("model.ffn", m.ffn, 65_536),
            ("model.heads", m.heads, 256),
            ("model.dec_layers", m.dec_layers, 256),
            ("model.feat_dim", m.feat_dim, 4096),
            ("model.max_frames", m.max_frames, 196),
            ("training.batch_size", t.batch_size, 16_384),
            ("diffusion.steps", self.diffusion.steps, 100_000),
        ];
        for (key, v, max) in limits {
            if v > max {
                return bad(key, &v, &format!("is too large (at most {max})"));
            }
        }
        if m.dma_sizes.len() > 64 {
            return bad("model.dma_sizes", &m.dma_sizes.len(), "blocks is too many (at most 64)");
        }
        Ok(())
    }

    /// The model's options in their ranges (dropout, root channels, temporal kernel).
    fn check_model_options(&self) -> Result<()> {
        let m = &self.model;
        if !(0.0..1.0).contains(&m.dropout) {
            return bad("model.dropout", &m.dropout, "must be in [0, 1)");
        }
        if m.root_channels != 0 && m.root_channels != diffkfc_data::motion::root_key::ROOT_CHANNELS
        {
            return bad(
                "model.root_channels",
                &m.root_channels,
                &format!("must be 0 or {}", diffkfc_data::motion::root_key::ROOT_CHANNELS),
            );
        }
        if (m.temporal_kernel.is_multiple_of(2) && m.temporal_kernel != 0) || m.temporal_kernel > 31
        {
            return bad(
                "model.temporal_kernel",
                &m.temporal_kernel,
                "must be 0 (none) or an odd number up to 31",
            );
        }
        Ok(())
    }

    /// Rates in [0, 1], loss weights finite and non-negative, lr positive.
    fn check_training(&self) -> Result<()> {
        let t = &self.training;
        let k = &self.keyframes;
        let unit = [
            ("keyframes.rate", k.rate),
            ("keyframes.drop_prob", k.drop_prob),
            ("keyframes.root_drop_prob", k.root_drop_prob),
            ("keyframes.dense_root_prob", k.dense_root_prob),
            ("keyframes.dense_root_min_density", k.dense_root_min_density),
            ("keyframes.part_prob", k.part_prob),
            ("training.ema_decay", t.ema_decay),
            ("training.text_drop_prob", t.text_drop_prob),
            ("training.text_drop_prob_unkeyed", t.text_drop_prob_unkeyed.unwrap_or(0.0)),
            ("training.rollout_prob", t.rollout_prob),
        ];
        for (key, v) in unit {
            if !(0.0..=1.0).contains(&v) {
                return bad(key, &v, "must be in [0, 1]");
            }
        }
        if let Some(v) = k.max_observed_sigma.filter(|v| !(v.is_finite() && *v > 0.0)) {
            return bad("keyframes.max_observed_sigma", &v, "must be a finite number > 0");
        }
        if let Some(q) = t.text_drop_prob_unkeyed.filter(|_| t.text_drop_prob == 0.0) {
            // Text guidance of keyed samples needs the keyed text-free branch too.
            return bad("training.text_drop_prob_unkeyed", &q, "needs training.text_drop_prob > 0");
        }
        let non_negative = [
            ("training.grad_clip", t.grad_clip),
            ("training.lambda_pos", t.lambda_pos),
            ("training.lambda_vel", t.lambda_vel),
            ("training.lambda_foot", t.lambda_foot),
            ("training.keyframe_loss", t.keyframe_loss),
            ("training.smooth_loss", t.smooth_loss),
            ("training.root_loss_weight", t.root_loss_weight),
            ("training.contact_loss_weight", t.contact_loss_weight),
        ];
        for (key, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return bad(key, &v, "must be a finite number >= 0");
            }
        }
        if !(t.lr.is_finite() && t.lr > 0.0) {
            return bad("training.lr", &t.lr, "must be a finite number > 0");
        }
        if t.rollout_prob > 0.0 && !(1..=self.diffusion.steps).contains(&t.rollout_gap) {
            return bad(
                "training.rollout_gap",
                &t.rollout_gap,
                &format!("must be 1 to diffusion.steps ({})", self.diffusion.steps),
            );
        }
        if t.rollout_prob > 0.0 && !(1..=10).contains(&t.rollout_steps) {
            return bad("training.rollout_steps", &t.rollout_steps, "must be 1 to 10");
        }
        Ok(())
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("config serialises")
    }
}

/// The error of a config value out of its range.
fn bad(key: &str, v: &dyn std::fmt::Display, want: &str) -> Result<()> {
    Err(ModelError::Config(format!("{key}: {v} {want}")))
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
        let e = RunConfig::parse(r#"{"model": "tiny", "training": {"learning_rate": 1}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("training.learning_rate: unknown key"), "{e}");
        let e = RunConfig::parse(r#"{"model": {"d_modle": 3}}"#).unwrap_err().to_string();
        assert!(e.contains("model.d_modle"), "{e}");
        let e = RunConfig::parse(r#"{"model": "tiny", "training": {"lr": "fast"}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("training.lr: bad value"), "{e}");
        for (body, needle) in [
            (r#""training": {"batch_size": 0}"#, "training.batch_size: 0"),
            (r#""diffusion": {"steps": 0}"#, "diffusion.steps: 0"),
            (r#""training": {"batch_size": 100000}"#, "too large"),
            (r#""training": {"lr": -1}"#, "training.lr: -1"),
            (r#""training": {"ema_decay": 1.5}"#, "training.ema_decay: 1.5"),
            (r#""training": {"grad_clip": -1}"#, "training.grad_clip: -1"),
            (r#""training": {"root_loss_weight": -2}"#, "training.root_loss_weight: -2"),
            (r#""training": {"text_drop_prob": 1.5}"#, "training.text_drop_prob: 1.5"),
            (
                r#""training": {"text_drop_prob": 0.1, "text_drop_prob_unkeyed": 2}"#,
                "training.text_drop_prob_unkeyed: 2 must be in [0, 1]",
            ),
            (
                r#""training": {"text_drop_prob_unkeyed": 0.5}"#,
                "training.text_drop_prob_unkeyed: 0.5 needs training.text_drop_prob > 0",
            ),
            (r#""keyframes": {"rate": 2}"#, "keyframes.rate: 2"),
            (r#""keyframes": {"part_prob": -0.1}"#, "keyframes.part_prob: -0.1"),
            (r#""keyframes": {"max_observed_sigma": 0}"#, "keyframes.max_observed_sigma: 0"),
            (r#""training": {"rollout_prob": 2}"#, "training.rollout_prob: 2"),
            (r#""training": {"rollout_prob": 0.5, "rollout_gap": 0}"#, "training.rollout_gap: 0"),
            (
                r#""training": {"rollout_prob": 0.5, "rollout_steps": 0}"#,
                "training.rollout_steps: 0",
            ),
            (
                r#""training": {"rollout_prob": 1, "rollout_steps": 11}"#,
                "training.rollout_steps: 11",
            ),
            (r#""diffusion": {"schedule": "foo"}"#, "diffusion.schedule: unknown 'foo'"),
        ] {
            let e = RunConfig::parse(&format!(r#"{{"model": "tiny", {body}}}"#))
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{body}: {e}");
        }
        for (model, needle) in [
            (r#"{"preset": "tiny", "heads": 3}"#, "does not divide"),
            (r#"{"preset": "tiny", "d_model": 0}"#, "model.d_model: 0"),
            (r#"{"preset": "tiny", "dropout": 1.5}"#, "model.dropout: 1.5"),
            (r#"{"preset": "tiny", "temporal_kernel": 4}"#, "model.temporal_kernel: 4"),
        ] {
            let e = RunConfig::parse(&format!(r#"{{"model": {model}}}"#)).unwrap_err().to_string();
            assert!(e.contains(needle), "{model}: {e}");
        }
        let e = RunConfig::parse(
            r#"{"model": {"preset": "tiny", "absolute_root": true}, "training": {"lambda_pos": 1}}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("model.absolute_root: true") && e.contains("no longer"), "{e}");
        let e = RunConfig::parse(r#"{"model": "huge"}"#).unwrap_err().to_string();
        assert!(e.contains("unknown preset 'huge'"), "{e}");
        let e = RunConfig::parse(r#"{"model": "tiny", "keyframes": {"strategy": "sometimes"}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad value") && e.contains("sometimes"), "{e}");
    }

    #[test]
    fn shipped_configs_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let json = |d: &Path| -> Vec<std::path::PathBuf> {
            let files = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().path());
            files.filter(|p| p.extension().is_some_and(|e| e == "json")).collect()
        };
        // Run configs (the recipes are checked by run::recipe and tests/cli_train.rs).
        let paths: Vec<_> = json(&dir)
            .into_iter()
            .filter(|p| !p.to_string_lossy().ends_with(".recipe.json"))
            .collect();
        assert!(paths.len() >= 5, "{} configs", paths.len());
        for path in paths {
            let c = RunConfig::load(&path).unwrap();
            let again = RunConfig::parse(&c.to_json()).unwrap();
            assert_eq!(c, again, "{} does not round-trip", path.display());
        }
    }

    /// The study's options round-trip, and a config written before they existed (no such keys)
    /// reads as the paper's behaviour: uniform loss weights, whole keys.
    #[test]
    fn new_options_default_to_the_old_behaviour() {
        let old = RunConfig::parse(r#"{"model": "tiny", "training": {"lr": 0.001}}"#).unwrap();
        assert_eq!(old.model.text_words, 0);
        assert!(old.training.trainable.is_empty());
        let t = &old.training;
        assert_eq!((t.root_loss_weight, t.contact_loss_weight), (1.0, 1.0));
        assert_eq!((old.keyframes.part_prob, old.training.rollout_prob), (0.0, 0.0));
        assert_eq!(old.training.rollout_steps, 1);
        assert_eq!(old.training.text_drop_prob_unkeyed, None);
        assert_eq!(old.keyframes.max_observed_sigma, None);
        for key in ["text_drop_prob_unkeyed", "max_observed_sigma", "trainable"] {
            assert!(!old.to_json().contains(key), "old configs write as before: {key}");
        }
        let c = RunConfig::parse(
            r#"{"model": {"preset": "tiny", "text_words": 32},
                "keyframes": {"part_prob": 0.3, "max_observed_sigma": 30},
                "training": {"root_loss_weight": 8, "contact_loss_weight": 4,
                             "rollout_prob": 0.5, "rollout_gap": 50, "rollout_steps": 2,
                             "text_drop_prob": 0.1, "text_drop_prob_unkeyed": 0.5,
                             "trainable": ["word"]}}"#,
        )
        .unwrap();
        let again = RunConfig::parse(&c.to_json()).unwrap();
        assert_eq!(c, again);
        assert_eq!((again.model.text_words, again.training.root_loss_weight), (32, 8.0));
        assert_eq!(
            (again.keyframes.part_prob, again.keyframes.max_observed_sigma),
            (0.3, Some(30.0))
        );
        let t = &again.training;
        assert_eq!((t.rollout_prob, t.rollout_gap, t.rollout_steps), (0.5, 50, 2));
        assert_eq!(t.text_drop_prob_unkeyed, Some(0.5));
        assert_eq!((again.model.text_words, &t.trainable), (32, &vec!["word".to_string()]));
    }
}

//! A model's training recipe: the synthetic sets it learns from and its stages in order, each
//! a run config written as a JSON merge patch (RFC 7396) over the stage before and started
//! from the stage before's weights (`train --init`). `train --recipe` runs one from the start
//! or from where it stopped, so a shipped model is retrained by one command.
//!
//! ```json
//! {"model": "mid-synth",
//!  "data": {"legacy": {"body": "legacy"}, "humanml3d": {"body": "humanml3d"}},
//!  "stages": [
//!    {"name": "base", "data": "legacy", "config": {"model": "mid", "training": {"lr": 5e-4}}},
//!    {"name": "slower", "data": "legacy", "config": {"training": {"lr": 2e-4}}},
//!    {"name": "words", "data": "humanml3d", "stop_at": 1127, "config": {"model": {"text_words": 32}}}]}
//! ```

use std::collections::BTreeMap;

use diffkfc_synth::variation::MAX_STRENGTH;
use diffkfc_synth::{Body, SynthSpec, MAX_CLIPS};
use serde::Deserialize;
use serde_json::Value;

use crate::error::{ModelError, Result};
use crate::run::config::RunConfig;

/// A recipe as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// The model it trains (its directory under `models/`).
    pub model: String,
    /// What it is, for `--help`-like listings (free text).
    #[serde(default)]
    pub about: String,
    /// The synthetic sets, by the names stages use.
    pub data: BTreeMap<String, SynthSet>,
    pub stages: Vec<StageSpec>,
}

/// `data synth`'s options for one set.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSet {
    pub body: String,
    #[serde(default = "default_clips")]
    pub clips: usize,
    #[serde(default)]
    pub seed: u64,
    /// `data synth --vary`.
    #[serde(default)]
    pub vary: f64,
}

fn default_clips() -> usize {
    3000
}

/// One stage as written: its config is a merge patch over the previous stage's.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageSpec {
    pub name: String,
    pub data: String,
    pub config: Value,
    /// Stop at this step rather than at `training.max_steps` (whose decay it keeps): a stage
    /// that was cut short.
    pub stop_at: Option<usize>,
}

/// A stage resolved: its whole config (as JSON, as `train --config` reads it), its set and
/// the step it ends at.
#[derive(Clone, Debug)]
pub struct Stage {
    pub index: usize,
    pub name: String,
    pub data: String,
    pub config: Value,
    pub end_step: usize,
}

impl Stage {
    /// The stage's run directory name under the recipe's output: `03-rollout`.
    pub fn dir_name(&self) -> String {
        format!("{:02}-{}", self.index + 1, self.name)
    }
}

impl Recipe {
    /// Parse the JSON text; errors name where in the file the problem is.
    pub fn parse(text: &str) -> Result<Recipe> {
        let r: Recipe = diffkfc_data::io::keyframe_file::parse_json(text)?;
        if r.stages.is_empty() {
            return Err(ModelError::Config("stages: a recipe needs at least one stage".into()));
        }
        for (name, set) in &r.data {
            set.spec().map_err(|e| ModelError::Config(format!("data.{name}: {e}")))?;
        }
        Ok(r)
    }

    /// Every stage with its whole config (each patch merged over the one before), checked as
    /// a run config.
    pub fn stages(&self) -> Result<Vec<Stage>> {
        let mut config = Value::Object(Default::default());
        let mut out = Vec::new();
        for (index, s) in self.stages.iter().enumerate() {
            let at = |m: String| ModelError::Config(format!("stages[{index}] ({}): {m}", s.name));
            if !self.data.contains_key(&s.data) {
                let known: Vec<&str> = self.data.keys().map(String::as_str).collect();
                return Err(at(format!("data \"{}\" is not one of {}", s.data, known.join(", "))));
            }
            if s.name.is_empty() || !s.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-') {
                return Err(at("name: letters, digits and '-' only".into()));
            }
            json_patch::merge(&mut config, &s.config);
            let parsed = RunConfig::parse(&config.to_string()).map_err(|e| at(e.to_string()))?;
            let max = parsed.training.max_steps;
            let end_step = match s.stop_at {
                Some(n) if n == 0 || n > max => {
                    return Err(at(format!("stop_at: {n} must be 1 to training.max_steps ({max})")))
                }
                Some(n) => n,
                None => max,
            };
            let (name, data) = (s.name.clone(), s.data.clone());
            out.push(Stage { index, name, data, config: config.clone(), end_step });
        }
        Ok(out)
    }
}

impl SynthSet {
    /// The set's `data synth` spec.
    pub fn spec(&self) -> std::result::Result<SynthSpec, String> {
        let body: Body = self.body.parse()?;
        if self.clips == 0 || self.clips > MAX_CLIPS {
            return Err(format!("clips: {} must be 1 to {MAX_CLIPS}", self.clips));
        }
        if !(0.0..=MAX_STRENGTH).contains(&self.vary) {
            return Err(format!("vary: {} must be 0 to {MAX_STRENGTH}", self.vary));
        }
        Ok(SynthSpec { clips: self.clips, seed: self.seed, body, vary: self.vary })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = r#"{"model": "m", "data": {"a": {"body": "legacy"}},
      "stages": [
        {"name": "base", "data": "a", "config": {"model": "tiny", "training": {"lr": 5e-4, "max_steps": 10}}},
        {"name": "slow", "data": "a", "stop_at": 4, "config": {"training": {"lr": 2e-4}}}]}"#;

    #[test]
    fn patches_merge_over_the_stage_before() {
        let st = Recipe::parse(TWO).unwrap().stages().unwrap();
        assert_eq!(st.len(), 2);
        assert_eq!(st[1].config["training"]["lr"], 2e-4);
        assert_eq!(st[1].config["training"]["max_steps"], 10);
        assert_eq!(st[1].config["model"], "tiny");
        assert_eq!((st[0].end_step, st[1].end_step), (10, 4));
        assert_eq!(st[1].dir_name(), "02-slow");
    }

    #[test]
    fn bad_recipes_name_the_stage_and_field() {
        let cases = [
            (TWO.replace("\"stop_at\": 4", "\"stop_at\": 40"), "stages[1] (slow): stop_at: 40"),
            (
                TWO.replace("\"data\": \"a\", \"stop", "\"data\": \"b\", \"stop"),
                "data \"b\" is not one of a",
            ),
            (TWO.replace("\"lr\": 2e-4", "\"lr\": -1"), "stages[1] (slow): training.lr"),
            (TWO.replace("legacy", "giant"), "data.a: "),
            (
                TWO.replace("\"legacy\"}", "\"legacy\", \"vary\": 2.5}"),
                "data.a: vary: 2.5 must be 0 to 2",
            ),
            (TWO.replace("\"slow\"", "\"a b\""), "name: letters"),
        ];
        for (text, want) in cases {
            let e = Recipe::parse(&text).and_then(|r| r.stages()).unwrap_err().to_string();
            assert!(e.contains(want), "{want:?} not in {e}");
        }
        let e = Recipe::parse(r#"{"model": "m", "data": {}, "stages": []}"#).unwrap_err();
        assert!(e.to_string().contains("at least one stage"), "{e}");
    }
}

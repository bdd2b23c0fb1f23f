//! Config keys of options that were removed: a run or model written while they existed still
//! loads when it left them at their default (what the code now always does), and one that
//! turned them on is refused with the key named, instead of being read as something else.

use serde_json::Value;

use crate::error::{ModelError, Result};

/// A removed option: its section and key, the value (JSON) that behaves as the code now does,
/// and what it was.
struct Retired {
    section: &'static str,
    key: &'static str,
    neutral: &'static str,
    what: &'static str,
}

const RETIRED: &[Retired] = &[
    Retired { section: "model", key: "patch_frames", neutral: "1", what: "temporal patching" },
    Retired {
        section: "model",
        key: "absolute_root",
        neutral: "false",
        what: "the absolute-root representation",
    },
    Retired {
        section: "model",
        key: "velocity_stats",
        neutral: "[]",
        what: "the absolute-root representation",
    },
    Retired { section: "model", key: "root_path", neutral: "false", what: "the root path hint" },
    Retired {
        section: "training",
        key: "min_snr_gamma",
        neutral: "0",
        what: "min-SNR loss weighting",
    },
];

/// Removes the retired keys of `config` (a run config's JSON) that hold their neutral value;
/// errors on one that does not.
pub fn strip(config: &mut Value) -> Result<()> {
    for Retired { section, key, neutral, what } in RETIRED {
        let Some(Value::Object(s)) = config.get_mut(*section) else { continue };
        let Some(v) = s.remove(*key) else { continue };
        let neutral: Value = serde_json::from_str(neutral).expect("a JSON literal");
        let same = match (&v, neutral) {
            (Value::Number(a), Value::Number(b)) => a.as_f64() == b.as_f64(),
            (a, b) => *a == b,
        };
        if !same {
            return Err(ModelError::Config(format!(
                "{section}.{key}: {v}: {what} is no longer supported (a model trained with it \
                 needs an older diffkfc)"
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn neutral_values_are_dropped_and_others_refused() {
        let mut v = json!({"model": {"patch_frames": 1, "d_model": 64},
                           "training": {"min_snr_gamma": 0}});
        strip(&mut v).unwrap();
        assert_eq!(v, json!({"model": {"d_model": 64}, "training": {}}));
        let mut v = json!({"model": {"patch_frames": 4}});
        let e = strip(&mut v).unwrap_err().to_string();
        assert!(e.contains("model.patch_frames: 4") && e.contains("no longer"), "{e}");
    }
}

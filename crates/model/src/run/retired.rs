//! Config keys of options that were removed: a run or model written while they existed still
//! loads when it left them at their default (what the code now always does), and one that
//! turned them on is refused with the key named, instead of being read as something else.

use serde_json::{json, Value};

use crate::error::{ModelError, Result};

/// (section, key, the value that behaves as the code now does, what it was).
const RETIRED: &[(&str, &str, fn() -> Value, &str)] = &[
    ("model", "patch_frames", || json!(1), "temporal patching"),
    ("training", "min_snr_gamma", || json!(0.0), "min-SNR loss weighting"),
];

/// Removes the retired keys of `config` (a run config's JSON) that hold their neutral value;
/// errors on one that does not.
pub fn strip(config: &mut Value) -> Result<()> {
    for (section, key, neutral, what) in RETIRED {
        let Some(Value::Object(s)) = config.get_mut(*section) else { continue };
        let Some(v) = s.remove(*key) else { continue };
        let same = match (&v, neutral()) {
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

//! Checkpoints store tensors by module path: unique paths for every preset, a checkpoint whose
//! tensors come in another order loads into the right parameters, and a missing one is named.

use burn::prelude::*;
use diffkfc_model::run::checkpoint::Checkpoint;
use diffkfc_model::{network::params, DiffKfcConfig};

#[test]
fn every_parameter_has_a_unique_path() {
    for (name, cfg) in [("tiny", DiffKfcConfig::tiny()), ("paper", DiffKfcConfig::paper())] {
        let m = cfg.with_temporal_kernel(9).init(&Device::flex());
        let names = params::names(&m);
        assert_eq!(names.len(), params::shapes(&m).len(), "{name}");
        let mut sorted = names.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), names.len(), "{name}: duplicate paths in {names:?}");
        assert_eq!(
            (names[0].as_str(), names[names.len() - 1].as_str()),
            ("x_in.weight", "out.bias")
        );
    }
}

#[test]
fn named_tensors_load_in_any_order() {
    let m = DiffKfcConfig::tiny().init(&Device::flex());
    let names = params::names(&m);
    let vals = params::values(&m);
    // Stored in reverse order, as another version of the code might visit them.
    let rev = |v: Vec<Vec<f32>>| v.into_iter().rev().collect::<Vec<_>>();
    let model: Vec<Vec<f32>> = vals.iter().map(|(_, v)| v.clone()).collect();
    let ck = Checkpoint {
        step: 3,
        shapes: vals.iter().rev().map(|(s, _)| s.clone()).collect(),
        model: rev(model.clone()),
        ema: Some(rev(model.clone())),
        adam_step: 3,
        adam_m: rev(model.iter().map(|v| vec![0.5; v.len()]).collect()),
        adam_v: rev(model.iter().map(|v| vec![0.25; v.len()]).collect()),
        config: String::new(),
        seed: 1,
        names: names.iter().rev().cloned().collect(),
    };
    let dir = std::env::temp_dir().join(format!("diffkfc-ckpt-names-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = ck.save(&dir).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    // The metadata's seven entries come out in one order: saved again, the same bytes.
    let twice = std::env::temp_dir().join(format!("diffkfc-ckpt-again-{}", std::process::id()));
    std::fs::create_dir_all(&twice).unwrap();
    for _ in 0..3 {
        assert!(
            std::fs::read(ck.save(&twice).unwrap()).unwrap() == bytes,
            "checkpoint bytes differ"
        );
    }
    std::fs::remove_dir_all(&twice).ok();
    let has = |s: &str| bytes.windows(s.len()).any(|w| w == s.as_bytes());
    assert!(has("model/x_in.weight") && has("adam_m/out.bias") && !has("model/0000"));
    let mut back = Checkpoint::load(&path).unwrap();
    back.align(&names, &path).unwrap();
    assert_eq!(back.model, model);
    assert_eq!(back.ema.as_ref(), Some(&model));
    assert_eq!(back.shapes, vals.iter().map(|(s, _)| s.clone()).collect::<Vec<_>>());
    // The inference weights keep their names too.
    let w = back.save_weights(&dir, false).unwrap();
    let mut again = Checkpoint::load(&w).unwrap();
    again.align(&names, &w).unwrap();
    assert_eq!(again.model, model);
    // A model with a parameter the checkpoint lacks: the error names it.
    let mut other = names.clone();
    other[5] = "decoder.extra.weight".into();
    let e = Checkpoint::load(&path).unwrap().align(&other, &path).unwrap_err().to_string();
    assert!(e.contains("no tensor for parameter decoder.extra.weight"), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// A newest checkpoint holding non-finite weights is skipped (with a warning) in favour of the
/// last finite one: resuming from NaN would only produce NaN.
#[test]
fn the_newest_finite_checkpoint_is_used() {
    let m = DiffKfcConfig::tiny().init(&Device::flex());
    let vals = params::values(&m);
    let model: Vec<Vec<f32>> = vals.iter().map(|(_, v)| v.clone()).collect();
    let ck = |step: usize, model: Vec<Vec<f32>>| Checkpoint {
        step,
        shapes: vals.iter().map(|(s, _)| s.clone()).collect(),
        adam_m: model.iter().map(|v| vec![0.0; v.len()]).collect(),
        adam_v: model.iter().map(|v| vec![0.0; v.len()]).collect(),
        ema: None,
        model,
        adam_step: step as u64,
        config: String::new(),
        seed: 1,
        names: params::names(&m),
    };
    let dir = std::env::temp_dir().join(format!("diffkfc-ckpt-nan-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    ck(4, model.clone()).save(&dir).unwrap();
    let mut broken = model.clone();
    broken[3][7] = f32::NAN;
    ck(8, broken).save(&dir).unwrap();
    assert_eq!(Checkpoint::latest(&dir).unwrap().unwrap().step, 4);
    // With no finite checkpoint at all, the error says why.
    std::fs::remove_file(dir.join("ckpt-00000004.safetensors")).unwrap();
    let e = Checkpoint::latest(&dir).unwrap().unwrap_err().to_string();
    assert!(e.contains("ckpt-00000008") && e.contains("not finite"), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

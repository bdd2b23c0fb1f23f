//! `diffkfc eval inbetween`, the in-betweening benchmark, end to end: bad input, the report's
//! shape on a tiny model, and the committed reference model on the two real clips of the shared
//! fixtures keyed every second, against linear interpolation of the same keys.

mod common;

use common::*;
use std::path::{Path, PathBuf};

const MODEL: &str = "models/mid-synth";

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

#[test]
fn bad_gaps_and_counts_are_one_line_errors() {
    let dir = scratch("inbetween-bad");
    let (model, out) = (repo("models/tiny-synth"), dir.join("o"));
    let bench = |data: &Path, extra: &str| {
        diffkfc(&[
            "eval",
            "inbetween",
            "--checkpoint",
            s(&model),
            "--data",
            s(data),
            extra,
            "--out",
            s(&out),
        ])
    };
    for (gaps, needle) in
        [("0", "'0'"), ("-1", "'-1'"), ("5%x", "'5%x'"), ("0%", "'0%'"), (",", "lists no gap")]
    {
        assert_one_line_error(&bench(&dir, &format!("--gaps={gaps}")), &["--gaps", needle]);
    }
    let o = bench(&dir.join("none"), "--seed=1");
    assert_one_line_error(&o, &["none"]);
    // A clip with a NaN is named with the frame and feature.
    let data = dir.join("nan");
    for sub in ["new_joint_vecs", "texts"] {
        std::fs::create_dir_all(data.join(sub)).unwrap();
    }
    for stat in ["Mean.npy", "Std.npy"] {
        std::fs::copy(model.join(stat), data.join(stat)).unwrap();
    }
    let mut feats = vec![0.0f32; 50 * 263];
    feats[3 * 263 + 5] = f32::NAN;
    diffkfc_data::io::npy::write(data.join("new_joint_vecs/x.npy"), &[50, 263], &feats).unwrap();
    std::fs::write(data.join("texts/x.txt"), "a walk.#a/OTHER walk/OTHER#0.0#0.0\n").unwrap();
    std::fs::write(data.join("test.txt"), "x\n").unwrap();
    assert_one_line_error(&bench(&data, "--seed=1"), &["--data", "x.npy", "frame 3, feature 5"]);
    assert!(!dir.join("o").exists(), "a refused run wrote its --out");
}

/// A dataset folder of the two fixture clips (HumanML3D's real motion), captioned by us.
fn fixture_clips(dir: &Path) -> Option<PathBuf> {
    let clips = [
        (
            "012314",
            "humanml3d/new_joint_vecs/012314.npy",
            "a person walks forward, turns around and walks back.",
        ),
        ("000021", "humanml3d/000021_features_reference.npy", "a person walks in a circle."),
    ];
    let data = dir.join("real");
    for sub in ["new_joint_vecs", "texts"] {
        std::fs::create_dir_all(data.join(sub)).unwrap();
    }
    for (id, rel, caption) in clips {
        let src = diffkfc_data::testing::fixtures::require(rel)?;
        std::fs::copy(src, data.join("new_joint_vecs").join(format!("{id}.npy"))).unwrap();
        let tokens: Vec<String> = caption
            .trim_end_matches('.')
            .split_whitespace()
            .map(|w| format!("{}/OTHER", w.trim_end_matches(',')))
            .collect();
        std::fs::write(
            data.join("texts").join(format!("{id}.txt")),
            format!("{caption}#{}#0.0#0.0\n", tokens.join(" ")),
        )
        .unwrap();
    }
    for stat in ["Mean.npy", "Std.npy"] {
        std::fs::copy(repo(MODEL).join(stat), data.join(stat)).unwrap();
    }
    std::fs::write(data.join("test.txt"), "012314\n000021\n").unwrap();
    Some(data)
}

/// The benchmark's report.json of `model` on the fixture clips at `gaps` (None: skipped for
/// want of the text encoder or the fixtures).
fn report_on_fixture_clips(name: &str, model: &str, gaps: &str) -> Option<serde_json::Value> {
    if !have_text_encoder() {
        return None;
    }
    let dir = scratch(name);
    let data = fixture_clips(&dir)?;
    Some(run(&repo(model), &data, &dir.join("out"), gaps, &[]))
}

fn run(model: &Path, data: &Path, out: &Path, gaps: &str, extra: &[&str]) -> serde_json::Value {
    let mut args =
        vec!["eval", "inbetween", "--checkpoint", s(model), "--data", s(data), "--gaps", gaps];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", s(out)]);
    let o = diffkfc(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("| 1 s"), "{}", stdout(&o));
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn the_report_has_every_method_at_every_gap() {
    let Some(r) = report_on_fixture_clips("inbetween-tiny", "models/tiny-synth", "1,5%") else {
        return;
    };
    let summary = r["summary"].as_array().unwrap();
    assert_eq!(summary.len(), 2);
    for g in summary {
        let methods: Vec<&str> =
            g["methods"].as_array().unwrap().iter().map(|m| m[0].as_str().unwrap()).collect();
        assert_eq!(methods, ["clip", "interpolation", "network", "pipeline"]);
        for m in g["methods"].as_array().unwrap() {
            for (k, v) in m[1].as_object().unwrap() {
                assert!(v.as_f64().is_some_and(f64::is_finite), "{k}: {v}");
            }
        }
    }
    // The pipeline meets every keyed place; interpolation passes through the keys.
    for c in r["clips"].as_array().unwrap() {
        for g in c["gaps"].as_array().unwrap() {
            assert!(g["pipeline"]["key_place_m"].as_f64().unwrap() < 0.01, "{g}");
            assert_eq!(g["interpolation"]["key_place_m"].as_f64().unwrap(), 0.0);
        }
    }
    assert_eq!(r["clips"][0]["gaps"][0]["keys"].as_array().unwrap().first().unwrap(), 0);
}

/// `--no-balance`: the pipeline keeps the network's in-betweens. The tiny model misses real keys
/// by far, so by default its pipeline falls back on the keys' interpolation and its motion
/// changes (measured: error 0.110 m with the balance, 0.104 m without, interpolation's 0.104 m);
/// the network alone never passes through the fit.
#[test]
fn no_balance_keeps_the_network_in_betweens() {
    if !have_text_encoder() {
        return;
    }
    let dir = scratch("inbetween-balance");
    let Some(data) = fixture_clips(&dir) else { return };
    let tiny = repo("models/tiny-synth");
    let on = run(&tiny, &data, &dir.join("on"), "1", &[]);
    let off = run(&tiny, &data, &dir.join("off"), "1", &["--no-balance"]);
    let mean = |r: &serde_json::Value, method: &str| {
        r["summary"][0]["methods"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m[0] == method)
            .map(|m| m[1]["error_m"].as_f64().unwrap())
            .unwrap()
    };
    eprintln!(
        "tiny, 1 s: pipeline {:.3} with the balance, {:.3} without; interpolation {:.3}",
        mean(&on, "pipeline"),
        mean(&off, "pipeline"),
        mean(&on, "interpolation")
    );
    assert_eq!(mean(&on, "network"), mean(&off, "network"));
    assert!((mean(&on, "pipeline") - mean(&off, "pipeline")).abs() > 1e-3);
    for r in [&on, &off] {
        assert!(r["clips"][0]["gaps"][0]["pipeline"]["key_place_m"].as_f64().unwrap() < 0.01);
    }
}

/// What the committed model measured here (keys every second, seed 11): its pipeline's joint
/// error is 1.11x interpolation's on 012314 and 0.81x on 000021 (root-relative 1.12x and
/// 0.97x), 0.96x over the two; its toes are planted on 0.57x and 0.63x as many frames as the
/// clips' (0.33x and 0.59x, mean 0.46x, when the balance judged the whole body at once: 012314
/// raises its arms where the network does not, and its legs then leaned on the keys' sliding
/// interpolation too). The guards leave 0.04-0.07 for differences between machines; the issue's
/// target (below interpolation on both clips) is not met on 012314 (docs/inbetween.md).
const MAX_MEAN_RATIO: f64 = 1.0;
const MAX_EACH_RATIO: f64 = 1.18;
const MIN_MEAN_PLANTED: f64 = 0.56;

#[test]
fn the_reference_model_keyed_every_second_against_interpolation_on_real_clips() {
    let Some(r) = report_on_fixture_clips("inbetween-real", MODEL, "1") else { return };
    let (mut global, mut planted) = (Vec::new(), Vec::new());
    for c in r["clips"].as_array().unwrap() {
        let g = &c["gaps"][0];
        let ratio =
            |k: &str| g["pipeline"][k].as_f64().unwrap() / g["interpolation"][k].as_f64().unwrap();
        let share = |m: &str| g[m]["planted_share"].as_f64().unwrap();
        planted.push(share("pipeline") / share("clip"));
        eprintln!(
            "{}: pipeline / interpolation {:.3} (root-relative {:.3}), planted share / clip's {:.2}",
            c["id"],
            ratio("error_m"),
            ratio("error_local_m"),
            planted.last().unwrap()
        );
        assert!(
            ratio("error_m") <= MAX_EACH_RATIO && ratio("error_local_m") <= MAX_EACH_RATIO,
            "{}: {g}",
            c["id"]
        );
        global.push(ratio("error_m"));
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(mean(&global) <= MAX_MEAN_RATIO, "mean ratio {}", mean(&global));
    assert!(mean(&planted) >= MIN_MEAN_PLANTED, "planted share / clip's: {planted:?}");
}

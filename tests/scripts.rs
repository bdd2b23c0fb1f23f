//! The analysis scripts in scripts/ (the design study's measurements): bad arguments get one
//! line naming the argument and the value with exit status 2, and some run end to end against
//! the binary, so that a renamed flag of `diffkfc` cannot break them unnoticed.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Each analysis script, its positional arguments, and the label its first one is named by.
const SCRIPTS: &[(&str, usize, &str)] = &[
    ("design-panel", 2, "CONFIG"),
    ("feet-walks", 2, "MODEL"),
    ("raw-walks", 2, "MODEL"),
    ("text-only-root", 2, "MODEL"),
    ("timeline-table", 2, "MODEL"),
    ("reference-tables", 4, "MODEL"),
    ("fixture-walks", 2, "MODEL"),
];

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../scripts/{name}.sh"))
}

fn run_script(name: &str, args: &[&str], bin: &str) -> Output {
    Command::new("bash")
        .arg(script(name))
        .args(args)
        .env("DIFFKFC_BIN", bin)
        .output()
        .expect("bash runs")
}

/// Positional arguments: `first`, then existing directories.
fn positionals<'a>(n: usize, first: &'a str, rest: &'a str) -> Vec<&'a str> {
    std::iter::once(first).chain(std::iter::repeat_n(rest, n - 1)).collect()
}

#[test]
fn too_few_arguments_print_the_usage_line() {
    for (name, _, _) in SCRIPTS {
        let o = run_script(name, &[], env!("CARGO_BIN_EXE_diffkfc"));
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert_one_line_error(&o, &[&format!("usage: scripts/{name}.sh")]);
    }
}

#[test]
fn a_missing_model_or_config_is_named() {
    let dir = scratch("scripts-missing");
    let missing = dir.join("no-such-model");
    for (name, n, label) in SCRIPTS {
        let mut args = positionals(*n, s(&missing), s(&dir));
        if *name == "design-panel" {
            args.extend(["--steps", "1"]);
        }
        let o = run_script(name, &args, env!("CARGO_BIN_EXE_diffkfc"));
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert_one_line_error(&o, &[label, s(&missing), "does not exist"]);
    }
}

#[test]
fn unknown_flags_missing_data_and_an_unbuilt_binary_are_named() {
    let dir = scratch("scripts-flags");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let bin = env!("CARGO_BIN_EXE_diffkfc");
    for name in ["feet-walks", "raw-walks", "text-only-root"] {
        let o = run_script(name, &[s(&model), s(&dir), "--bogus"], bin);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert_one_line_error(&o, &["unknown argument '--bogus'", "usage:"]);

        let o = run_script(name, &[s(&model), s(&dir), "--data", s(&dir)], bin);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert_one_line_error(&o, &["--data", s(&dir), "no manifest.json"]);
    }
    let data = synth(&dir, 6, 1);
    let unbuilt = dir.join("no-such-binary");
    let o = run_script("raw-walks", &[s(&model), s(&dir), "--data", s(&data)], s(&unbuilt));
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_one_line_error(&o, &[s(&unbuilt), "not built"]);
}

/// `text-only-root.sh` samples two test clips (one walks at 0.75 m/s, one stands) from their
/// captions with the tiny reference model and compares their root speed with the sources'.
#[test]
fn bad_sample_counts_and_seeds_are_named_before_anything_runs() {
    let dir = scratch("scripts-counts");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let bin = env!("CARGO_BIN_EXE_diffkfc");
    let cases: &[(&str, &str, &str)] = &[
        ("feet-walks", "--samples", "0"),
        ("raw-walks", "--samples", "abc"),
        ("raw-walks", "--seed", "-1"),
        ("fixture-walks", "--samples", "2.5"),
        ("fixture-walks", "--seed", "x"),
        ("fixture-walks", "--key-sets", "0"),
        ("text-only-root", "--seed", ""),
        ("timeline-table", "--samples", "00"),
    ];
    for (name, flag, value) in cases {
        let o = run_script(name, &[s(&model), s(&dir), flag, value], bin);
        assert_eq!(o.status.code(), Some(2), "{name} {flag} '{value}': {}", stderr(&o));
        assert_one_line_error(&o, &[&format!("{flag} '{value}'"), "expected a whole number"]);
    }
    // A flag at the end with no value is named the same way, not bash's unbound variable.
    let o = run_script("raw-walks", &[s(&model), s(&dir), "--samples"], bin);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_one_line_error(&o, &["--samples ''", "expected a whole number"]);
}

#[test]
fn text_only_root_runs_against_the_binary() {
    if !have_text_encoder() {
        return;
    }
    let have_numpy = diffkfc_data::testing::fixtures::python(&["numpy"], "", &[]).is_some();
    if !have_numpy {
        return;
    }
    let dir = scratch("scripts-text-only");
    let data = synth(&dir, 24, 1);
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let out = dir.join("out");
    let args = [s(&model), s(&out), "--data", s(&data), "--count", "2", "--", "--steps", "2"];
    let o = run_script("text-only-root", &args, env!("CARGO_BIN_EXE_diffkfc"));
    assert!(o.status.success(), "{}", stderr(&o));
    let line = stdout(&o);
    assert!(line.starts_with("2 clips: root speed "), "{line}");
    assert!(line.contains("(sources ") && line.contains("|yaw rate| "), "{line}");
    assert!(!line.contains("nan") && !line.contains("n/a"), "{line}");
    let samples = std::fs::read_dir(&out)
        .unwrap()
        .filter(|e| e.as_ref().is_ok_and(|e| e.path().join("sample_00.npy").is_file()));
    assert_eq!(samples.count(), 2, "one sample per clip under {}", out.display());
}

/// `fixture-walks.sh` samples the two real fixture clips with the tiny reference model on two key
/// sets and tabulates the mean over both against the clip's own gait; a fixtures folder without
/// them is named.
#[test]
fn fixture_walks_runs_against_the_binary() {
    let Some(fixtures) = diffkfc_data::testing::fixtures::dir() else {
        diffkfc_data::testing::fixtures::require("humanml3d/new_joint_vecs/012314.npy");
        return;
    };
    let bin = env!("CARGO_BIN_EXE_diffkfc");
    let dir = scratch("scripts-fixture-walks");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let o = run_script("fixture-walks", &[s(&model), s(&dir), "--fixtures", s(&dir)], bin);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_one_line_error(&o, &["--fixtures", s(&dir), "012314.npy"]);
    if !have_text_encoder()
        || diffkfc_data::testing::fixtures::python(&["numpy"], "", &[]).is_none()
    {
        return;
    }
    let out = dir.join("out");
    let args =
        [s(&model), s(&out), "--fixtures", s(&fixtures), "--samples", "1", "--key-sets", "2"];
    let o = run_script("fixture-walks", &[&args[..], &["--", "--steps", "2"]].concat(), bin);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    assert_eq!(table.matches("| 012314 |").count(), 2, "{table}");
    assert_eq!(table.matches("| 000021 |").count(), 2, "{table}");
    assert!(!table.contains("nan") && table.contains(" ± "), "{table}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fixture-walks.json")).unwrap())
            .unwrap();
    let rows = json["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 4);
    // Each row is the mean over both key sets' samples, read back from the samples' own results.
    for row in rows {
        let (clip, mode) = (row["clip"].as_str().unwrap(), row["mode"].as_str().unwrap());
        let skating: Vec<f64> = [3, 4]
            .iter()
            .map(|seed| {
                let r = out.join(format!("{clip}-{mode}-seed{seed}")).join("results.json");
                let r: serde_json::Value =
                    serde_json::from_str(&std::fs::read_to_string(r).unwrap()).unwrap();
                r["samples"][0]["foot_skating"].as_f64().unwrap()
            })
            .collect();
        assert_eq!(row["samples"].as_u64(), Some(2), "{row}");
        let mean = (skating[0] + skating[1]) / 2.0;
        assert!((row["foot_skating"].as_f64().unwrap() - mean).abs() < 1e-9, "{row} vs {mean}");
    }
    // The clips' own skating is the real motion's, whatever the model.
    assert!((rows[0]["real_foot_skating"].as_f64().unwrap() - 0.129).abs() < 0.001);
}

/// `feet-walks.sh --samples 2` on the tiny reference model: every walk's row, and the planted
/// share line is the panel walks' per-walk mean shares summed against the sources', as read
/// back from the samples' own results (the quick start's walk, the last row, left out).
#[test]
fn feet_walks_sums_the_planted_share_over_the_samples() {
    if !have_text_encoder() {
        return;
    }
    let dir = scratch("scripts-feet-walks");
    let data = synth(&dir, 60, 1);
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let out = dir.join("out");
    let args = [s(&model), s(&out), "--data", s(&data), "--samples", "2"];
    let o = run_script("feet-walks", &args, env!("CARGO_BIN_EXE_diffkfc"));
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    let rows: Vec<&str> = table.lines().filter(|l| l.contains(" (seed ")).collect();
    assert!(rows.len() >= 2, "at least one panel walk and the quick start's walk: {table}");
    let (mut shares, mut sources) = (0.0, 0.0);
    for row in &rows[..rows.len() - 1] {
        let (walk, seed) = row[2..].split_once(" (seed ").unwrap();
        let case = out.join(format!("{walk}-seed{}", &seed[..1]));
        let read = |mode: &str| -> serde_json::Value {
            let text = std::fs::read_to_string(case.join(mode).join("results.json")).unwrap();
            serde_json::from_str(&text).unwrap()
        };
        let steps = read("steps");
        let samples = steps["samples"].as_array().unwrap();
        assert_eq!(samples.len(), 2, "{walk}");
        let mean =
            samples.iter().map(|x| x["gait"]["planted_share"].as_f64().unwrap()).sum::<f64>() / 2.0;
        shares += mean;
        sources += read("none")["real_gait"]["planted_share"].as_f64().unwrap();
    }
    let line = table.lines().find(|l| l.starts_with("planted share")).expect(&table);
    let walks = rows.len() - 1;
    assert!(line.contains(&format!("{walks} walks x 2 sample(s)")), "{line}");
    let want = format!("{:.3} of the sources' ({shares:.3} / {sources:.3})", shares / sources);
    assert!(line.ends_with(&want), "{line} against {want}");
}

/// Joints of a hand-made walk, 80 frames: each toe stands still on the floor for 10 frames at
/// x = 0.5 k (the left half a cycle later), then swings 12 cm above it to the next place;
/// `moved` shifts the right toe's second stance by that many metres, and `glide` keeps the
/// toes on the floor at 1 m/s instead of lifting them. Every other joint stays at the origin.
fn stepping(moved: f32, glide: bool) -> Vec<f32> {
    let (frames, half) = (80, 10);
    let mut j = vec![0.0f32; frames * 22 * 3];
    for f in 0..frames {
        for (toe, offset) in [(10, half), (11, 0)] {
            let t = f + offset;
            let (k, phase) = (t / (2 * half), t % (2 * half));
            let (mut x, mut y) = (0.5 * k as f32, 0.0);
            if phase >= half {
                x += 0.5 * (phase - half) as f32 / half as f32;
                y = 0.12;
            }
            if toe == 11 && k == 1 && phase < half {
                x += moved;
            }
            if glide {
                (x, y) = (f as f32 / 20.0, 0.0);
            }
            let at = (f * 22 + toe) * 3;
            j[at..at + 3].copy_from_slice(&[x, y, 0.0]);
        }
    }
    j
}

/// `stances.py` counts a moved stance as off by its distance, a glide as no stance, and names
/// bad arguments in one line.
#[test]
fn stances_match_hand_made_footprints() {
    if diffkfc_data::testing::fixtures::python(&["numpy"], "", &[]).is_none() {
        return;
    }
    let dir = scratch("scripts-stances");
    let npy = |name: &str, j: Vec<f32>| {
        let p = dir.join(name);
        diffkfc_data::io::npy::write(&p, &[80, 22, 3], &j).unwrap();
        p
    };
    let source = npy("source.npy", stepping(0.0, false));
    let moved = npy("moved.npy", stepping(0.1, false));
    let glide = npy("glide.npy", stepping(0.0, true));
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/stances.py");
    let run = |args: &[&str]| Command::new("python3").arg(&py).args(args).output().unwrap();
    let o = run(&[s(&moved), s(&source)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        stdout(&o),
        "right: 3 of 4 stances within 0.04 m of the source's 4; the others 0.10 m off\n\
         left: 4 of 4 stances within 0.04 m of the source's 4\n"
    );
    let o = run(&[s(&glide), s(&source)]);
    assert_eq!(stdout(&o), "right: 0 stances, source 4\nleft: 0 stances, source 4\n");
    let o = run(&[s(&source)]);
    assert_eq!(o.status.code(), Some(2));
    assert_one_line_error(&o, &["usage: scripts/stances.py"]);
    let o = run(&[s(&source), s(&source), "--within"]);
    assert_one_line_error(&o, &["--within needs a number"]);
    let o = run(&[s(&source), s(&source), "--within", "0"]);
    assert_one_line_error(&o, &["--within 0", "expected M > 0"]);
    let o = run(&[s(&source), s(&dir.join("absent.npy"))]);
    assert_one_line_error(&o, &["absent.npy", "No such file"]);
}

/// `text-ranks.py` groups top-3 misses (rank 3 or more; null ranks skipped) by caption
/// structure from a hand-made report, and names a bad report or argument in one line.
#[test]
fn text_ranks_group_misses_by_caption_structure() {
    if diffkfc_data::testing::fixtures::python(&["json"], "", &[]).is_none() {
        return;
    }
    let dir = scratch("scripts-text-ranks");
    let report = serde_json::json!({
        "meta": {"items": [[
            {"clip": "000001", "caption": "a person walks forward."},
            {"clip": "000002", "caption": "a man walks while waving."},
            {"clip": "000003", "caption": "a person jumps, then sits down."},
        ]]},
        "rows": [
            {"name": "Real motion", "real": true, "keyframe_rate": 0.0,
             "per_item": {"text_rank": [[0.0, 0.0, 2.0]]}},
            {"name": "DiffKFC", "real": false, "keyframe_rate": 0.05,
             "per_item": {"text_rank": [[0.0, 5.0, null]]}},
        ],
    });
    let good = dir.join("report.json");
    std::fs::write(&good, report.to_string()).unwrap();
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/text-ranks.py");
    let run = |args: &[&str]| Command::new("python3").arg(&py).args(args).output().unwrap();
    let o = run(&[s(&good), "--list", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        stdout(&o),
        "| row | single: items, top-3 misses | simultaneous: items, top-3 misses | sequence: items, top-3 misses |\n\
         |---|---|---|---|\n\
         | Real motion @ 0% | 1, 0.000 | 1, 0.000 | 1, 0.000 |\n\
         | DiffKFC @ 5% | 1, 0.000 | 1, 1.000 | 0, 0.000 |\n\
         1  a man walks while waving.\n"
    );
    let o = run(&[]);
    assert_eq!(o.status.code(), Some(2));
    assert_one_line_error(&o, &["usage: scripts/text-ranks.py", "report"]);
    assert_one_line_error(&run(&[s(&good), "--list", "a"]), &["--list", "'a'"]);
    let bad = dir.join("bad.json");
    std::fs::write(&bad, r#"{"meta": {}}"#).unwrap();
    let o = run(&[s(&bad)]);
    assert_eq!((o.status.code(), stdout(&o).as_str()), (Some(2), ""));
    assert_one_line_error(&o, &["bad.json", "not a diffkfc eval report", "items"]);
    assert_one_line_error(&run(&[s(&dir.join("absent.json"))]), &["absent.json", "No such file"]);
}

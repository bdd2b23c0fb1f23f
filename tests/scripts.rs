//! The analysis scripts in scripts/ (the design study's measurements): bad arguments get one
//! line naming the argument and the value with exit status 2, and one script runs end to end
//! against the binary, so that a renamed flag of `diffkfc` cannot break them unnoticed.

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
    ("track-walks", 3, "MODEL"),
    ("keyframe-fit-table", 4, "RUN"),
    ("reference-tables", 4, "MODEL"),
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

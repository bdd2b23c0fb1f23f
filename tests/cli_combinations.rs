//! End-to-end: every `sample` option that selects a behaviour, crossed pairwise (an all-pairs
//! cover, built and checked here), on a tiny model with key input, a temporal convolution and a
//! 20-step schedule; transition guidance stays on (its default), so that every pair that
//! involves keys also runs it (`--tg-mode exact` once panicked only with keys and guidance on).
//! Each combination exits 0 with finite outputs, or is refused at argument
//! time with one line naming the flags (no output folder made); the refusals are listed.

mod common;
use common::*;
use diffkfc_data::io::npy;
use diffkfc_data::testing::pairwise::{all_pairs, wrong_pairs};
use std::path::Path;

/// Factors and their levels.
const FACTORS: [(&str, &[&str]); 11] = [
    ("sampler", &["dpm", "ddim", "ddpm"]),
    ("tg-mode", &["x0", "exact"]),
    ("keyframe-fit", &["track", "warp", "paste", "none"]),
    ("keyframe-mode", &["diffkfc", "inpaint"]),
    ("foot-lock", &["on", "off"]),
    ("rigid", &["on", "off"]),
    ("place-guidance", &["0", "1"]),
    ("keys", &["none", "pose", "place", "pose+place", "suggested"]),
    ("prompt", &["text", "timeline", "body-parts"]),
    ("kf-guidance", &["1", "2.5"]),
    ("feet", &["steps", "network", "warp", "pin"]),
];

/// Pairs of levels the command refuses at argument time, each with a needle of its message:
/// a timeline keys its windows from a JSON keyframe file, not from a motion (`--from`).
/// A factor's level: (factor, level).
type Level = (&'static str, &'static str);

const REFUSED: [(Level, Level, &str); 2] = [
    (
        ("keys", "pose"),
        ("prompt", "timeline"),
        "'--timeline <SEGMENTS|FILE>' cannot be used with '--from <FROM>'",
    ),
    (
        ("keys", "pose+place"),
        ("prompt", "timeline"),
        "'--timeline <SEGMENTS|FILE>' cannot be used with '--from <FROM>'",
    ),
];

/// (factor, level) indices of a named level.
fn index(factor: &str, level: &str) -> (usize, usize) {
    let i = FACTORS.iter().position(|(n, _)| *n == factor).expect("a factor");
    (i, FACTORS[i].1.iter().position(|l| *l == level).expect("a level"))
}

/// Whether levels x of factor a and y of factor b may be combined (a < b).
fn allowed(a: usize, x: usize, b: usize, y: usize) -> bool {
    !REFUSED.iter().any(|&((f1, l1), (f2, l2), _)| {
        let (p, q) = (index(f1, l1), index(f2, l2));
        (p, q) == ((a, x), (b, y)) || (q, p) == ((a, x), (b, y))
    })
}

/// The all-pairs cover of [`FACTORS`] without the refused pairs.
fn cover() -> Vec<Vec<usize>> {
    let levels: Vec<usize> = FACTORS.iter().map(|(_, l)| l.len()).collect();
    all_pairs(&levels, allowed)
}

#[test]
fn the_cover_covers_every_pair() {
    let levels: Vec<usize> = FACTORS.iter().map(|(_, l)| l.len()).collect();
    let rows = cover();
    assert_eq!(wrong_pairs(&levels, &rows, allowed), vec![]);
    // Far fewer than the full product (2 * 3 * 3 * 4 * 5 * 2^5 = 11520 here).
    assert!(rows.len() <= 30, "{} rows", rows.len());
}

/// The tiny model: key input and a temporal convolution (the paths the reference model uses),
/// a 20-step schedule so DDPM runs every step quickly.
const RUN: &str = r#"{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0], "key_input": true, "temporal_kernel": 3},
  "diffusion": {"steps": 20},
  "training": {"batch_size": 4, "max_steps": 2, "checkpoint_every": 2, "val_every": 0}}"#;

/// The command line of one row.
fn args(row: &[usize], run: &Path, src: &Path, keys: &Path, out: &Path) -> Vec<String> {
    let level = |name: &str| {
        let (i, (_, levels)) =
            FACTORS.iter().enumerate().find(|(_, (n, _))| *n == name).expect("a factor");
        levels[row[i]]
    };
    let mut a: Vec<String> = ["sample", "--checkpoint", s(run), "--steps", "2", "--out", s(out)]
        .iter()
        .map(|x| x.to_string())
        .collect();
    let mut push = |xs: &[&str]| a.extend(xs.iter().map(|x| x.to_string()));
    for name in ["sampler", "tg-mode", "keyframe-fit", "keyframe-mode", "kf-guidance", "feet"] {
        push(&[&format!("--{name}"), level(name)]);
    }
    push(&["--place-guidance", level("place-guidance")]);
    if level("foot-lock") == "off" {
        push(&["--no-foot-lock"]);
    }
    if level("rigid") == "off" {
        push(&["--no-rigid"]);
    }
    match level("prompt") {
        "text" => push(&["--text", "a person walks forward."]),
        "timeline" => {
            push(&["--timeline", "0-1s: a person walks forward | 1-2.5s: a person jumps"])
        }
        _ => push(&["--text-lower", "a person walks forward.", "--text-upper", "a person waves."]),
    }
    match level("keys") {
        "none" => {}
        "pose" => push(&["--from", s(src), "--frames", "0,20,39", "--no-root-keys"]),
        "place" => push(&["--keyframes", s(&keys.join("place.json"))]),
        "pose+place" => push(&["--from", s(src), "--frames", "0,20,39"]),
        _ => push(&["--keyframes", s(&keys.join("suggested.json"))]),
    }
    if level("prompt") != "timeline" && !matches!(level("keys"), "pose" | "pose+place") {
        push(&["--length", "40"]);
    }
    a
}

#[test]
fn sample_options_crossed_pairwise() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("combinations");
    let data = synth(&d, 12, 5);
    let cfg = d.join("run.json");
    std::fs::write(&cfg, RUN).unwrap();
    let run = d.join("run");
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let src = data.join("new_joint_vecs/000000.npy");
    std::fs::write(
        d.join("place.json"),
        r#"{"length": 40, "keyframes": [{"frame": 0, "root": [0, 0.9, 0], "heading": 0}, {"frame": 39, "root": [0.2, 0.9, 1.5]}]}"#,
    )
    .unwrap();
    let o = diffkfc(&[
        "keyframes",
        "suggest",
        "--checkpoint",
        s(&run),
        "--text",
        "a person walks forward.",
        "--length",
        "40",
        "--count",
        "3",
        "--steps",
        "2",
        "-o",
        s(&d.join("suggested.json")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = cover();
    eprintln!("{} combinations of {} factors", rows.len(), FACTORS.len());
    let mut failures = Vec::new();
    for (k, row) in rows.iter().enumerate() {
        let out = d.join(format!("out{k:02}"));
        let a = args(row, &run, &src, &d, &out);
        let o = diffkfc(&a.iter().map(String::as_str).collect::<Vec<_>>());
        let err = stderr(&o);
        let shown = a[5..].join(" ");
        if err.contains("panicked") {
            failures.push(format!("panic: {shown}: {err}"));
        } else if !o.status.success() {
            failures.push(format!("refused: {shown}: {}", err.trim()));
        } else {
            let f = npy::read_f32(out.join("sample_00.npy")).unwrap();
            let j = npy::read_f32(out.join("sample_00_joints.npy")).unwrap();
            let finite = f.data.iter().chain(&j.data).all(|v| v.is_finite());
            let json = std::fs::read_to_string(out.join("results.json")).unwrap();
            if !finite || json.contains("NaN") {
                failures.push(format!("not finite: {shown}"));
            }
            // The foot post-process asked for is the one that ran.
            let feet = a.iter().position(|x| x == "--feet").map(|i| a[i + 1].clone());
            let r: serde_json::Value = serde_json::from_str(&json).unwrap();
            let want = if a.iter().any(|x| x == "--no-foot-lock") { None } else { feet };
            if r["feet"].as_str().map(str::to_string) != want {
                failures.push(format!("feet {:?} recorded as {}: {shown}", want, r["feet"]));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of the combinations failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
    // The refused pairs: one line at argument time, no output folder.
    for (k, &(a, b, needle)) in REFUSED.iter().enumerate() {
        let mut row = vec![0; FACTORS.len()];
        for (factor, level) in [a, b] {
            let (i, l) = index(factor, level);
            row[i] = l;
        }
        let out = d.join(format!("refused{k}"));
        let a = args(&row, &run, &src, &d, &out);
        let o = diffkfc(&a.iter().map(String::as_str).collect::<Vec<_>>());
        assert_one_line_error(&o, &[needle]);
        assert!(!out.exists());
    }
}

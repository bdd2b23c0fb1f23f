//! End-to-end tests of `diffkfc data check`.

mod common;
use common::*;
use diffkfc_data::{io::npy, testing::fixtures};
use std::path::Path;

fn clip(root: &Path, id: &str, data: &[f32], frames: usize, caption: &str) {
    npy::write(
        root.join(format!("new_joint_vecs/{id}.npy")),
        &[frames, data.len() / frames.max(1)],
        data,
    )
    .unwrap();
    std::fs::write(root.join(format!("texts/{id}.txt")), caption).unwrap();
}

/// The three split files, each listing `ids`' lines.
fn splits(root: &Path, [train, val, test]: [&str; 3]) {
    for (name, ids) in [("train", train), ("val", val), ("test", test)] {
        std::fs::write(root.join(format!("{name}.txt")), ids).unwrap();
    }
}

fn base(name: &str) -> Option<(Scratch, Vec<f32>)> {
    let feats =
        npy::read_f32(fixtures::require("humanml3d/new_joint_vecs/012314.npy")?).unwrap().data;
    let d = scratch(name);
    std::fs::create_dir_all(d.join("new_joint_vecs")).unwrap();
    std::fs::create_dir_all(d.join("texts")).unwrap();
    for f in ["Mean.npy", "Std.npy"] {
        std::fs::copy(fixtures::require(&format!("humanml3d/{f}")).unwrap(), d.join(f)).unwrap();
    }
    Some((d, feats))
}

const CAP: &str = "a person walks forward.#a/DET person/NOUN walk/VERB forward/ADV#0.0#0.0\nsomeone walks.#someone/PRON walk/VERB#0.0#0.0\n";

#[test]
fn clean_dataset_passes_with_statistics() {
    let Some((d, feats)) = base("check-clean") else {
        return;
    };
    clip(&d, "000001", &feats, 170, CAP);
    clip(&d, "M000001", &feats, 170, CAP);
    clip(&d, "000002", &feats[..100 * 263], 100, CAP);
    splits(&d, ["000001\nM000001\n", "000002\n", "000002\n"]);
    let o = diffkfc(&["data", "check", s(&d)]);
    assert!(o.status.success(), "{}{}", stdout(&o), stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("OK: no problems found"), "{out}");
    assert!(out.contains("distinct words: 5"), "{out}");
    let o = diffkfc(&["data", "check", s(&d), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["splits"][0]["clips"], 2);
    assert_eq!(v["splits"][0]["items"], 2);
    assert_eq!(v["splits"][0]["frames"], 340);
    assert_eq!(v["splits"][0]["captions"], 4);
    assert_eq!(v["problems"].as_array().unwrap().len(), 0);
    // 170-frame clips fall in the 160-179 bin.
    assert_eq!(v["length_histogram"][8][2], 2);
}

/// A frame far outside the distribution (a yaw-rate spike, as a fast synthetic spin's facing
/// flip makes) is listed with its clip, frame and feature, and is not a problem.
#[test]
fn values_far_from_the_mean_are_listed() {
    let Some((d, feats)) = base("check-outlier") else {
        return;
    };
    let std = npy::read_f32(d.join("Std.npy")).unwrap().data;
    let mean = npy::read_f32(d.join("Mean.npy")).unwrap().data;
    let mut spiked = feats.clone();
    spiked[40 * 263] = mean[0] + 120.0 * std[0];
    clip(&d, "000001", &feats, 170, CAP);
    clip(&d, "000002", &spiked, 170, CAP);
    splits(&d, ["000001\n000002\n", "000001\n", "000001\n"]);
    let o = diffkfc(&["data", "check", s(&d)]);
    assert!(o.status.success(), "{}{}", stdout(&o), stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("OK: no problems found"), "{out}");
    let line = out.lines().find(|l| l.contains("000002.npy")).unwrap_or_else(|| panic!("{out}"));
    assert!(
        line.contains("frame 40, feature 0 (root yaw rate") && line.contains(": 120 std"),
        "{line}"
    );
    let o = diffkfc(&["data", "check", s(&d), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // The real clip's own largest value (24 std, a fast arm) is not listed.
    assert_eq!(v["outliers"].as_array().unwrap().len(), 1, "{}", v["outliers"]);
    assert_eq!(
        (v["outliers"][0]["frame"].as_u64(), v["outliers"][0]["feature"].as_u64()),
        (Some(40), Some(0))
    );
}

#[test]
fn every_problem_is_listed() {
    let Some((d, feats)) = base("check-broken") else {
        return;
    };
    clip(&d, "good", &feats, 170, CAP);
    let mut nan = feats.clone();
    nan[5 * 263 + 9] = f32::NAN;
    clip(&d, "nan", &nan, 170, CAP);
    clip(&d, "width", &vec![0.0; 50 * 100], 50, CAP);
    clip(&d, "short", &feats[..263], 1, CAP);
    // Finite but absurd: training on it went NaN at step 5.
    let mut huge = feats.clone();
    huge[7 * 263 + 1] = 1e30;
    clip(&d, "huge", &huge, 170, CAP);
    clip(&d, "badcap", &feats, 170, "a caption without tags\n");
    npy::write(d.join("new_joint_vecs/notext.npy"), &[170, 263], &feats).unwrap();
    std::fs::write(d.join("texts/nomotion.txt"), CAP).unwrap();
    let bytes = std::fs::read(d.join("new_joint_vecs/good.npy")).unwrap();
    std::fs::write(d.join("new_joint_vecs/trunc.npy"), &bytes[..1000]).unwrap();
    std::fs::write(d.join("texts/trunc.txt"), CAP).unwrap();
    std::fs::write(
        d.join("train.txt"),
        "good\nnan\nwidth\nshort\nbadcap\nnotext\nnomotion\ntrunc\nhuge\n",
    )
    .unwrap();
    std::fs::write(d.join("test.txt"), "good\n").unwrap();
    // val.txt missing
    let o = diffkfc(&["data", "check", s(&d)]);
    assert!(!o.status.success());
    let out = stdout(&o);
    let expect = [
        ("val.txt", "split list unreadable"),
        ("nan.npy", "NaN or infinite value at frame 5, feature 9"),
        ("width.npy", "expected (T, 263)"),
        ("short.npy", "1 frame(s)"),
        ("badcap.txt", "line 1: expected 4 '#'-separated fields"),
        ("notext.txt", "No such file"),
        ("nomotion.npy", "No such file"),
        ("trunc.npy", "truncated data"),
        (
            "huge.npy",
            "frame 7, feature 1 (root velocity (per frame)) is 1000000000000000000000000000000",
        ),
    ];
    for (file, problem) in expect {
        assert!(
            out.lines().any(|l| l.contains(file) && l.contains(problem)),
            "{file}: {problem} missing in\n{out}"
        );
    }
    assert!(out.contains("9 problem(s) found"), "{out}");
    let o = diffkfc(&["data", "check", s(&d), "--json"]);
    assert!(!o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["problems"].as_array().unwrap().len(), 9);
    assert_eq!(v["splits"][0]["clips"], 1);
}

#[test]
fn missing_normalisation_is_reported() {
    let d = scratch("check-empty");
    // Each says what is wrong and what a dataset directory holds.
    let garbage = d.join("garbage");
    std::fs::create_dir_all(&garbage).unwrap();
    std::fs::write(garbage.join("notes.txt"), "x").unwrap();
    let file = d.join("file.npy");
    std::fs::write(&file, "x").unwrap();
    let empty = d.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    for (dir, why) in [
        (d.join("missing"), "dataset directory not found"),
        (file, "is a file, not a dataset directory"),
        (empty, "the directory is empty"),
        (garbage, "no Mean.npy: not a dataset directory"),
    ] {
        let o = diffkfc(&["data", "check", s(&dir)]);
        assert!(!o.status.success());
        let out = stdout(&o);
        assert!(
            out.contains(why) && out.contains("holds Mean.npy, Std.npy, new_joint_vecs/"),
            "{out}"
        );
    }
}

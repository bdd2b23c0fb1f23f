//! `diffkfc sample --timeline`: a long motion from a timeline of prompts, joined with no seam,
//! hitting keyframes placed anywhere on it; every bad timeline gives one clear line.

mod common;
use std::path::Path;

use common::*;
use diffkfc_data::io::npy;

fn steps(j: &[f32]) -> Vec<f32> {
    // Largest joint move from each frame to the next (metres).
    let f: Vec<&[f32]> = j.chunks(66).collect();
    f.windows(2)
        .map(|w| {
            (0..22)
                .map(|k| {
                    (0..3).map(|c| (w[1][3 * k + c] - w[0][3 * k + c]).powi(2)).sum::<f32>().sqrt()
                })
                .fold(0.0, f32::max)
        })
        .collect()
}

#[test]
fn thirty_seconds_join_without_seams_and_hit_keys() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("timeline");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    // A keyframe in the fourth window: the pelvis at a place 3 m to the side, facing +X.
    let keys = d.join("keys.json");
    std::fs::write(
        &keys,
        r#"{"keyframes": [{"frame": 450, "root": [3.0, 0.9, 12.0], "heading": 90}]}"#,
    )
    .unwrap();
    let tl = d.join("timeline.txt");
    std::fs::write(&tl, "// a long walk\n0-8s: a person walks forward.\n8-11s: a person jumps forward.\n11-20s: a person walks in a circle.\n20-30s: a person runs forward.\n").unwrap();
    let out = d.join("out");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--timeline",
        s(&tl),
        "--keyframes",
        s(&keys),
        "--steps",
        "4",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(r["length"], 600);
    assert_eq!(r["timeline"].as_array().unwrap().len(), 4);
    let joins: Vec<usize> =
        r["joins"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
    assert!(
        joins.len() >= 4 && joins.contains(&160) && joins.contains(&220) && joins.contains(&400),
        "{joins:?}"
    );
    let j = npy::read_f32(out.join("sample_00_joints.npy")).unwrap();
    assert_eq!(j.shape, vec![600, 22, 3]);
    let st = steps(&j.data);
    let mut away: Vec<f32> = st
        .iter()
        .enumerate()
        .filter(|(f, _)| joins.iter().all(|j| (f + 1).abs_diff(*j) > 3))
        .map(|(_, v)| *v)
        .collect();
    away.sort_by(f32::total_cmp);
    let p95 = away[away.len() * 95 / 100];
    for &k in &joins {
        eprintln!("join at frame {k}: largest joint move {:.3} m (elsewhere: median {:.3}, 95th percentile {p95:.3})", st[k - 1], away[away.len() / 2]);
        assert!(st[k - 1] <= p95, "a seam at frame {k}: {} m", st[k - 1]);
    }
    // The keyed place and heading, on the whole timeline's frame.
    let pelvis = &j.data[450 * 66..450 * 66 + 3];
    let miss = ((pelvis[0] - 3.0).powi(2) + (pelvis[2] - 12.0).powi(2)).sqrt();
    eprintln!("keyframe at frame 450: pelvis {miss:.4} m from the keyed place");
    assert!(miss < 1e-3, "{pelvis:?}");
    // Facing +X puts the left hip (joint 1) on -Z of the right hip (joint 2).
    let (l, r) = (&j.data[450 * 66 + 3..450 * 66 + 6], &j.data[450 * 66 + 6..450 * 66 + 9]);
    let (dx, dz) = (l[0] - r[0], l[2] - r[2]);
    let facing_z = -dz / (dx * dx + dz * dz).sqrt();
    assert!(facing_z > 0.95, "hips at frame 450 do not face +X: left-right ({dx}, {dz})");
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("a person jumps forward.") && html.contains("\"segments\""));
}

#[test]
fn bad_timelines_give_one_line() {
    let d = scratch("timeline-bad");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    for (spec, needle) in [
        ("0-4s: walk | 5-8s: jump", "a gap"),
        ("0-4s: walk | 3-8s: jump", "an overlap"),
        ("0-0.5s: walk", "at least 1 s"),
        ("0-4s:", "empty text"),
        ("walk", "START-END"),
        // Bounded: this once planned 10 753 windows (and 1e9 s aborted allocating 21 TB).
        ("0-100000s: walk", "a timeline lasts at most 600 s"),
        ("0-1e9s: walk", "at most 600 s"),
    ] {
        let o = diffkfc(&[
            "sample",
            "--checkpoint",
            s(&model),
            "--timeline",
            spec,
            "--out",
            s(&d.join("o")),
        ]);
        assert_one_line_error(&o, &["--timeline", needle]);
    }
    let keys = d.join("keys.json");
    std::fs::write(&keys, r#"{"keyframes": [{"frame": 200, "root": [0, 0.9, 1]}]}"#).unwrap();
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--timeline",
        "0-5s: walk",
        "--keyframes",
        s(&keys),
        "--out",
        s(&d.join("o")),
    ]);
    assert_one_line_error(&o, &["keys.json", "frame 200 is beyond the length 100"]);
    assert!(!d.join("o").exists(), "nothing written on error");
}

//! End-to-end: what a prompt alone can ask of `diffkfc sample`: body-part prompts (a text for
//! the lower and one for the upper body) and keyframes suggested by `diffkfc keyframes suggest`.

mod common;
use common::*;
use diffkfc_data::io::npy;

/// Body-part prompts: the lower body is exactly that of the plain lower-body prompt with the
/// same seed, and the upper body follows its own text (raised arms here, not the walk's swing).
#[test]
fn body_part_prompts_keep_the_lower_body_and_follow_the_upper_text() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("parts");
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let run = |args: &[&str], out: &str| {
        let o = diffkfc(
            &[
                &[
                    "sample",
                    "--checkpoint",
                    s(&model),
                    "--seed",
                    "3",
                    "--num-samples",
                    "2",
                    "--steps",
                    "6",
                    "--out",
                    s(&d.join(out)),
                ],
                args,
            ]
            .concat(),
        );
        assert!(o.status.success(), "{}", stderr(&o));
        (0..2)
            .map(|i| {
                npy::read_f32(d.join(out).join(format!("sample_{i:02}_joints.npy"))).unwrap().data
            })
            .collect::<Vec<_>>()
    };
    let walk = run(&["--text", "a person walks forward."], "walk");
    let parts = run(
        &["--text-lower", "a person walks forward.", "--text-upper", "a person raises both arms."],
        "parts",
    );
    let lower = [0, 1, 2, 4, 5, 7, 8, 10, 11];
    for (w, p) in walk.iter().zip(&parts) {
        let frames = w.len() / 66;
        let lower_diff = (0..frames)
            .flat_map(|f| lower.map(|j| (f, j)))
            .flat_map(|(f, j)| (0..3).map(move |c| f * 66 + j * 3 + c))
            .map(|k| (w[k] - p[k]).abs())
            .fold(0.0, f32::max);
        assert!(lower_diff < 1e-3, "lower body moved by {lower_diff} m");
        let wrists_up = |m: &[f32]| {
            (0..frames)
                .map(|f| (m[f * 66 + 20 * 3 + 1] + m[f * 66 + 21 * 3 + 1]) / 2.0 - m[f * 66 + 1])
                .fold(f32::MIN, f32::max)
        };
        eprintln!(
            "wrists above the pelvis at most: walk {:.2} m, with raised arms {:.2} m",
            wrists_up(w),
            wrists_up(p)
        );
        assert!(wrists_up(p) > wrists_up(w) + 0.2);
    }
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--text-lower",
        "walk",
        "--out",
        s(&d.join("x")),
    ]);
    assert!(!o.status.success() && stderr(&o).contains("--text-upper"), "{}", stderr(&o));
}

/// `keyframes suggest` writes a keyframe file that `sample --keyframes` reads back and hits:
/// the keyed places exactly, the poses to within the facing the file's pose implies.
#[test]
fn suggested_keyframes_read_back_and_are_hit() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("suggest");
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    let keys = d.join("keys.json");
    let o = diffkfc(&[
        "keyframes",
        "suggest",
        "--checkpoint",
        s(&model),
        "--text",
        "a person jumps forward.",
        "--count",
        "4",
        "--length",
        "80",
        "--steps",
        "4",
        "-o",
        s(&keys),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let k: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&keys).unwrap()).unwrap();
    let kf = k["keyframes"].as_array().unwrap();
    assert_eq!((k["length"].as_u64(), kf.len()), (Some(80), 4));
    let out = d.join("out");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--text",
        "a person jumps forward.",
        "--keyframes",
        s(&keys),
        "--steps",
        "4",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = npy::read_f32(out.join("sample_00_joints.npy")).unwrap().data;
    for key in kf {
        let f = key["frame"].as_u64().unwrap() as usize;
        let root: Vec<f32> =
            key["root"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
        let p = &j[f * 66..f * 66 + 66];
        let miss = ((p[0] - root[0]).powi(2) + (p[2] - root[2]).powi(2)).sqrt();
        let pose: Vec<f32> = key["joints"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|q| {
                q.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect::<Vec<_>>()
            })
            .collect();
        let rel = (0..66)
            .map(|c| ((p[c] - p[c % 3]) - (pose[c] - pose[c % 3])).abs())
            .fold(0.0, f32::max);
        eprintln!("suggested key at frame {f}: place missed by {miss:.4} m, root-relative pose by {rel:.4} m");
        assert!(miss < 1e-3 && rel < 0.05, "frame {f}: {miss} {rel}");
    }
    // From a motion, evenly spaced; bad counts and rates.
    let Some(src) = diffkfc_data::testing::fixtures::require("humanml3d/new_joint_vecs/012314.npy")
    else {
        return;
    };
    let o = diffkfc(&[
        "keyframes",
        "suggest",
        "--from",
        s(&src),
        "--count",
        "3",
        "--strategy",
        "uniform",
        "-o",
        s(&keys),
    ]);
    assert!(
        o.status.success() && stdout(&o).contains("[0, 85, 169]"),
        "{}{}",
        stdout(&o),
        stderr(&o)
    );
    for (flag, v, needle) in [
        ("--count", "0", "at least 1"),
        ("--rate", "2", "(0, 1]"),
        ("--count", "500", "has 170 frames"),
    ] {
        let o = diffkfc(&["keyframes", "suggest", "--from", s(&src), flag, v, "-o", s(&keys)]);
        assert_one_line_error(&o, &[flag, needle]);
    }
}

//! The BVH export read by Blender itself: Debian's `blender` in background mode imports the
//! file with its own BVH importer (scripts/blender_positions.py), and its joint positions are
//! compared with ours. Without Blender the test skips with a notice, unless
//! DIFFKFC_REQUIRE_BLENDER=1 (set by .ci/run, which installs it) makes that a failure.

mod common;
use std::path::Path;

use common::*;
use diffkfc_data::{io::npy, io::rig::T2M_NAMES, testing::fixtures};

fn joints(path: &Path) -> Vec<[f64; 3]> {
    npy::read_f64(path).unwrap().data.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// Mean and largest distance between Blender's joints and `ours` ((T*22) positions).
fn compare(b: &Frames, ours: &[[f64; 3]]) -> (f64, f64) {
    let mut d = Vec::new();
    for (f, bones) in b {
        let f: usize = f.parse().unwrap();
        for (j, name) in T2M_NAMES.iter().enumerate() {
            let p = bones[*name];
            let q = ours[f * 22 + j];
            d.push(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt());
        }
    }
    (d.iter().sum::<f64>() / d.len() as f64, d.iter().copied().fold(0.0, f64::max))
}

#[test]
fn blender_reads_our_bvh_as_we_do() {
    let Some(blender) = blender() else {
        return;
    };
    let d = scratch("blender");

    // A real HumanML3D clip (rigid bones): Blender's joints are the clip's own.
    if let Some(real) = fixtures::require("humanml3d/new_joints/012314.npy") {
        let bvh = d.join("real.bvh");
        let o = diffkfc(&["data", "bvh", s(&real), "-o", s(&bvh)]);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = std::fs::read_to_string(&bvh).unwrap();
        assert!(
            text.contains("ROOT Hips") && text.contains("JOINT LeftToe") && !text.contains("_to_"),
            "names"
        );
        let b = blender_positions(&blender, &bvh, &[0, 57, 113, 169], &d);
        let (mean, max) = compare(&b, &joints(&real));
        eprintln!("real clip 012314, Blender vs the clip's joints: mean {:.4} mm, max {:.4} mm (4 frames x 22 joints)", mean * 1e3, max * 1e3);
        assert!(max < 1e-3, "{max} m");
    }

    // A generated motion: Blender reads the file as our own reader does.
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth");
    if !have_text_encoder() {
        return;
    }
    // The default steps (which lift swinging feet and may lower the pelvis) and stride warping
    // (which lowers the pelvis between keys).
    for feet in ["steps", "warp"] {
        generated_bvh_reads_back(&blender, &model, &d, feet);
    }
}

/// A generated motion (feet post-process `feet`): Blender reads its BVH as our own reader does,
/// and as the sample's joints are.
fn generated_bvh_reads_back(blender: &Path, model: &Path, d: &Path, feet: &str) {
    let out = d.join(format!("sample-{feet}"));
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(model),
        "--text",
        "a person walks forward and waves the left hand.",
        "--length",
        "120",
        "--num-samples",
        "1",
        "--steps",
        "4",
        "--feet",
        feet,
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let bvh = out.join("sample_00.bvh");
    let back = d.join(format!("back-{feet}.npy"));
    let o = diffkfc(&["data", "joints", s(&bvh), "-o", s(&back)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let b = blender_positions(blender, &bvh, &[0, 30, 77, 119], d);
    let (mean, max) = compare(&b, &joints(&back));
    eprintln!(
        "generated sample (--feet {feet}), Blender vs our reading of its BVH: mean {:.4} mm, max {:.4} mm",
        mean * 1e3,
        max * 1e3
    );
    assert!(max < 1e-3, "{max} m");
    // The sample is made rigid before it is written, so the BVH is the motion itself.
    let (mean, max) = compare(&b, &joints(&out.join("sample_00_joints.npy")));
    eprintln!(
        "generated sample (--feet {feet}), Blender vs the sample's own joints: mean {:.4} mm, max {:.4} mm",
        mean * 1e3,
        max * 1e3
    );
    assert!(max < 1e-3, "Blender's joints are {max} m from sample_00_joints.npy");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    let reported = r["samples"][0]["bvh_error_m"]["max"].as_f64().unwrap();
    if feet == "warp" {
        let st = &r["samples"][0]["stride"];
        eprintln!(
            "stride warp: mean factor {}, pelvis drop {} m",
            st["mean_factor"], st["pelvis_drop_m"]
        );
    }
    assert!(
        max <= reported + 1e-3,
        "results.json says the BVH is within {reported} m of the joints; Blender finds {max} m"
    );
}

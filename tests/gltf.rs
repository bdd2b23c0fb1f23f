//! The glTF export checked by tools we did not write: `sample` writes `sample_00.glb` and
//! `data gltf` converts a real clip; the Khronos glTF-Validator (npm `gltf-validator`, run by
//! node; scripts/gltf_validate.js) finds no error and no warning in either, and Blender's own
//! glTF importer places the joints within 1 mm of `sample_00_joints.npy` on every frame.
//! Without node and the validator, or Blender, those parts skip with a notice, unless
//! DIFFKFC_REQUIRE_NODE=1 or DIFFKFC_REQUIRE_BLENDER=1 (set by .ci/run) make that a failure.

mod common;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;
use diffkfc_data::{io::npy, io::rig::T2M_NAMES, testing::fixtures};

/// The folder holding `node_modules/gltf-validator` ($DIFFKFC_NPM, else ~/.cache/diffkfc/npm).
fn validator() -> Option<PathBuf> {
    let dir = std::env::var_os("DIFFKFC_NPM").map(PathBuf::from).or_else(|| {
        std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/diffkfc/npm"))
    })?;
    let ok = dir.join("node_modules/gltf-validator").is_dir()
        && Command::new("node").arg("--version").output().is_ok_and(|o| o.status.success());
    if !ok {
        if std::env::var("DIFFKFC_REQUIRE_NODE").is_ok_and(|v| v == "1") {
            panic!("node and npm's gltf-validator are needed in {}", dir.display());
        }
        eprintln!(
            "SKIPPED: no node or gltf-validator in {}; the .glb is not validated",
            dir.display()
        );
        return None;
    }
    Some(dir)
}

fn validate(npm: &Path, glb: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/gltf_validate.js");
    let o = Command::new("node")
        .arg(&script)
        .arg(glb)
        .env("NODE_PATH", npm.join("node_modules"))
        .output()
        .expect("run node");
    assert!(o.status.success(), "validator: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn glb_passes_the_validator_and_blender_reads_our_joints() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("gltf");
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/tiny-synth");
    let out = d.join("s");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        model,
        "--text",
        "a person walks forward.",
        "--length",
        "60",
        "--seed",
        "3",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let glb = out.join("sample_00.glb");
    let mut files = vec![glb.clone()];
    if let Some(clip) = fixtures::require("humanml3d/new_joints/012314.npy") {
        let real = d.join("real.glb");
        let o = diffkfc(&["data", "gltf", s(&clip), "-o", s(&real)]);
        assert!(o.status.success(), "{}", stderr(&o));
        files.push(real);
    }
    if let Some(npm) = validator() {
        for f in &files {
            let r = validate(&npm, f);
            let first: Vec<_> = r["messages"].as_array().unwrap().iter().take(3).collect();
            eprintln!(
                "{}: glTF-Validator {}: {} errors, {} warnings, {} infos, {} hints {first:?}",
                f.display(),
                r["validator"],
                r["errors"],
                r["warnings"],
                r["infos"],
                r["hints"]
            );
            assert_eq!(
                (r["errors"].as_u64(), r["warnings"].as_u64()),
                (Some(0), Some(0)),
                "{first:?}"
            );
        }
    }
    let Some(blender) = blender() else { return };
    let ours: Vec<[f64; 3]> = npy::read_f64(out.join("sample_00_joints.npy"))
        .unwrap()
        .data
        .chunks(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let n = ours.len() / 22;
    let frames: Vec<usize> = (0..n).collect();
    let b = blender_positions(&blender, &glb, &frames, &d);
    let mut worst: f64 = 0.0;
    for (f, bones) in &b {
        let f: usize = f.parse().unwrap();
        for (j, name) in T2M_NAMES.iter().enumerate() {
            let (p, q) = (bones[*name], ours[f * 22 + j]);
            worst = worst.max(
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt(),
            );
        }
    }
    eprintln!(
        "Blender's glTF import: {} frames, joints within {:.4} mm of sample_00_joints.npy",
        b.len(),
        worst * 1e3
    );
    assert_eq!(b.len(), n);
    assert!(worst < 1e-3, "Blender's joints are {worst} m from ours");
}

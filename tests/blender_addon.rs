//! The Blender add-on in headless Blender (scripts/blender_addon_check.py) against a running
//! `diffkfc serve` with the reference model: installed from the zip `diffkfc blender-addon`
//! writes, on our rig (a real clip's BVH) with three keyed poses, one 2 m ahead facing 90
//! degrees, **Generate** writes a new action (the old one kept) whose keyed frames are the keys
//! and whose other frames are `diffkfc sample`'s motion for the same request and seed, within
//! 1 mm, through Blender's own evaluation of the armature; the same on the rig renamed to
//! Mixamo's bones. No armature and an unreachable server are one-line errors that change
//! nothing. The time of Generate is printed.

mod common;
use std::path::Path;
use std::process::{Command, Stdio};

use common::*;
use diffkfc_data::{io::npy, testing::fixtures};
use serde_json::Value;

fn run_blender(
    blender: &Path,
    zip: &Path,
    bvh: &Path,
    url: &str,
    out: &Path,
    mixamo: bool,
) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/blender_addon_check.py");
    let scripts_home = out.with_extension("scripts");
    let mut args =
        vec!["-b", "--factory-startup", "--python", s(&script), "--", s(zip), s(bvh), url, s(out)];
    if mixamo {
        args.push("--mixamo");
    }
    // The add-on installs into a scratch user folder, not the user's own.
    let o = Command::new(blender)
        .args(&args)
        .env("BLENDER_USER_SCRIPTS", &scripts_home)
        .output()
        .expect("run blender");
    assert!(o.status.success() && out.exists(), "blender failed: {}{}", stdout(&o), stderr(&o));
    serde_json::from_str(&std::fs::read_to_string(out).unwrap()).unwrap()
}

fn frames(v: &Value) -> Vec<Vec<[f64; 3]>> {
    v["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            f.as_array()
                .unwrap()
                .iter()
                .map(|p| [0, 1, 2].map(|k| p[k].as_f64().unwrap()))
                .collect()
        })
        .collect()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn the_addon_generates_from_the_armatures_keys() {
    let Some(blender) = blender() else { return };
    let Some(clip) = fixtures::require("humanml3d/new_joints/012314.npy") else { return };
    if !have_text_encoder() {
        return;
    }
    let d = scratch("blender-addon");
    let (zip, bvh) = (d.join("diffkfc_blender.zip"), d.join("rig.bvh"));
    assert!(diffkfc(&["blender-addon", "-o", s(&zip)]).status.success());
    assert!(diffkfc(&["data", "bvh", s(&clip), "-o", s(&bvh)]).status.success());
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/mid-synth");
    let mut server = Command::new(env!("CARGO_BIN_EXE_diffkfc"))
        .args(["serve", "--checkpoint", model, "--port", "0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let line = line_with(server.stdout.take().unwrap(), "diffkfc editor: http://");
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("http://"))
        .unwrap()
        .trim_end_matches('/')
        .to_string();
    let ours = run_blender(&blender, &zip, &bvh, &url, &d.join("ours.json"), false);
    let mixamo = run_blender(&blender, &zip, &bvh, &url, &d.join("mixamo.json"), true);
    let _ = server.kill();
    let _ = server.wait();

    for v in [&ours, &mixamo] {
        assert_eq!(v["result"], serde_json::json!(["FINISHED"]), "{v}");
        assert!(
            v["old_kept"].as_bool().unwrap()
                && v["new_action"].as_str().unwrap().starts_with("diffkfc")
        );
        for (case, want) in [("no_armature", "select an armature"), ("no_server", "not reachable")]
        {
            let e = &v["errors"][case];
            let msg = e["message"].as_str().unwrap();
            assert!(msg.contains(want) && !msg.contains('\n'), "{case}: {e}");
            assert!(e["action_kept"].as_bool().unwrap(), "{case} changed the action: {e}");
        }
    }
    eprintln!(
        "Generate of 120 frames with 3 keys (reference model, server running, Blender {}): {:.2} s, {:.2} s on the Mixamo-named rig",
        ours["blender"], ours["seconds"].as_f64().unwrap(), mixamo["seconds"].as_f64().unwrap()
    );
    // The keyed frames hold the keys.
    let got = frames(&ours);
    let keys = ours["request"]["keyframes"]["keyframes"].as_array().unwrap();
    assert_eq!(keys.len(), 3);
    let third = &keys[2];
    assert!((third["heading"].as_f64().unwrap() - 90.0).abs() < 0.5, "{third}");
    assert!(
        (third["root"][2].as_f64().unwrap() - keys[0]["root"][2].as_f64().unwrap() - 2.0).abs()
            < 1e-3
    );
    let mut key_err: f64 = 0.0;
    for k in keys {
        let f = k["frame"].as_u64().unwrap() as usize;
        for (j, p) in k["joints"].as_array().unwrap().iter().enumerate() {
            key_err = key_err.max(dist(got[f][j], [0, 1, 2].map(|c| p[c].as_f64().unwrap())));
        }
    }
    // The other frames are `sample`'s motion for the same request and seed.
    let keys_file = d.join("keys.json");
    std::fs::write(&keys_file, ours["request"]["keyframes"].to_string()).unwrap();
    let out = d.join("sample");
    let text = ours["request"]["text"].as_str().unwrap();
    let seed = ours["request"]["seed"].to_string();
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        model,
        "--text",
        text,
        "--keyframes",
        s(&keys_file),
        "--seed",
        &seed,
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let want = npy::read_f64(out.join("sample_00_joints.npy")).unwrap().data;
    let mut sample_err: f64 = 0.0;
    let mut mixamo_err: f64 = 0.0;
    let other = frames(&mixamo);
    for (f, frame) in got.iter().enumerate() {
        for (j, p) in frame.iter().enumerate() {
            let w = &want[(f * 22 + j) * 3..(f * 22 + j) * 3 + 3];
            sample_err = sample_err.max(dist(*p, [w[0], w[1], w[2]]));
            mixamo_err = mixamo_err.max(dist(*p, other[f][j]));
        }
    }
    eprintln!("largest distance: keys {key_err:.2e} m, sample {sample_err:.2e} m, Mixamo rig {mixamo_err:.2e} m");
    assert!(key_err < 1e-3 && sample_err < 1e-3 && mixamo_err < 1e-3);
}

//! The editor's API fields crossed pairwise (an all-pairs cover) against the reference model:
//! every combination of endpoint, keys (none, pose, place, pose and place), body parts, fit,
//! foot lock, feet and keyframe guidance answers 200 with finite numbers, never a 5xx or a panic.

mod common;
use common::*;
use diffkfc_data::testing::pairwise::all_pairs;
use serde_json::{json, Value};

const FACTORS: [(&str, &[&str]); 7] = [
    ("endpoint", &["sample", "export-bvh", "export-glb", "export-features", "export-joints"]),
    ("keys", &["none", "pose", "place", "pose+place"]),
    ("joints", &["all", "lower_body"]),
    ("fit", &["track", "warp", "paste", "none"]),
    ("foot_lock", &["true", "false"]),
    ("feet", &["steps", "warp", "pin", "network"]),
    ("kf_guidance", &["1", "2.5"]),
];

/// `suggested` keys (poses, places, headings) reduced to what `level` observes.
fn keys_of(suggested: &Value, level: &str, joints: &str) -> Value {
    let keep: &[&str] = match level {
        "none" => return json!({"length": 60, "keyframes": []}),
        "pose" => &["frame", "joints"],
        "place" => &["frame", "root", "heading"],
        _ => &["frame", "joints", "root", "heading"],
    };
    let keys: Vec<Value> = suggested["keyframes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| {
            let o = k.as_object().unwrap();
            Value::Object(
                o.iter()
                    .filter(|(n, _)| keep.contains(&n.as_str()))
                    .map(|(n, v)| (n.clone(), v.clone()))
                    .collect(),
            )
        })
        .collect();
    let mut spec = json!({"length": 60, "keyframes": keys});
    if joints != "all" {
        spec["joints"] = json!(joints);
    }
    spec
}

/// An exported file has 60 frames of finite numbers (a BVH's motion lines, an .npy's values).
fn export_is_finite(path: &str, body: &[u8]) -> bool {
    if path.ends_with("glb") {
        // A GLB of 60 frames: the header's magic and length, the animation's time accessor.
        let len = body.get(8..12).map(|b| u32::from_le_bytes(b.try_into().unwrap()) as usize);
        return body.starts_with(b"glTF") && len == Some(body.len()) && body.len() > 60 * 22 * 16;
    }
    if path.ends_with("bvh") {
        let text = String::from_utf8_lossy(body);
        let frames = text.lines().find_map(|l| l.strip_prefix("Frames:")).map(str::trim);
        return frames == Some("60") && !text.contains("NaN") && !text.contains("inf");
    }
    match diffkfc_data::io::npy::decode_f64(std::path::Path::new(path), body) {
        Ok((a, _)) => a.shape[0] == 60 && a.data.iter().all(|v| v.is_finite()),
        Err(_) => false,
    }
}

#[test]
fn api_fields_crossed_pairwise() {
    let Some(srv) = server(4) else { return };
    let s = post(
        srv.addr,
        "/api/suggest",
        &json!({"request": {"text": "a person walks forward.", "length": 60, "steps": 2}, "count": 3}),
    );
    assert_eq!(s.status, 200, "{}", String::from_utf8_lossy(&s.body));
    let suggested = s.json();
    assert!(
        suggested["keyframes"][0]["joints"].is_array()
            && suggested["keyframes"][0]["root"].is_array()
    );
    let levels: Vec<usize> = FACTORS.iter().map(|(_, l)| l.len()).collect();
    let rows = all_pairs(&levels, |_, _, _, _| true);
    eprintln!("{} combinations of {} fields", rows.len(), FACTORS.len());
    let mut failures = Vec::new();
    for row in &rows {
        let level = |name: &str| {
            let i = FACTORS.iter().position(|(n, _)| *n == name).unwrap();
            FACTORS[i].1[row[i]]
        };
        let req = json!({
            "text": "a person walks forward.",
            "keyframes": keys_of(&suggested, level("keys"), level("joints")),
            "steps": 2,
            "fit": level("fit"),
            "foot_lock": level("foot_lock") == "true",
            "feet": level("feet"),
            "kf_guidance": level("kf_guidance").parse::<f64>().unwrap(),
        });
        let path = match level("endpoint") {
            "sample" => "/api/sample".to_string(),
            e => format!("/api/export?format={}", e.trim_start_matches("export-")),
        };
        let r = post(srv.addr, &path, &req);
        let shown = format!("{path} {req}");
        if r.status != 200 {
            failures.push(format!("{}: {shown}: {}", r.status, String::from_utf8_lossy(&r.body)));
        } else if path == "/api/sample" {
            let m = r.json();
            let joints = m["joints"].as_array().unwrap();
            let finite = joints.iter().all(|v| v.as_f64().is_some_and(f64::is_finite));
            if joints.len() != 60 * 22 * 3 || !finite {
                failures.push(format!("not 60 finite frames: {shown}"));
            }
        } else if !export_is_finite(&path, &r.body) {
            failures.push(format!("empty or non-finite export: {shown}"));
        }
    }
    srv.stop().unwrap();
    assert!(
        failures.is_empty(),
        "{} of {} combinations failed:\n{}",
        failures.len(),
        rows.len(),
        failures.join("\n")
    );
}

//! End-to-end: `diffkfc sample` from a motion and from a keyframe JSON file; outputs,
//! exact keyframes, determinism and one-line errors.

mod common;
use common::*;
use diffkfc_data::npy;

#[test]
fn sample_outputs_errors_and_determinism() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("sample");
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "12", "--seed", "3"]).status.success());
    std::fs::write(d.join("cfg.json"), TWO_STEP_RUN).unwrap();
    let run = d.join("run");
    let o = diffkfc(&["train", "--config", s(&d.join("cfg.json")), "--data", s(&data), "--out", s(&run)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let src = data.join("new_joint_vecs/000000.npy");
    let out = d.join("out");
    let args = |out: &std::path::Path| -> Vec<String> {
        ["sample", "--checkpoint", s(&run), "--text", "a person walks forward.", "--from", s(&src), "--frames", "0,20,39", "--length", "40", "--steps", "5", "--num-samples", "2", "--out", s(out)]
            .iter()
            .map(|x| x.to_string())
            .collect()
    };
    let a: Vec<String> = args(&out);
    let o = diffkfc(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["results.json", "index.html", "sample_00.npy", "sample_00_joints.npy", "sample_00.gif", "sample_01.gif", "sample_00.bvh"] {
        assert!(out.join(f).exists(), "{f}");
    }
    let gen = npy::read_f32(out.join("sample_00.npy")).unwrap();
    assert_eq!(gen.shape, vec![40, 263]);
    let source = npy::read_f32(&src).unwrap();
    for f in [0usize, 20, 39] {
        for c in 0..263 {
            let (g, s) = (gen.data[f * 263 + c], source.data[f * 263 + c]);
            assert!((g - s).abs() <= 1e-5 * (1.0 + s.abs()), "frame {f} dim {c}: {g} vs {s}");
        }
    }
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(report["keyframes"], serde_json::json!([0, 20, 39]));
    assert!(report["samples"][0]["k_err_root_relative_m"].as_f64().unwrap() < 1e-4);
    assert!(report["samples"][0]["k_trans"].as_f64().unwrap().is_finite());
    // Same seed, same bytes.
    let out2 = d.join("out2");
    let a2 = args(&out2);
    assert!(diffkfc(&a2.iter().map(String::as_str).collect::<Vec<_>>()).status.success());
    assert_eq!(std::fs::read(out.join("sample_00.npy")).unwrap(), std::fs::read(out2.join("sample_00.npy")).unwrap());

    // The BVH reads back as keyframe source and as a picture.
    let bvh = out.join("sample_00.bvh");
    let out4 = d.join("out4");
    let o = diffkfc(&["sample", "--checkpoint", s(&run), "--text", "walk", "--from", s(&bvh), "--frames", "0,10", "--steps", "2", "--out", s(&out4)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(diffkfc(&["render", s(&bvh), "-o", s(&d.join("bvh.gif"))]).status.success());
    // A JSON keyframe file: one pose, one feature vector, the lower body only.
    let joints = npy::read_f32(data.join("new_joints/000000.npy")).unwrap();
    let pose: Vec<Vec<f32>> = (0..22).map(|j| joints.data[j * 3..j * 3 + 3].to_vec()).collect();
    let feats: Vec<f32> = source.data[10 * 263..11 * 263].to_vec();
    let kjson = d.join("keys.json");
    std::fs::write(&kjson, serde_json::json!({"length": 30, "joints": "lower_body", "keyframes": [{"frame": 0, "joints": pose}, {"frame": 10, "features": feats}]}).to_string()).unwrap();
    let out3 = d.join("out3");
    let o = diffkfc(&["sample", "--checkpoint", s(&run), "--text", "a person squats.", "--keyframes", s(&kjson), "--steps", "3", "--out", s(&out3)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out3.join("results.json")).unwrap()).unwrap();
    assert_eq!(r["length"], 30);
    assert_eq!(r["keyframe_joints"], serde_json::json!([0, 1, 2, 4, 5, 7, 8, 10, 11]));

    // A prompts file: one output folder per line, `#length` honoured.
    let prompts = d.join("prompts.txt");
    std::fs::write(&prompts, "a person jumps.#24\na person waves.\n").unwrap();
    let out5 = d.join("out5");
    let o = diffkfc(&["sample", "--checkpoint", s(&run), "--prompts", s(&prompts), "--length", "16", "--steps", "2", "--out", s(&out5)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(npy::read_f32(out5.join("prompt000/sample_00.npy")).unwrap().shape, vec![24, 263]);
    assert_eq!(npy::read_f32(out5.join("prompt001/sample_00.npy")).unwrap().shape, vec![16, 263]);
    std::fs::write(&prompts, "a person jumps.#soon\n").unwrap();
    assert_one_line_error(&diffkfc(&["sample", "--checkpoint", s(&run), "--prompts", s(&prompts)]), &["prompts.txt", "line 1", "soon"]);

    // Exact transition guidance, the inpainting baseline and no snapping all run.
    for extra in [vec!["--tg-mode", "exact"], vec!["--keyframe-mode", "inpaint"], vec!["--no-snap", "--tg-window", "3", "--tg-bases", "2"]] {
        let o6 = d.join("out6");
        let mut v = vec!["sample", "--checkpoint", s(&run), "--text", "walk", "--from", s(&src), "--frames", "0,20", "--length", "30", "--steps", "3", "--out", s(&o6)];
        v.extend(extra.iter().copied());
        let o = diffkfc(&v);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(o6.join("results.json")).unwrap()).unwrap();
        assert!(r["samples"][0]["k_err_m"].as_f64().unwrap().is_finite(), "{extra:?}");
    }
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("sample_00.gif") && html.contains("a person walks forward."));

    // Errors.
    let base = ["sample", "--checkpoint", s(&run), "--text", "walk", "--steps", "2", "--out", s(&out3)];
    let with = |extra: &[&str]| -> Vec<String> { base.iter().chain(extra).map(|x| x.to_string()).collect() };
    let run_err = |extra: &[&str], needles: &[&str]| {
        let v = with(extra);
        assert_one_line_error(&diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()), needles);
    };
    run_err(&["--from", s(&src), "--frames", "0,500"], &["--frames", "500", "beyond"]);
    run_err(&["--from", s(&src), "--frames", "0", "--joints", "tail"], &["--joints", "'tail'"]);
    run_err(&["--length", "300"], &["--length", "196"]);
    let bad = d.join("bad.json");
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 25, "features": []}]}"#).unwrap();
    run_err(&["--keyframes", s(&bad)], &["bad.json", "beyond the length"]);
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 2, "features": [1, 2]}]}"#).unwrap();
    run_err(&["--keyframes", s(&bad)], &["bad.json", "2 features, expected 263"]);
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 2, "joints": [[0, "x", 0]]}]}"#).unwrap();
    run_err(&["--keyframes", s(&bad)], &["bad.json", "keyframe 0"]);
    let v: Vec<String> = ["sample", "--checkpoint", s(&run), "--text", "  "].iter().map(|x| x.to_string()).collect();
    assert_one_line_error(&diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()), &["--text", "empty"]);
    let v: Vec<String> = ["sample", "--checkpoint", s(&d.join("norun")), "--text", "walk"].iter().map(|x| x.to_string()).collect();
    assert_one_line_error(&diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()), &["norun", "no checkpoint"]);
}

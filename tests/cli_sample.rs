//! End-to-end: `diffkfc sample` from a motion and from a keyframe JSON file; outputs,
//! exact keyframes, determinism and one-line errors.

mod common;
use common::*;
use diffkfc_data::io::npy;

#[test]
fn sample_outputs_errors_and_determinism() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("sample");
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "12", "--seed", "3"])
        .status
        .success());
    let run = two_step_run(&d, &data, "run", None);
    let src = data.join("new_joint_vecs/000000.npy");
    let out = d.join("out");
    let args = |out: &std::path::Path| -> Vec<String> {
        [
            "sample",
            "--checkpoint",
            s(&run),
            "--text",
            "a person walks forward.",
            "--from",
            s(&src),
            "--frames",
            "0,20,39",
            "--length",
            "40",
            "--steps",
            "5",
            "--num-samples",
            "2",
            "--out",
            s(out),
        ]
        .iter()
        .map(|x| x.to_string())
        .collect()
    };
    let a: Vec<String> = args(&out);
    let o = diffkfc(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "results.json",
        "index.html",
        "sample_00.npy",
        "sample_00_joints.npy",
        "sample_00.gif",
        "sample_01.gif",
        "sample_00.bvh",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    let gen = npy::read_f32(out.join("sample_00.npy")).unwrap();
    assert_eq!(gen.shape, vec![40, 263]);
    let source = npy::read_f32(&src).unwrap();
    // The default fit (warp) meets every observed pose feature; the root's velocity channels are
    // rewritten to reach the keyed places, and foot contacts are left as generated.
    for f in [0usize, 20, 39] {
        for c in 3..259 {
            let (g, s) = (gen.data[f * 263 + c], source.data[f * 263 + c]);
            assert!((g - s).abs() <= 1e-4 * (1.0 + s.abs()), "frame {f} dim {c}: {g} vs {s}");
        }
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(report["keyframes"], serde_json::json!([0, 20, 39]));
    assert_eq!(report["keyframe_fit"], "track");
    // The track fit: the first stage's root path beside the sample, the second stage's distance
    // from it; one rigid motion, which the BVH reproduces; every planted span with its drift.
    let s0 = &report["samples"][0];
    let path = npy::read_f32(out.join("sample_00_root_path.npy")).unwrap();
    assert_eq!(
        (path.shape.clone(), s0["root_path"].as_str()),
        (vec![40, 3], Some("sample_00_root_path.npy"))
    );
    assert!(s0["track"]["raw_distance_m"].as_f64().unwrap().is_finite(), "{s0}");
    assert!(s0["bone_length_std_m"].as_f64().unwrap() < 1e-3, "{s0}");
    // Keyed rows stay as given, so the BVH departs from the motion only where a key pose is
    // itself not rigid (the synthetic body's spine base moves against its hips by up to ~1 mm),
    // and by no more than that.
    let key_move = s0["rigid"]["max_key_move_m"].as_f64().unwrap();
    assert!(key_move < 2e-3, "the key poses are rigid to ~1 mm: {s0}");
    assert!(s0["bvh_error_m"]["max"].as_f64().unwrap() <= key_move + 1e-5, "{s0}");
    assert!(s0["bvh_error_m"]["mean"].as_f64().unwrap() < 2e-4, "{s0}");
    assert!(s0["foot_lock"]["spans"].is_array(), "{s0}");
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(page.contains("\"root_path\":[") && page.contains("\"planted\":"));
    assert!(report["samples"][0]["k_err_root_relative_m"].as_f64().unwrap() < 1e-4);
    // Keyed places too: the global joint error at the keys is under a millimetre.
    assert!(report["samples"][0]["k_err_m"].as_f64().unwrap() < 1e-3, "{}", report["samples"][0]);
    assert_eq!(report["samples"][0]["corrections"].as_array().unwrap().len(), 3);
    // Foot locking is on by default and says what it moved; --no-foot-lock turns it off.
    assert_eq!(report["foot_lock"], true);
    assert!(
        report["samples"][0]["foot_lock"]["frames"].is_u64()
            && report["samples"][0]["foot_lock"]["dragged"].is_u64()
            && report["samples"][0]["foot_lock"]["out_of_reach"].is_u64(),
        "{}",
        report["samples"][0]
    );
    // The paste writes every observed feature into the key frames.
    let outp = d.join("outp");
    let mut ap = args(&outp);
    ap.extend(["--keyframe-fit".to_string(), "paste".to_string(), "--no-foot-lock".to_string()]);
    assert!(diffkfc(&ap.iter().map(String::as_str).collect::<Vec<_>>()).status.success());
    let rp: serde_json::Value =
        serde_json::from_slice(&std::fs::read(outp.join("results.json")).unwrap()).unwrap();
    assert_eq!(
        (rp["foot_lock"].as_bool(), rp["samples"][0]["foot_lock"].is_null()),
        (Some(false), true)
    );
    let pasted = npy::read_f32(outp.join("sample_00.npy")).unwrap();
    for f in [0usize, 20, 39] {
        for c in 0..263 {
            let (g, s) = (pasted.data[f * 263 + c], source.data[f * 263 + c]);
            assert!((g - s).abs() <= 1e-5 * (1.0 + s.abs()), "paste frame {f} dim {c}: {g} vs {s}");
        }
    }
    assert!(report["samples"][0]["k_trans"].as_f64().unwrap().is_finite());
    // Same seed, same bytes.
    let out2 = d.join("out2");
    let a2 = args(&out2);
    assert!(diffkfc(&a2.iter().map(String::as_str).collect::<Vec<_>>()).status.success());
    assert_eq!(
        std::fs::read(out.join("sample_00.npy")).unwrap(),
        std::fs::read(out2.join("sample_00.npy")).unwrap()
    );
    // An exported model directory samples like its run: the same bytes in f32, within f16
    // rounding in f16, and its weights file holds no optimiser state.
    for (dtype, tol) in [("f32", 0.0f32), ("f16", 0.05)] {
        let model = d.join(format!("model-{dtype}"));
        let o = diffkfc(&[
            "model",
            "export",
            "--checkpoint",
            s(&run),
            "--out",
            s(&model),
            "--dtype",
            dtype,
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        for f in
            ["model.safetensors", "config.json", "Mean.npy", "Std.npy", "metrics.jsonl", "loss.svg"]
        {
            assert!(model.join(f).is_file(), "{dtype}: {f} missing");
        }
        let mut am = args(&d.join(format!("out-{dtype}")));
        let at = am.iter().position(|x| x == "--checkpoint").unwrap() + 1;
        am[at] = s(&model).to_string();
        let o = diffkfc(&am.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{}", stderr(&o));
        let m = npy::read_f32(d.join(format!("out-{dtype}/sample_00.npy"))).unwrap();
        let worst = m.data.iter().zip(&gen.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst <= tol, "{dtype}: largest difference {worst}");
    }
    let ckpt_bytes = std::fs::metadata(
        std::fs::read_dir(&run)
            .unwrap()
            .flatten()
            .find(|e| e.file_name().to_string_lossy().starts_with("ckpt-"))
            .unwrap()
            .path(),
    )
    .unwrap()
    .len();
    let f16_bytes = std::fs::metadata(d.join("model-f16/model.safetensors")).unwrap().len();
    assert!(f16_bytes * 6 < ckpt_bytes, "f16 weights {f16_bytes} bytes vs checkpoint {ckpt_bytes}");
    assert_one_line_error(
        &diffkfc(&[
            "model",
            "export",
            "--checkpoint",
            s(&d.join("nothing")),
            "--out",
            s(&d.join("m")),
        ]),
        &["nothing"],
    );
    // Exporting into the run itself (spelled differently) would mix the two: refused.
    let run_slash = format!("{}/", s(&run));
    assert_one_line_error(
        &diffkfc(&["model", "export", "--checkpoint", s(&run), "--out", &run_slash]),
        &["run directory itself"],
    );
    // Reusing the folder with fewer samples leaves no stale sample_01 files of the first run.
    let mut one = args(&out2);
    let at = one.iter().position(|x| x == "--num-samples").unwrap() + 1;
    one[at] = "1".into();
    assert!(diffkfc(&one.iter().map(String::as_str).collect::<Vec<_>>()).status.success());
    assert!(
        out2.join("sample_00.gif").exists()
            && !out2.join("sample_01.gif").exists()
            && !out2.join("sample_01.npy").exists()
    );
    // The set is replaced whole; a user's own file in our folder is kept, and nothing partial
    // is left beside it.
    std::fs::write(out2.join("notes.txt"), "mine").unwrap();
    let o = diffkfc(&one.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success() && stdout(&o).contains("kept notes.txt"), "{}", stdout(&o));
    assert_eq!(std::fs::read_to_string(out2.join("notes.txt")).unwrap(), "mine");
    let siblings: Vec<String> = std::fs::read_dir(&d)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".partial") || n.contains(".old"))
        .collect();
    assert!(siblings.is_empty(), "{siblings:?}");
    // A folder diffkfc did not write: refused (its sample_05.npy is the user's), or with --force
    // only our names are written and nothing is removed.
    let theirs = d.join("theirs");
    std::fs::create_dir_all(&theirs).unwrap();
    std::fs::write(theirs.join("sample_05.npy"), "mine").unwrap();
    let mut v = args(&theirs);
    assert_one_line_error(
        &diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--out", "theirs", "did not write", "sample_05.npy", "--force"],
    );
    v.push("--force".into());
    assert!(diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()).status.success());
    assert_eq!(std::fs::read_to_string(theirs.join("sample_05.npy")).unwrap(), "mine");
    assert!(theirs.join("sample_01.npy").exists() && theirs.join("results.json").exists());
    // A checkpoint built for shorter motions is not asked for longer ones.
    let short = two_step_run(&d, &data, "short-run", Some(30));
    let mut v = args(&d.join("short-out"));
    v[2] = s(&short).to_string();
    assert_one_line_error(
        &diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--length: 40 frames", "at most 30 (model.max_frames)"],
    );

    // A foot-lock reach outside 0..2 m: one line naming the flag and the value.
    for bad in ["-1", "3", "NaN"] {
        let mut v = args(&d.join("reach"));
        v.push(format!("--foot-lock-reach={bad}"));
        assert_one_line_error(
            &diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()),
            &["--foot-lock-reach", bad],
        );
    }

    // The BVH reads back as keyframe source and as a picture.
    let bvh = out.join("sample_00.bvh");
    let out4 = d.join("out4");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&run),
        "--text",
        "walk",
        "--from",
        s(&bvh),
        "--frames",
        "0,10",
        "--steps",
        "2",
        "--out",
        s(&out4),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(diffkfc(&["render", s(&bvh), "-o", s(&d.join("bvh.gif"))]).status.success());
    // A JSON keyframe file: one pose, one feature vector, the lower body only.
    let joints = npy::read_f32(data.join("new_joints/000000.npy")).unwrap();
    let pose: Vec<Vec<f32>> = (0..22).map(|j| joints.data[j * 3..j * 3 + 3].to_vec()).collect();
    let feats: Vec<f32> = source.data[10 * 263..11 * 263].to_vec();
    let kjson = d.join("keys.json");
    std::fs::write(&kjson, serde_json::json!({"length": 30, "joints": "lower_body", "keyframes": [{"frame": 0, "joints": pose}, {"frame": 10, "features": feats}]}).to_string()).unwrap();
    let out3 = d.join("out3");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&run),
        "--text",
        "a person squats.",
        "--keyframes",
        s(&kjson),
        "--steps",
        "3",
        "--out",
        s(&out3),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out3.join("results.json")).unwrap()).unwrap();
    assert_eq!(r["length"], 30);
    assert_eq!(r["keyframe_joints"], serde_json::json!([0, 1, 2, 4, 5, 7, 8, 10, 11]));
    // Keyed places and headings: the pelvis stands where it was put, facing where it was turned.
    let placed = serde_json::json!({"length": 40, "keyframes": [
        {"frame": 15, "joints": pose, "root": [1.0, 0.95, 2.0], "heading": 90},
        {"frame": 35, "root": [-0.5, 0.9, 3.5]}]});
    std::fs::write(&kjson, placed.to_string()).unwrap();
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&run),
        "--text",
        "a person walks.",
        "--keyframes",
        s(&kjson),
        "--steps",
        "3",
        "--out",
        s(&out3),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = npy::read_f32(out3.join("sample_00_joints.npy")).unwrap();
    for (f, x, y, z) in [(15usize, 1.0f32, 0.95f32, 2.0f32), (35, -0.5, 0.9, 3.5)] {
        let p = &j.data[f * 66..f * 66 + 3];
        assert!(
            (p[0] - x).abs() < 1e-3 && (p[1] - y).abs() < 1e-3 && (p[2] - z).abs() < 1e-3,
            "frame {f}: {p:?}"
        );
    }
    // Heading 90 faces +X: forward = up x (r_hip - l_hip), as HumanML3D finds the facing.
    let (l, r) = (&j.data[15 * 66 + 3..15 * 66 + 6], &j.data[15 * 66 + 6..15 * 66 + 9]);
    let across = [r[0] - l[0], r[2] - l[2]];
    let facing = [across[1], -across[0]];
    let ang = facing[0].atan2(facing[1]).to_degrees();
    assert!((ang - 90.0).abs() < 20.0, "facing {ang} degrees");
    for (bad_key, needle) in [
        (serde_json::json!({"frame": 3, "root": [1, 2]}), "root: invalid length 2"),
        (
            serde_json::json!({"frame": 3, "root": [1, "up", 2]}),
            "root[1]: invalid type: string \"up\"",
        ),
        (
            serde_json::json!({"frame": 3, "heading": "north"}),
            "heading: invalid type: string \"north\"",
        ),
        (
            serde_json::json!({"frame": 3, "heading": 1e300}),
            "heading 1e300: must be finite degrees",
        ),
    ] {
        std::fs::write(
            &kjson,
            serde_json::json!({"length": 20, "keyframes": [bad_key]}).to_string(),
        )
        .unwrap();
        let o = diffkfc(&[
            "sample",
            "--checkpoint",
            s(&run),
            "--text",
            "walk",
            "--keyframes",
            s(&kjson),
            "--steps",
            "2",
            "--out",
            s(&out3),
        ]);
        assert_one_line_error(&o, &["keys.json", "keyframes[0]", needle]);
    }

    // A prompts file: one output folder per line, `#length` honoured.
    let prompts = d.join("prompts.txt");
    std::fs::write(&prompts, "a person jumps.#24\na person waves.\n").unwrap();
    let out5 = d.join("out5");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&run),
        "--prompts",
        s(&prompts),
        "--length",
        "16",
        "--steps",
        "2",
        "--out",
        s(&out5),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(npy::read_f32(out5.join("prompt000/sample_00.npy")).unwrap().shape, vec![24, 263]);
    assert_eq!(npy::read_f32(out5.join("prompt001/sample_00.npy")).unwrap().shape, vec![16, 263]);
    std::fs::write(&prompts, "a person jumps.#soon\n").unwrap();
    assert_one_line_error(
        &diffkfc(&["sample", "--checkpoint", s(&run), "--prompts", s(&prompts)]),
        &["prompts.txt", "line 1", "soon"],
    );

    // Exact transition guidance, the inpainting baseline and no snapping all run.
    for extra in [
        vec!["--tg-mode", "exact"],
        vec!["--keyframe-mode", "inpaint"],
        vec!["--no-snap", "--tg-window", "3", "--tg-bases", "2"],
    ] {
        let o6 = d.join("out6");
        let mut v = vec![
            "sample",
            "--checkpoint",
            s(&run),
            "--text",
            "walk",
            "--from",
            s(&src),
            "--frames",
            "0,20",
            "--length",
            "30",
            "--steps",
            "3",
            "--out",
            s(&o6),
        ];
        v.extend(extra.iter().copied());
        let o = diffkfc(&v);
        assert!(o.status.success(), "{extra:?}: {}", stderr(&o));
        let r: serde_json::Value =
            serde_json::from_slice(&std::fs::read(o6.join("results.json")).unwrap()).unwrap();
        assert!(r["samples"][0]["k_err_m"].as_f64().unwrap().is_finite(), "{extra:?}");
    }
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("sample_00.gif") && html.contains("a person walks forward."));

    // Errors.
    let base =
        ["sample", "--checkpoint", s(&run), "--text", "walk", "--steps", "2", "--out", s(&out3)];
    let with = |extra: &[&str]| -> Vec<String> {
        base.iter().chain(extra).map(|x| x.to_string()).collect()
    };
    let run_err = |extra: &[&str], needles: &[&str]| {
        let v = with(extra);
        assert_one_line_error(&diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()), needles);
    };
    run_err(&["--from", s(&src), "--frames", "0,500"], &["--frames", "500", "beyond"]);
    run_err(&["--from", s(&src), "--frames", "0", "--joints", "tail"], &["--joints", "'tail'"]);
    run_err(&["--length", "300"], &["--length", "196"]);
    // Sizes are checked before anything is allocated (these used to abort or exhaust memory).
    run_err(&["--length", "10000000000"], &["--length", "10000000000", "196"]);
    run_err(&["--seconds", "1e9"], &["--seconds", "1000000000"]);
    run_err(&["--seconds", "0"], &["--seconds", "0"]);
    for (bad_len, needle) in [
        ("1e9", "length: invalid type: floating point `1000000000.0`"),
        ("-5", "length: invalid value: integer `-5`"),
        ("\"60\"", "length: invalid type: string \"60\""),
    ] {
        std::fs::write(d.join("bad.json"), format!(r#"{{"length": {bad_len}, "keyframes": []}}"#))
            .unwrap();
        run_err(&["--keyframes", s(&d.join("bad.json"))], &["bad.json", needle]);
    }
    for (bad_frame, needle) in [
        ("-1", "frame: invalid value: integer `-1`"),
        ("1.5", "frame: invalid type: floating point `1.5`"),
        ("\"3\"", "frame: invalid type: string \"3\""),
    ] {
        std::fs::write(
            d.join("bad.json"),
            format!(
                r#"{{"length": 20, "keyframes": [{{"frame": {bad_frame}, "root": [0, 1, 0]}}]}}"#
            ),
        )
        .unwrap();
        run_err(&["--keyframes", s(&d.join("bad.json"))], &["bad.json", "keyframes[0]", needle]);
    }
    // --checkpoint takes one checkpoint file as well as a run directory.
    let ckpt = std::fs::read_dir(&run)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|x| x == "safetensors"))
        .unwrap();
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&ckpt),
        "--text",
        "walk",
        "--length",
        "12",
        "--steps",
        "2",
        "--out",
        s(&d.join("outc")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // A run whose normalisation does not fit its model: one line naming the file.
    let broken = d.join("broken");
    std::fs::create_dir_all(&broken).unwrap();
    for e in std::fs::read_dir(&run).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, broken.join(p.file_name().unwrap())).unwrap();
    }
    npy::write(broken.join("Mean.npy"), &[10], &[0f32; 10]).unwrap();
    assert_one_line_error(
        &diffkfc(&[
            "sample",
            "--checkpoint",
            s(&broken),
            "--text",
            "walk",
            "--steps",
            "2",
            "--out",
            s(&out3),
        ]),
        &["Mean.npy", "10 values", "263"],
    );
    npy::write(broken.join("Mean.npy"), &[263], &[0f32; 263]).unwrap();
    npy::write(broken.join("Std.npy"), &[263], &[0f32; 263]).unwrap();
    assert_one_line_error(
        &diffkfc(&[
            "sample",
            "--checkpoint",
            s(&broken),
            "--text",
            "walk",
            "--steps",
            "2",
            "--out",
            s(&out3),
        ]),
        &["Std.npy", "entry 0", "> 0"],
    );
    // Flag ranges, and a sampler driven past any useful guidance fails instead of writing NaN.
    run_err(&["--kf-guidance", "-1"], &["--kf-guidance", "-1"]);
    run_err(&["--kf-guidance", "inf"], &["--kf-guidance", "inf"]);
    run_err(&["--kf-guidance", "nan"], &["--kf-guidance", "NaN"]);
    run_err(&["--text-guidance", "-1"], &["--text-guidance", "-1"]);
    // This run was trained without text drop: it has no text-free branch to guide against.
    run_err(&["--text-guidance", "2.5"], &["--text-guidance: 2.5", "text_drop_prob"]);
    run_err(&["--transition-guidance", "1e30"], &["--transition-guidance"]);
    run_err(&["--place-guidance", "1e30"], &["--place-guidance"]);
    run_err(&["--place-guidance", "-2"], &["--place-guidance", "-2"]);
    for steps in ["0", "100000"] {
        assert_one_line_error(
            &diffkfc(&[
                "sample",
                "--checkpoint",
                s(&run),
                "--text",
                "walk",
                "--steps",
                steps,
                "--out",
                s(&out3),
            ]),
            &["--steps", steps],
        );
    }
    // Body parts must be named; an empty frame list is an error, not zero keyframes.
    for bad_joints in ["\"\"", "5"] {
        std::fs::write(d.join("bad.json"), format!(r#"{{"length": 20, "joints": {bad_joints}, "keyframes": [{{"frame": 2, "root": [0, 1, 0]}}]}}"#)).unwrap();
        run_err(&["--keyframes", s(&d.join("bad.json"))], &["bad.json", "joints: "]);
    }
    run_err(&["--from", s(&src), "--frames", ""], &["--frames", "empty"]);
    // Prompt files: real line numbers (blank and comment lines counted), lengths checked.
    std::fs::write(&prompts, "a person jumps.\n\n// comment\nwalk#99999999999\n").unwrap();
    let out7 = d.join("out7");
    assert_one_line_error(
        &diffkfc(&["sample", "--checkpoint", s(&run), "--prompts", s(&prompts), "--out", s(&out7)]),
        &["prompts.txt", "line 4", "99999999999"],
    );
    assert!(!out7.exists(), "a bad line must stop the file before any prompt is sampled");
    let bad = d.join("bad.json");
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 25, "features": []}]}"#)
        .unwrap();
    run_err(&["--keyframes", s(&bad)], &["bad.json", "beyond the length"]);
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 2, "features": [1, 2]}]}"#)
        .unwrap();
    run_err(&["--keyframes", s(&bad)], &["bad.json", "2 features, expected 263"]);
    std::fs::write(&bad, r#"{"length": 20, "keyframes": [{"frame": 2, "joints": [[0, "x", 0]]}]}"#)
        .unwrap();
    run_err(
        &["--keyframes", s(&bad)],
        &["bad.json", "keyframes[0].joints[0][1]: invalid type: string \"x\""],
    );
    let v: Vec<String> =
        ["sample", "--checkpoint", s(&run), "--text", "  "].iter().map(|x| x.to_string()).collect();
    assert_one_line_error(
        &diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()),
        &["--text", "empty"],
    );
    let v: Vec<String> = ["sample", "--checkpoint", s(&d.join("norun")), "--text", "walk"]
        .iter()
        .map(|x| x.to_string())
        .collect();
    assert_one_line_error(
        &diffkfc(&v.iter().map(String::as_str).collect::<Vec<_>>()),
        &["norun", "no checkpoint"],
    );
}

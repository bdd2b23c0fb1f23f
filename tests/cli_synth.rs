//! End-to-end: `diffkfc data synth` output passes `data check`, and `render` draws it.

mod common;
use common::*;

#[test]
fn synth_check_and_render() {
    let d = scratch("synth");
    let out = d.join("synth");
    let o = diffkfc(&["data", "synth", "--out", s(&out), "--clips", "30", "--seed", "4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // HumanML3D's body unless asked otherwise.
    assert!(
        stdout(&o).contains("30 clips") && stdout(&o).contains("humanml3d body"),
        "{}",
        stdout(&o)
    );
    let o = diffkfc(&["data", "check", s(&out)]);
    assert!(o.status.success(), "{}", stdout(&o));
    // Refuses to overwrite.
    assert_one_line_error(
        &diffkfc(&["data", "synth", "--out", s(&out), "--clips", "3"]),
        &["already exists"],
    );
    // The body is chosen by name, recorded in the manifest; an unknown one is refused.
    let o =
        diffkfc(&["data", "synth", "--out", s(&d.join("b")), "--clips", "3", "--body", "legacy"]);
    assert!(o.status.success() && stdout(&o).contains("legacy body"), "{}", stderr(&o));
    assert_one_line_error(
        &diffkfc(&["data", "synth", "--out", s(&d.join("c")), "--body", "smpl"]),
        &["--body", "'smpl'", "legacy, humanml3d"],
    );
    // --vary is recorded in the manifest; out of its range it is refused and nothing written.
    let o = diffkfc(&["data", "synth", "--out", s(&d.join("v")), "--clips", "3", "--vary", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("v/manifest.json")).unwrap()).unwrap();
    assert_eq!(m["vary"].as_f64(), Some(1.0));
    assert_one_line_error(
        &diffkfc(&["data", "synth", "--out", s(&d.join("w")), "--vary", "3"]),
        &["--vary", "3", "0 to 2"],
    );
    assert!(!d.join("w").exists());

    // GIF: one frame per motion frame; keyframe frames use the highlight colour.
    let clip = out.join("new_joint_vecs/000000.npy");
    let frames = diffkfc_data::io::npy::read_f32(&clip).unwrap().shape[0];
    let gif_path = d.join("m.gif");
    let o = diffkfc(&["render", s(&clip), "-o", s(&gif_path), "--keyframes", "0,10"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::Indexed);
    let mut dec = opts.read_info(std::fs::File::open(&gif_path).unwrap()).unwrap();
    let mut n = 0;
    let mut orange = Vec::new();
    while let Some(f) = dec.read_next_frame().unwrap() {
        // Palette index 7 is the keyframe highlight.
        orange.push(f.buffer.iter().filter(|&&p| p == 7).count());
        n += 1;
    }
    assert_eq!(n, frames);
    assert!(orange[0] > 50 && orange[10] > 50, "keyframes not highlighted");
    assert!(orange[5] < orange[0], "a non-keyframe drawn as a keyframe");

    // Contact sheet of three clips in two columns: 2x2 cells of 240 px.
    let sheet = d.join("sheet.png");
    let clips: Vec<String> =
        (0..3).map(|i| s(&out.join(format!("new_joints/{i:06}.npy"))).to_string()).collect();
    let mut args = vec!["render", "--sheet", "--columns", "2", "-o", s(&sheet)];
    args.extend(clips.iter().map(String::as_str));
    args.extend(["--label", "walk", "--label", "jump", "--label", "wave"]);
    let o = diffkfc(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    // The sheet's cells are numbered; stdout says which is which.
    assert!(stdout(&o).contains("cell 0: walk\n  cell 1: jump\n  cell 2: wave"), "{}", stdout(&o));
    let info = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&sheet).unwrap()))
        .read_info()
        .unwrap()
        .info()
        .clone();
    assert_eq!((info.width, info.height), (480, 480));

    assert_one_line_error(
        &diffkfc(&["render", s(&clip), "-o", s(&gif_path), "--keyframes", "9999"]),
        &["--keyframes", "9999"],
    );

    // The loader benchmark builds the cache once, then reuses it.
    for built in [true, false] {
        let o = diffkfc(&["data", "bench-loader", s(&out), "--batches", "3", "--batch-size", "4"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["cache_built"], built);
        assert!(v["items_per_s"].as_f64().unwrap() > 0.0);
    }
    assert!(out.join(".diffkfc-cache/train.f32").exists());
}

//! End-to-end tests of `diffkfc data features|joints`, `--version` and `--help`.

mod common;
use common::*;
use diffkfc_data::{io::npy, testing::fixtures};
use std::path::Path;

fn max_abs(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn features_of_raw_mocap_reproduce_reference() {
    let (Some(raw), Some(reference)) = (
        fixtures::require("humanml3d/000021.npy"),
        fixtures::require("humanml3d/000021_features_reference.npy"),
    ) else {
        return;
    };
    let d = scratch("features");
    let out = d.join("f.npy");
    let o = diffkfc(&["data", "features", s(&raw), "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("(179, 263)"), "{}", stdout(&o));
    let got = npy::read_f32(&out).unwrap();
    let want = npy::read_f32(&reference).unwrap();
    assert_eq!(got.shape, vec![179, 263]);
    let e = max_abs(&got.data, &want.data);
    eprintln!("data features 000021.npy vs reference: max abs error {e:.2e}");
    assert!(e < 1e-4, "{e}");

    // And back to joints, against HumanML3D's own recover_from_ric of the reference.
    let joints = d.join("j.npy");
    let o = diffkfc(&["data", "joints", s(&out), "-o", s(&joints)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let refj =
        npy::read_f32(fixtures::require("humanml3d/000021_joints_reference.npy").unwrap()).unwrap();
    let got = npy::read_f32(&joints).unwrap();
    assert_eq!(got.shape, vec![179, 22, 3]);
    assert!(max_abs(&got.data, &refj.data) < 1e-4);
}

#[test]
fn joints_of_released_features_match_released_joints() {
    let (Some(feats), Some(joints)) = (
        fixtures::require("humanml3d/new_joint_vecs/012314.npy"),
        fixtures::require("humanml3d/new_joints/012314.npy"),
    ) else {
        return;
    };
    let d = scratch("joints");
    let out = d.join("j.npy");
    let o = diffkfc(&["data", "joints", s(&feats), "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = max_abs(&npy::read_f32(&out).unwrap().data, &npy::read_f32(&joints).unwrap().data);
    assert!(e < 1e-5, "{e}");
}

/// 000021 rewritten Z-up and at 40 fps (midpoints inserted) must give the same features with
/// `--up z --fps 40`.
#[test]
fn z_up_and_frame_rate_options() {
    let (Some(raw), Some(reference)) = (
        fixtures::require("humanml3d/000021.npy"),
        fixtures::require("humanml3d/000021_features_reference.npy"),
    ) else {
        return;
    };
    let a = npy::read_f64(&raw).unwrap();
    let (t, j) = (a.shape[0], a.shape[1]);
    let frame = |f: usize| &a.data[f * j * 3..(f + 1) * j * 3];
    let mut data = Vec::new();
    for f in 0..t {
        let cur = frame(f);
        let pts: Vec<Vec<f64>> = if f + 1 < t {
            let mid: Vec<f64> = cur.iter().zip(frame(f + 1)).map(|(x, y)| 0.5 * (x + y)).collect();
            vec![cur.to_vec(), mid]
        } else {
            vec![cur.to_vec()]
        };
        for p in pts {
            for k in p.chunks(3) {
                // Y-up (x, y, z) -> Z-up (-x, z, y), the inverse of HumanML3D's turn.
                data.extend_from_slice(&[-k[0], k[2], k[1]]);
            }
        }
    }
    let d = scratch("zup");
    let input = d.join("zup40.npy");
    npy::write(&input, &[2 * t - 1, j, 3], &data).unwrap();
    let out = d.join("f.npy");
    let o = diffkfc(&["data", "features", s(&input), "--up", "z", "--fps", "40", "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = max_abs(&npy::read_f32(&out).unwrap().data, &npy::read_f32(&reference).unwrap().data);
    eprintln!("--up z --fps 40 vs reference: max abs error {e:.2e}");
    assert!(e < 1e-4, "{e}");
}

/// `bytes` with the first occurrence of `from` overwritten by `to` (same length).
fn patch(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let at = b.windows(from.len()).position(|w| w == from.as_bytes()).unwrap();
    b[at..at + to.len()].copy_from_slice(to.as_bytes());
    b
}

/// A valid .npy header claiming (2^61, 22, 3) float32 elements, followed by 64 bytes.
fn huge_header() -> Vec<u8> {
    let mut dict =
        "{'descr': '<f4', 'fortran_order': False, 'shape': (2305843009213693952, 22, 3), }"
            .to_string();
    while !(10 + dict.len() + 1).is_multiple_of(64) {
        dict.push(' ');
    }
    dict.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((dict.len() as u16).to_le_bytes());
    b.extend(dict.bytes());
    b.extend([0u8; 64]);
    b
}

#[test]
fn bad_inputs_give_one_line_errors() {
    let d = scratch("bad");
    let good = npy::encode(&[3, 22, 3], &[0.5f32; 198]);
    let cases: Vec<(&str, Vec<u8>, &str, Vec<&str>)> = vec![
        (
            "truncated.npy",
            good[..good.len() - 7].to_vec(),
            "features",
            vec!["truncated.npy", "truncated data"],
        ),
        (
            "garbage.npy",
            b"not an array".to_vec(),
            "features",
            vec!["garbage.npy", "not a .npy file"],
        ),
        (
            "ints.npy",
            patch(&good, "<f4", "<i4"),
            "features",
            vec!["ints.npy", "'<i4' is not supported"],
        ),
        (
            "width.npy",
            npy::encode(&[10, 200], &[0f32; 2000]),
            "joints",
            vec!["width.npy", "(T, 263)", "[10, 200]"],
        ),
        (
            "shape.npy",
            npy::encode(&[10, 20, 3], &[0f32; 600]),
            "features",
            vec!["shape.npy", "(T, 22, 3)", "[10, 20, 3]"],
        ),
        (
            "one_frame.npy",
            npy::encode(&[1, 22, 3], &[0.1f32; 66]),
            "features",
            vec!["one_frame.npy", "at least 2"],
        ),
        (
            "empty.npy",
            npy::encode(&[0, 263], &[0f32; 0]),
            "joints",
            vec!["empty.npy", "at least 2"],
        ),
        (
            "one_row.npy",
            npy::encode(&[1, 263], &[0f32; 263]),
            "joints",
            vec!["one_row.npy", "at least 2"],
        ),
        // A header whose shape product overflows (it used to wrap and index out of range).
        ("huge.npy", huge_header(), "features", vec!["huge.npy", "truncated data"]),
        // Every joint at one point: rotations are undefined, an error rather than NaN features.
        (
            "collapsed.npy",
            npy::encode(&[3, 22, 3], &[0.5f32; 198]),
            "features",
            vec!["collapsed.npy", "the leg (ankle to root) is 0.000 m long"],
        ),
    ];
    for (name, bytes, cmd, needles) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let o = diffkfc(&["data", cmd, s(&p), "-o", s(&d.join("out.npy"))]);
        assert_one_line_error(&o, &needles);
    }
    // NaN in a joint we use and in a feature.
    let mut j = vec![0.1f32; 4 * 22 * 3];
    j[2 * 66 + 5 * 3 + 1] = f32::NAN;
    let p = d.join("nan_joints.npy");
    npy::write(&p, &[4, 22, 3], &j).unwrap();
    assert_one_line_error(
        &diffkfc(&["data", "features", s(&p), "-o", s(&d.join("o.npy"))]),
        &["nan_joints.npy", "frame 2, joint 5"],
    );
    let mut f = vec![0.0f32; 3 * 263];
    f[263 + 7] = f32::INFINITY;
    let p = d.join("nan_feats.npy");
    npy::write(&p, &[3, 263], &f).unwrap();
    assert_one_line_error(
        &diffkfc(&["data", "joints", s(&p), "-o", s(&d.join("o.npy"))]),
        &["nan_feats.npy", "frame 1, feature 7"],
    );
    // A missing file and a bad flag value.
    let o = diffkfc(&["data", "joints", s(&d.join("missing.npy")), "-o", "x.npy"]);
    assert_one_line_error(&o, &["missing.npy", "No such file"]);
    assert_eq!(stderr(&o).matches("No such file").count(), 1, "cause repeated: {}", stderr(&o));
    let p = d.join("ok.npy");
    npy::write(&p, &[5, 22, 3], &(0..330).map(|i| i as f32 * 0.01).collect::<Vec<_>>()).unwrap();
    assert_one_line_error(
        &diffkfc(&["data", "features", s(&p), "--fps=-3", "-o", "o.npy"]),
        &["--fps"],
    );
    assert_one_line_error(
        &diffkfc(&["data", "features", s(&p), "--fps", "1e-9", "-o", "o.npy"]),
        &["--fps", "1 to 1000"],
    );
    assert_one_line_error(
        &diffkfc(&["data", "features", s(&p), "--feet-threshold", "nan", "-o", "o.npy"]),
        &["--feet-threshold", "NaN"],
    );
    assert_one_line_error(&diffkfc(&["data", "features", s(&p), "--bogus"]), &["--bogus"]);
    // A motion that runs off to 1e38 m is refused at once (drawing its ground grid never ended);
    // so is one whose small steps add up past 1 km.
    let mut f = vec![0.0f32; 4 * 263];
    f[263 + 2] = 3e38;
    let p = d.join("far.npy");
    npy::write(&p, &[4, 263], &f).unwrap();
    let t0 = std::time::Instant::now();
    assert_one_line_error(
        &diffkfc(&["render", s(&p), "-o", s(&d.join("far.gif"))]),
        &["far.npy", "frame 1, feature 2", "root velocity"],
    );
    let mut f = vec![0.0f32; 1000 * 263];
    for t in 0..1000 {
        f[t * 263 + 2] = 1.5;
    }
    npy::write(&p, &[1000, 263], &f).unwrap();
    assert_one_line_error(
        &diffkfc(&["render", s(&p), "-o", s(&d.join("far.gif"))]),
        &["far.npy", "from the origin", "within 1000 m"],
    );
    assert!(t0.elapsed().as_secs() < 10);
    // Nothing half-written is left behind by failures.
    assert!(!d.join("out.npy").exists() && !d.join("o.npy").exists());
}

#[test]
fn version_and_help_with_examples() {
    let o = diffkfc(&["--version"]);
    assert!(o.status.success());
    assert!(stdout(&o).starts_with(&format!("diffkfc {}", env!("CARGO_PKG_VERSION"))));
    let cmds: Vec<Vec<&str>> = vec![
        vec!["--help"],
        vec!["data", "--help"],
        vec!["data", "features", "--help"],
        vec!["data", "joints", "--help"],
        vec!["data", "bvh", "--help"],
        vec!["data", "check", "--help"],
        vec!["data", "synth", "--help"],
        vec!["data", "bench-loader", "--help"],
        vec!["render", "--help"],
        vec!["train", "--help"],
        vec!["sample", "--help"],
        vec!["keyframes", "--help"],
        vec!["keyframes", "suggest", "--help"],
        vec!["model", "--help"],
        vec!["model", "summary", "--help"],
        vec!["model", "export", "--help"],
        vec!["bench", "--help"],
        vec!["text-embed", "--help"],
        vec!["eval", "--help"],
        vec!["eval", "train-evaluator", "--help"],
    ];
    for cmd in cmds {
        let o = diffkfc(&cmd);
        assert!(o.status.success(), "{cmd:?}");
        let out = stdout(&o);
        assert!(out.contains("Example"), "{cmd:?} has no example:\n{out}");
        // Every flag has a description: in the long help an option line is followed by its
        // text, indented deeper (a bare option line is followed by a blank line).
        let lines: Vec<&str> = out.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            let t = l.trim_start();
            if l.starts_with("  ")
                && (t.starts_with("--") || (t.starts_with('-') && t.chars().nth(2) == Some(',')))
            {
                if t.split_once("  ").is_some_and(|(_, rest)| {
                    !rest.trim().is_empty() && !rest.trim().starts_with('[')
                }) {
                    continue; // short help: the text on the same line
                }
                let next = lines.get(i + 1).copied().unwrap_or("");
                let indent = |x: &str| x.len() - x.trim_start().len();
                assert!(
                    !next.trim().is_empty()
                        && indent(next) > indent(l)
                        && !next.trim_start().starts_with('['),
                    "{cmd:?}: {t} has no description"
                );
            }
        }
    }
}

/// `data bvh` and `data joints` on BVH files: the rig round trip, a renamed joint named in the
/// error and resolved by --rig-map, bad BVH flags.
#[test]
fn bvh_rig_round_trip_and_rig_map() {
    let Some(real) = fixtures::require("humanml3d/new_joints/012314.npy") else {
        return;
    };
    let d = scratch("bvh-rig");
    let bvh = d.join("walk.bvh");
    let o = diffkfc(&["data", "bvh", s(&real), "-o", s(&bvh)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("170 frames"), "{}", stdout(&o));
    let back = d.join("back.npy");
    let o = diffkfc(&["data", "joints", s(&bvh), "-o", s(&back)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (a, b) = (npy::read_f32(&real).unwrap(), npy::read_f32(&back).unwrap());
    assert!(max_abs(&a.data, &b.data) < 1e-4);
    broken_files_are_refused(&d, &bvh, &real);

    let renamed = d.join("renamed.bvh");
    std::fs::write(
        &renamed,
        std::fs::read_to_string(&bvh).unwrap().replace("JOINT LeftHand", "JOINT hand_L"),
    )
    .unwrap();
    let o = diffkfc(&["data", "joints", s(&renamed), "-o", s(&d.join("x.npy"))]);
    assert_one_line_error(&o, &["renamed.bvh", "l_wrist (LeftHand)", "--rig-map"]);
    let map = d.join("map.json");
    std::fs::write(&map, r#"{"LeftHand": "hand_L"}"#).unwrap();
    let o = diffkfc(&["data", "joints", s(&renamed), "--rig-map", s(&map), "-o", s(&back)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(max_abs(&a.data, &npy::read_f32(&back).unwrap().data) < 1e-4);

    std::fs::write(&map, r#"{"LeftHand": 3}"#).unwrap();
    let o = diffkfc(&["data", "joints", s(&renamed), "--rig-map", s(&map), "-o", s(&back)]);
    assert_one_line_error(&o, &["--rig-map", "map.json", "LeftHand"]);
    let o = diffkfc(&["data", "joints", s(&bvh), "--bvh-units", "furlong", "-o", s(&back)]);
    assert_one_line_error(&o, &["--bvh-units", "furlong"]);
}

/// Files a broken exporter or a unit mix-up writes: refused with what is wrong, never converted
/// (each of these used to exit 0, some with non-finite joints); an output naming its input is
/// refused before the input is read.
fn broken_files_are_refused(d: &Path, bvh: &Path, joints: &Path) {
    let text = std::fs::read_to_string(bvh).unwrap();
    let frames = text.lines().find(|l| l.starts_with("Frames:")).unwrap().to_string();
    let first_values = text.lines().skip_while(|l| !l.starts_with("Frame Time")).nth(1).unwrap();
    let big = format!("1e30 {}", first_values.split_once(' ').unwrap().1);
    let offsets = text
        .lines()
        .map(|l| if l.trim_start().starts_with("OFFSET") { "OFFSET 0 0 0" } else { l })
        .collect::<Vec<_>>()
        .join("\n");
    for (name, broken, needle) in [
        ("negative", text.replace(&frames, "Frames: -3"), "'Frames: -3' is not a frame count"),
        ("overflow", text.replace(&frames, "Frames: 99999999999999999999"), "not a frame count"),
        ("words", text.replace(&frames, "Frames: many"), "not a frame count"),
        ("noframes", text.replace(&format!("{frames}\n"), ""), "no 'Frames:' line"),
        ("noroot", text.replacen("ROOT", "JOINT", 1), "not a ROOT"),
        ("zero", offsets, "every OFFSET is zero"),
        (
            "far",
            text.replacen(first_values, &big, 1),
            "Xposition is 1000000000000000000000000000000",
        ),
    ] {
        let p = d.join(format!("{name}.bvh"));
        std::fs::write(&p, broken).unwrap();
        let (npy_out, gif_out) = (d.join("o.npy"), d.join("o.gif"));
        for args in [
            vec!["data", "joints", s(&p), "-o", s(&npy_out)],
            vec!["render", s(&p), "-o", s(&gif_out)],
        ] {
            assert_one_line_error(&diffkfc(&args), &[&format!("{name}.bvh"), needle]);
        }
    }
    // Millimetres given as metres.
    let j = npy::read_f32(joints).unwrap();
    let mm = d.join("mm.npy");
    npy::write(&mm, &j.shape, &j.data.iter().map(|v| v * 1000.0).collect::<Vec<_>>()).unwrap();
    assert_one_line_error(
        &diffkfc(&["data", "features", s(&mm), "-o", s(&d.join("o.npy"))]),
        &["mm.npy", "look like millimetres"],
    );
    // -o naming the input, in any spelling.
    let before = std::fs::read(bvh).unwrap();
    let same = format!("{}/./{}", d.display(), bvh.file_name().unwrap().to_string_lossy());
    for (cmd, input, out) in [
        ("bvh", joints.to_path_buf(), joints.to_str().unwrap().to_string()),
        ("joints", bvh.to_path_buf(), same),
    ] {
        assert_one_line_error(
            &diffkfc(&["data", cmd, s(&input), "-o", &out]),
            &["-o", "is the input file"],
        );
    }
    assert_eq!(std::fs::read(bvh).unwrap(), before);
    // render's output naming its input (a motion file called .gif), spelt another way.
    let gif_named = d.join("m.gif");
    std::fs::copy(joints, &gif_named).unwrap();
    let spelt = format!("{}/./m.gif", d.display());
    assert_one_line_error(
        &diffkfc(&["render", s(&gif_named), "-o", &spelt]),
        &["-o", "is the input file"],
    );
    assert_eq!(std::fs::read(&gif_named).unwrap(), std::fs::read(joints).unwrap());
    // A picture under a name that says otherwise, and a sheet with no columns.
    assert_one_line_error(
        &diffkfc(&["render", s(joints), "-o", s(&d.join("r.txt"))]),
        &["-o", "r.txt", "must end in .gif or .html"],
    );
    assert_one_line_error(
        &diffkfc(&["render", s(joints), "--sheet", "--columns", "0", "-o", s(&d.join("r.png"))]),
        &["--columns", "0 must be 1 to 64"],
    );
    assert!(!d.join("r.txt").exists() && !d.join("o.npy").exists());
}

/// This session's new commands refuse bad input in one line: `data clips` with no manifest or no
/// match, `render --page` of a folder that is not a sample set or to a non-HTML file.
#[test]
fn clips_and_page_refuse_bad_input() {
    let d = scratch("clips-page");
    let data = synth(&d, 12, 6);
    let o = diffkfc(&["data", "clips", s(&d), "--split", "test"]);
    assert_one_line_error(&o, &["manifest.json"]);
    let o = diffkfc(&["data", "clips", s(&data), "--action", "fly_to_the_moon"]);
    assert_one_line_error(&o, &["no clip matches", "fly_to_the_moon"]);
    let o = diffkfc(&["data", "clips", s(&data), "--count", "2"]);
    assert!(o.status.success() && stdout(&o).lines().count() == 2, "{}", stderr(&o));
    let o = diffkfc(&["render", "--page", s(&data), "-o", s(&d.join("page.html"))]);
    assert_one_line_error(&o, &["results.json"]);
    let o = diffkfc(&["render", "--page", s(&data), "-o", s(&d.join("page.png"))]);
    assert_one_line_error(&o, &["must end in .html with --page"]);
    assert!(!d.join("page.html").exists() && !d.join("view.html").exists());
}

/// A reader that goes away (`diffkfc ... | head -1`) ends the process quietly, by SIGPIPE as it
/// ends other command-line tools, never with a panic.
#[test]
#[cfg(unix)]
fn a_closed_stdout_is_not_a_panic() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Command, Stdio};
    let dir = scratch("closed-stdout");
    let data = synth(&dir, 12, 1);
    // The pipe's reading end is closed before the process starts: its first line meets EPIPE.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = Command::new(env!("CARGO_BIN_EXE_diffkfc"))
        .args(["data", "clips", s(&data), "--count", "12"])
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("run diffkfc");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    // 13: SIGPIPE.
    assert_eq!(o.status.signal(), Some(13), "SIGPIPE expected, got {:?}: {err}", o.status);
}

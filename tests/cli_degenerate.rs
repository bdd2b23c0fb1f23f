//! Degenerate motions through the binary, each class once per command that reads a motion
//! (`sample --from`, `keyframes suggest --from`, `data features|joints|bvh`, `render`): every
//! run exits 0 with finite outputs or refuses with one line naming the file and writes nothing. The property test
//! behind it, over 10 000 generated cases, is `crates/model/tests/degenerate.rs`.

mod common;
use common::*;
use diffkfc_data::io::npy;
use diffkfc_data::motion::representation::{joints_to_f32, recover_from_ric_f32};
use diffkfc_data::T2M;
use diffkfc_synth::{clip, Body};
use std::path::Path;

const D: usize = 263;

/// (name, features [T, D]) of each class, from a synthetic walk.
fn feature_cases() -> Vec<(&'static str, Vec<f32>)> {
    let (_, walk) = clip(Body::Legacy, 0, 0);
    let w = walk[..60 * D].to_vec();
    let map = |f: &dyn Fn(usize, f32) -> f32| -> Vec<f32> {
        w.iter().enumerate().map(|(i, &v)| f(i % D, v)).collect()
    };
    let ric = 4..67;
    let constant: Vec<f32> = w[..D].iter().cycle().take(60 * D).copied().collect();
    vec![
        ("zeros", vec![0.0; 60 * D]),
        ("constant", constant),
        ("one_frame", w[..D].to_vec()),
        ("two_frames", w[..2 * D].to_vec()),
        ("collapsed", map(&|c, v| if ric.contains(&c) { 0.0 } else { v })),
        ("still", map(&|c, v| if c < 3 { 0.0 } else { v })),
        ("far", map(&|c, v| if c == 2 { 1e4 / 60.0 } else { v })),
        ("tiny", map(&|c, v| if (3..67).contains(&c) { v * 1e-3 } else { v })),
        ("huge", map(&|c, v| if (3..67).contains(&c) { v * 1e3 } else { v })),
    ]
}

/// Exit 0 with every `.npy` written finite, or a one-line refusal naming `file`.
fn works_or_refuses(o: &std::process::Output, file: &str, out: &Path, what: &str) -> bool {
    if o.status.success() {
        let files: Vec<_> = if out.is_dir() {
            std::fs::read_dir(out).unwrap().map(|e| e.unwrap().path()).collect()
        } else {
            vec![out.to_path_buf()]
        };
        for p in files.iter().filter(|p| p.extension().is_some_and(|e| e == "npy")) {
            let a = npy::read_f32(p).unwrap();
            assert!(a.data.iter().all(|v| v.is_finite()), "{what}: {} holds NaN", p.display());
        }
        true
    } else {
        assert_one_line_error(o, &[file]);
        // A refused command writes nothing.
        assert!(!out.exists(), "{what}: refused but {} was written", out.display());
        false
    }
}

#[test]
fn every_degenerate_class_works_or_refuses_with_one_line() {
    let d = scratch("degenerate");
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/tiny-synth");
    let mut tally = Vec::new();
    for (name, f) in feature_cases() {
        let t = f.len() / D;
        let joints = recover_from_ric_f32(&T2M, &f);
        for (kind, shape, data) in
            [("f", vec![t, D], f.clone()), ("j", vec![t, 22, 3], joints_to_f32(&joints))]
        {
            let file = format!("{kind}_{name}.npy");
            let p = d.join(&file);
            npy::write(&p, &shape, &data).unwrap();
            let out = d.join(format!("out_{kind}_{name}"));
            let o_npy = out.with_extension("npy");
            let bvh = out.with_extension("bvh");
            let gif = out.with_extension("gif");
            let json = out.with_extension("json");
            let runs: Vec<(&str, Vec<&str>, &Path)> = vec![
                (
                    "sample",
                    vec![
                        "sample",
                        "--checkpoint",
                        model,
                        "--text",
                        "a person walks.",
                        "--from",
                        s(&p),
                        "--frames",
                        "0",
                        "--out",
                        s(&out),
                    ],
                    &out,
                ),
                ("suggest", vec!["keyframes", "suggest", "--from", s(&p), "-o", s(&json)], &json),
                ("joints", vec!["data", "joints", s(&p), "-o", s(&o_npy)], &o_npy),
                ("bvh", vec!["data", "bvh", s(&p), "-o", s(&bvh)], &bvh),
                ("render", vec!["render", s(&p), "-o", s(&gif)], &gif),
            ];
            for (what, args, written) in runs {
                let args = if kind == "j" && what == "joints" {
                    vec!["data", "features", s(&p), "-o", s(&o_npy)]
                } else {
                    args
                };
                let o = diffkfc(&args);
                let ok = works_or_refuses(&o, &file, written, &format!("{what} {file}"));
                tally.push(format!("{file} {what}: {}", if ok { "ok" } else { "refused" }));
            }
        }
    }
    eprintln!("{}", tally.join("\n"));
    // The classes a user can animate work; a collapsed body is refused as a source of keys.
    for expect in
        ["f_constant.npy sample: ok", "f_still.npy sample: ok", "f_zeros.npy sample: refused"]
    {
        assert!(tally.iter().any(|l| l == expect), "{expect} missing:\n{}", tally.join("\n"));
    }
}

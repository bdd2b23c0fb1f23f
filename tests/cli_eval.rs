//! End-to-end: `diffkfc eval train-evaluator` learns text-motion retrieval far above chance.

mod common;
use common::*;

#[test]
fn evaluator_beats_chance() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("eval");
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "400", "--seed", "5"]).status.success());
    let out = d.join("evaluator");
    let o = diffkfc(&["eval", "train-evaluator", "--data", s(&data), "--out", s(&out), "--max-steps", "80"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let top3 = r["r_precision_top3"].as_f64().unwrap();
    let top1 = r["r_precision_top1"].as_f64().unwrap();
    eprintln!("evaluator after 80 steps: top-1 {top1:.3}, top-3 {top3:.3}");
    assert!(top1 > 3.0 / 32.0 && top3 > 9.0 / 32.0, "{r}");
    assert!(r["last_loss"].as_f64().unwrap() < r["first_loss"].as_f64().unwrap());
    for f in ["Mean.npy", "Std.npy", "ckpt-00000080.safetensors"] {
        assert!(out.join(f).exists(), "{f}");
    }
    // Too few items to form a batch of 32.
    let small = d.join("small");
    assert!(diffkfc(&["data", "synth", "--out", s(&small), "--clips", "20"]).status.success());
    assert_one_line_error(&diffkfc(&["eval", "train-evaluator", "--data", s(&small), "--out", s(&d.join("e2"))]), &["at least 32 items"]);
}

//! End-to-end: `diffkfc eval train-evaluator` learns text-motion retrieval far above chance;
//! `diffkfc eval` on a tiny checkpoint writes both reports with every row and metric.

mod common;
use common::*;

#[test]
fn evaluator_beats_chance() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("eval");
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "400", "--seed", "5"])
        .status
        .success());
    let out = d.join("evaluator");
    let o = diffkfc(&[
        "eval",
        "train-evaluator",
        "--data",
        s(&data),
        "--out",
        s(&out),
        "--max-steps",
        "80",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let top3 = r["r_precision_top3"].as_f64().unwrap();
    let top1 = r["r_precision_top1"].as_f64().unwrap();
    eprintln!("evaluator after 80 steps: top-1 {top1:.3}, top-3 {top3:.3}");
    assert!(top1 > 3.0 / 32.0 && top3 > 9.0 / 32.0, "{r}");
    assert!(r["last_loss"].as_f64().unwrap() < r["first_loss"].as_f64().unwrap());
    for f in ["Mean.npy", "Std.npy", "ckpt-00000080.safetensors"] {
        assert!(out.join(f).exists(), "{f}");
    }
    // Training flags that make a broken evaluator are refused before any work.
    let train_ev = |extra: &[&str]| {
        let e2 = d.join("e-bad");
        let mut a = vec!["eval", "train-evaluator", "--data", s(&data), "--out", s(&e2)];
        a.extend(extra);
        let o = diffkfc(&a);
        assert!(!e2.join("Mean.npy").exists(), "a broken evaluator was saved");
        o
    };
    for (flag, v, needle) in [
        ("--lr", "nan", "--lr: NaN"),
        ("--lr", "1e30", "--lr: 1000000000000000000000000000000"),
        ("--lr", "0", "--lr: 0 must be"),
        ("--batch-size", "0", "--batch-size: 0 must be 2"),
        ("--batch-size", "100000000", "--batch-size: 100000000"),
        ("--max-steps", "0", "--max-steps: 0"),
    ] {
        assert_one_line_error(&train_ev(&[flag, v]), &[needle]);
    }
    evaluate_tiny_checkpoint(&d, &data, &out);
    // Too few items to form a batch of 32.
    let small = d.join("small");
    assert!(diffkfc(&["data", "synth", "--out", s(&small), "--clips", "20"]).status.success());
    assert_one_line_error(
        &diffkfc(&["eval", "train-evaluator", "--data", s(&small), "--out", s(&d.join("e2"))]),
        &["at least 32 items"],
    );
}

fn metric(row: &serde_json::Value, k: &str) -> f64 {
    row["metrics"][k]["mean"].as_f64().unwrap_or_else(|| panic!("{k} missing in {row}"))
}

fn evaluate_tiny_checkpoint(
    d: &std::path::Path,
    data: &std::path::Path,
    evaluator: &std::path::Path,
) {
    let run = two_step_run(d, data, "run", None);
    let rep = d.join("report");
    let common = [
        "eval",
        "--checkpoint",
        s(&run),
        "--evaluator",
        s(evaluator),
        "--data",
        s(data),
        "--replications",
        "2",
        "--steps",
        "3",
        "--samples-for-ade",
        "2",
    ];
    let mut args: Vec<&str> = common.to_vec();
    // The paper's guidance (the defaults are s = 1, r = 0), so the sweep rows carry TG too.
    args.extend([
        "--num-items",
        "32",
        "--compare",
        "--two-stage",
        "--sweep-rates",
        "0,0.1",
        "--multimodality",
        "--mm-texts",
        "2",
        "--transition-guidance",
        "100",
        "--kf-guidance",
        "2.5",
        "--out",
        s(&rep),
    ]);
    let o = diffkfc(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("estimate"), "{}", stdout(&o));
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    for needle in [
        "Table 2 layout",
        "Table 4 layout",
        "| Real motion |",
        "| DiffKFC |",
        "| DiffKFC w/o TG |",
        "| MDM-inp |",
        "| 0% |",
        "| 10% |",
        "K-TranS",
    ] {
        assert!(md.contains(needle), "{needle} not in\n{md}");
    }
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rep.join("report.json")).unwrap()).unwrap();
    let rows = r["rows"].as_array().unwrap();
    let find = |name: &str, rate: f64| {
        rows.iter()
            .find(|x| x["name"] == name && x["keyframe_rate"].as_f64() == Some(rate))
            .unwrap_or_else(|| panic!("{name} {rate}"))
    };
    let (real, kfc, inp, zero) = (
        find("Real motion", 0.05),
        find("DiffKFC", 0.05),
        find("MDM-inp", 0.05),
        find("DiffKFC", 0.0),
    );
    assert_eq!(real["metrics"]["fid"]["replications"].as_array().unwrap().len(), 2);
    // A 2-step model is far from the real motions the evaluator embeds; real test items are not.
    assert!(metric(kfc, "fid") > metric(real, "fid"), "{kfc} {real}");
    // FID's mean term is a non-negative part of it (the covariance term is the rest).
    let mean_term = metric(kfc, "fid_mean_term");
    assert!((0.0..=metric(kfc, "fid") + 1e-9).contains(&mean_term), "{kfc}");
    // Each item's clip and caption per replication, and each motion's text rank (0..=31)
    // in the same order, for the real and the generated rows.
    let items = r["meta"]["items"].as_array().unwrap();
    assert_eq!(items.len(), 2);
    assert!(items.iter().all(|rep| rep.as_array().unwrap().len() == 32), "{items:?}");
    assert!(items[0][0]["caption"].as_str().is_some_and(|c| !c.is_empty()), "{items:?}");
    for row in [real, kfc] {
        let ranks = row["per_item"]["text_rank"].as_array().unwrap();
        assert_eq!(ranks.len(), 2);
        for rep in ranks {
            let rep = rep.as_array().unwrap();
            assert_eq!(rep.len(), 32);
            assert!(rep.iter().all(|x| x.as_f64().is_some_and(|x| (0.0..32.0).contains(&x))));
        }
    }
    // R-precision top-3 is the share of ranks under 3.
    let ranks: Vec<f64> = kfc["per_item"]["text_rank"][0]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let top3 = ranks.iter().filter(|&&x| x < 3.0).count() as f64 / 32.0;
    assert_eq!(top3, kfc["metrics"]["r_top3"]["replications"][0].as_f64().unwrap(), "{kfc}");
    assert!(metric(real, "r_top3") > 3.0 / 32.0, "{real}");
    // The default fit (warp, with root keyframes) meets the keyframes exactly: root-relative
    // and global, for both methods.
    assert!(metric(kfc, "k_err_local") < 1e-5 && metric(inp, "k_err_local") < 1e-5, "{kfc}");
    assert!(metric(kfc, "k_err") < 1e-3 && metric(inp, "k_err") < 1e-3, "{kfc} {inp}");
    for k in [
        "ade",
        "k_err",
        "k_trans",
        "k_trans_real",
        "foot_skate",
        "diversity",
        "multimodality",
        "mm_dist",
    ] {
        assert!(metric(kfc, k).is_finite(), "{k}");
    }
    // Two stages: keyframes from a text-only proposal, met exactly (K-Err against the proposal).
    let staged = find("DiffKFC, suggested keys", 0.05);
    assert!(metric(staged, "k_err_local") < 1e-5 && metric(staged, "fid").is_finite(), "{staged}");
    // Without keyframes there is nothing to measure at keyframes.
    assert!(
        zero["metrics"].get("k_err").is_none() && zero["metrics"].get("ade").is_some(),
        "{zero}"
    );
    let mut few: Vec<&str> = common.to_vec();
    few.extend(["--num-items", "8", "--out", s(&rep)]);
    assert_one_line_error(&diffkfc(&few), &["--num-items", "at least 32"]);
    // Without snapping the raw model misses its keyframes; the report says which mode ran.
    let raw = d.join("raw");
    let o = diffkfc(&[
        "eval",
        "--checkpoint",
        s(&run),
        "--evaluator",
        s(evaluator),
        "--data",
        s(data),
        "--replications",
        "1",
        "--steps",
        "2",
        "--samples-for-ade",
        "1",
        "--num-items",
        "32",
        "--no-snap",
        "--transition-guidance",
        "0",
        "--kf-guidance",
        "1",
        "--keyframe-strategy",
        "uniform",
        "--out",
        s(&raw),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(raw.join("report.json")).unwrap()).unwrap();
    assert_eq!(
        (
            r["meta"]["keyframe_fit"].as_str() == Some("none"),
            r["meta"]["keyframe_strategy"].as_str(),
            r["meta"]["kf_guidance"].as_f64()
        ),
        (true, Some("uniform"), Some(1.0))
    );
    let row =
        r["rows"].as_array().unwrap().iter().find(|x| x["name"] == "DiffKFC w/o TG").expect("row");
    assert!(metric(row, "k_err_local") > 1e-3, "{row}");
    // The official T2M evaluator's layout (here the small converted copy of tests/t2m, random
    // weights): the tables run on it and the report names it.
    let t2m = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../eval/tests/t2m/converted");
    let t2m_arg = format!("t2m:{}", t2m.display());
    let t2m_out = d.join("t2m");
    let o = diffkfc(&[
        "eval",
        "--checkpoint",
        s(&run),
        "--evaluator",
        &t2m_arg,
        "--data",
        s(data),
        "--replications",
        "1",
        "--steps",
        "2",
        "--num-items",
        "32",
        "--out",
        s(&t2m_out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(t2m_out.join("report.json")).unwrap()).unwrap();
    assert!(
        r["meta"]["evaluator_name"].as_str().unwrap().contains("T2M evaluator"),
        "{}",
        r["meta"]
    );
    let md = std::fs::read_to_string(t2m_out.join("report.md")).unwrap();
    assert!(md.contains("the T2M evaluator of Guo et al. 2022"), "{md}");
    let row = r["rows"].as_array().unwrap().iter().find(|x| x["name"] == "DiffKFC").expect("row");
    assert!(metric(row, "fid").is_finite() && metric(row, "r_top3") >= 0.0, "{row}");
    let none = d.join("none");
    let bad = |evaluator: &std::path::Path, extra: &[&str], needles: &[&str]| {
        let mut a = vec![
            "eval",
            "--checkpoint",
            s(&run),
            "--evaluator",
            s(evaluator),
            "--data",
            s(data),
            "--out",
            s(&raw),
        ];
        a.extend(extra);
        assert_one_line_error(&diffkfc(&a), needles);
    };
    bad(evaluator, &["--sweep-rates", "0,2"], &["--sweep-rates", "2"]);
    bad(evaluator, &["--replications", "0"], &["--replications", "0 must be 1 to 100"]);
    // Counts that would run for ever or fail to allocate, and guidance eval used to accept.
    bad(evaluator, &["--replications", "1000000000"], &["--replications", "1 to 100"]);
    bad(evaluator, &["--samples-for-ade", "100000000"], &["--samples-for-ade", "1 to 100"]);
    bad(evaluator, &["--batch-size", "100000000"], &["--batch-size", "1 to 1024"]);
    bad(evaluator, &["--mm-texts", "0"], &["--mm-texts", "0 must be 1"]);
    bad(evaluator, &["--kf-guidance", "nan"], &["--kf-guidance", "NaN"]);
    bad(evaluator, &["--transition-guidance", "inf"], &["--transition-guidance", "inf"]);
    bad(evaluator, &["--sweep-rates", ""], &["--sweep-rates", "lists no rate"]);
    bad(evaluator, &["--sweep-rates", " , "], &["--sweep-rates", "lists no rate"]);
    bad(evaluator, &["--keyframe-strategy", "odd"], &["--keyframe-strategy", "odd"]);
    bad(&none, &[], &["none", "train-evaluator"]);
    let no_t2m = format!("t2m:{}", none.display());
    bad(
        std::path::Path::new(&no_t2m),
        &[],
        &["missing evaluator.safetensors", "convert-t2m-evaluator.py"],
    );
    // A checkpoint built for shorter motions than the split's items is refused before any work.
    let short = two_step_run(d, data, "short-run", Some(30));
    let o = diffkfc(&[
        "eval",
        "--checkpoint",
        s(&short),
        "--evaluator",
        s(evaluator),
        "--data",
        s(data),
        "--out",
        s(&raw),
    ]);
    assert_one_line_error(&o, &["--checkpoint", "at most 30 frames (model.max_frames)"]);
}

//! End-to-end: `model summary`, `bench` (the CI smoke run of the benchmark suite), `text-embed`,
//! config errors.

mod common;
use std::path::Path;

use common::*;

fn config(name: &str) -> String {
    format!("{}/../../configs/{name}.json", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn summary_counts_parameters() {
    let o = diffkfc(&["model", "summary", "--config", &config("paper-humanml3d")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    let total: usize = out
        .lines()
        .find(|l| l.trim_start().starts_with("total"))
        .unwrap()
        .split_whitespace()
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!((total as f64 - 47e6).abs() < 4.7e6, "{out}");
}

/// Every case of the suite runs on the tiny config and reports time and GFLOP/s (not timed).
#[test]
fn bench_suite_smoke() {
    let o = diffkfc(&["bench", "--config", "tiny", "--frames", "40", "--batch", "2", "--quick"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines: Vec<serde_json::Value> =
        stdout(&o).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let cases: Vec<&str> = lines.iter().map(|v| v["case"].as_str().unwrap()).collect();
    assert_eq!(
        cases,
        [
            "machine",
            "train_step",
            "sampling_call",
            "sampling_call_cached",
            "ddim",
            "loader",
            "train_throughput"
        ]
    );
    // The machine first: its vector flags and measured matrix-product peak; each case's rate
    // as a fraction of it.
    assert!(
        lines[0]["matmul_peak_gflops"].as_f64().unwrap() > 0.0 && lines[0]["avx2"].is_boolean(),
        "{}",
        lines[0]
    );
    let lines = &lines[1..];
    assert!(lines[0]["fraction_of_peak"].as_f64().unwrap() > 0.0);
    // Each timed step paired with a peak reading right after it (one step with --quick).
    let peaks = lines[0]["adjacent_peaks_gflops"].as_array().unwrap();
    assert_eq!(peaks.len(), lines[0]["runs_ms"].as_array().unwrap().len(), "{}", lines[0]);
    assert!(peaks.iter().all(|p| p.as_f64().unwrap() > 0.0), "{}", lines[0]);
    assert!(lines[0]["fraction_of_adjacent_peak"].as_f64().unwrap() > 0.0);
    for v in &lines[..4] {
        assert!(v["ms"].as_f64().unwrap() > 0.0 && v["gflops"].as_f64().unwrap() > 0.0, "{v}");
        // CPU seconds per wall second over the timed runs: measured, and at most every thread
        // (well under 1 only where other processes take the cores, as on a busy CI machine).
        let util = v["cpu_utilisation"].as_f64().unwrap();
        let threads = lines[0]["common"]["threads"].as_f64().unwrap_or(64.0);
        assert!(util > 0.02 && util <= threads + 0.5, "{v}");
        // The device's memory is reported on GPUs only: null on flex, but always present.
        assert!(v.get("device_memory").is_some_and(|m| m.is_null()), "{v}");
    }
    assert_eq!(lines[3]["finite"], true);
    // The cached call skips the encoder: fewer FLOPs than the full call.
    assert!(lines[2]["gflop"].as_f64() < lines[1]["gflop"].as_f64());
    assert!(lines[4]["items_per_s"].as_f64().unwrap() > 0.0);
    // Throughput with the loader: the step and the batch's loading add up.
    let step_s = lines[0]["ms"].as_f64().unwrap() / 1e3;
    let mps = lines[5]["motions_per_s"].as_f64().unwrap();
    assert!(mps > 0.0 && mps < 2.0 / step_s, "{}", lines[5]);
    assert_one_line_error(
        &diffkfc(&["bench", "--config", "tiny", "--cases", "train,fly"]),
        &["--cases", "fly"],
    );
    // The whole keyed sample needs weights: a preset is refused, a model directory samples the
    // quick start's 147-frame walk keyed at 5%.
    assert_one_line_error(
        &diffkfc(&["bench", "--config", "tiny", "--cases", "sample"]),
        &["--cases sample", "'tiny'", "model or run directory"],
    );
    if have_text_encoder() {
        let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../../models/tiny-synth");
        let o = diffkfc(&["bench", "--config", model, "--cases", "sample", "--quick"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let line: serde_json::Value =
            serde_json::from_str(stdout(&o).lines().nth(1).unwrap()).unwrap();
        assert_eq!((line["case"].as_str(), line["frames"].as_u64()), (Some("sample"), Some(147)));
        assert!(
            line["ms"].as_f64().unwrap() > 0.0 && line["keys"].as_u64().unwrap() >= 2,
            "{line}"
        );
    }
    // --torch/--reference: a stand-in for the PyTorch script (prints the reference's JSON line
    // with known times) checks the side-by-side plumbing and the ratios without torch.
    let d = scratch("bench");
    let script = d.join("reference.py");
    std::fs::write(&script, "import json\nprint('warming up')\nprint(json.dumps({'train_step_ms': 1e9, 'cfg_call_ms': 1e9}))\n").unwrap();
    let o = diffkfc(&[
        "bench",
        "--config",
        "torch-tiny",
        "--frames",
        "40",
        "--batch",
        "2",
        "--quick",
        "--cases",
        "train,call",
        "--torch",
        "python3",
        "--reference",
        s(&script),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines: Vec<serde_json::Value> =
        stdout(&o).lines().skip(1).map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines[2]["case"], "pytorch");
    let ratio = &lines[3];
    let want = lines[0]["ms"].as_f64().unwrap() / 1e9;
    assert!(
        (ratio["train_step"].as_f64().unwrap() - want).abs() < 1e-12
            && ratio["sampling_call"].as_f64().unwrap() > 0.0,
        "{ratio}"
    );
    // --rounds alternates both sides: a ratio line per round, then their median, min and max.
    let o = diffkfc(&[
        "bench",
        "--config",
        "torch-tiny",
        "--frames",
        "40",
        "--batch",
        "2",
        "--quick",
        "--cases",
        "train,call",
        "--torch",
        "python3",
        "--reference",
        s(&script),
        "--rounds",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines: Vec<serde_json::Value> =
        stdout(&o).lines().skip(1).map(|l| serde_json::from_str(l).unwrap()).collect();
    let cases: Vec<&str> = lines.iter().map(|l| l["case"].as_str().unwrap()).collect();
    assert_eq!(
        cases,
        [
            "train_step",
            "sampling_call",
            "pytorch",
            "ratio",
            "train_step",
            "sampling_call",
            "pytorch",
            "ratio",
            "ratio_summary"
        ]
    );
    let (r1, r2) =
        (lines[3]["train_step"].as_f64().unwrap(), lines[7]["train_step"].as_f64().unwrap());
    let sum = &lines[8]["train_step"];
    assert_eq!(lines[7]["round"], 2);
    assert!(
        (sum["median"].as_f64().unwrap() - (r1 + r2) / 2.0).abs() < 1e-15
            && sum["min"].as_f64().unwrap() == r1.min(r2),
        "{sum}"
    );
    assert_one_line_error(
        &diffkfc(&["bench", "--config", "tiny", "--cases", "call", "--rounds", "0"]),
        &["--rounds"],
    );
    // The shared reference script has no counterpart of our tiny preset (a ratio would compare
    // two networks); scripts/torch_reference.py has, and --torch-compile reaches it.
    let shared = d.join("reference_diffkfc.py");
    std::fs::copy(&script, &shared).unwrap();
    let bench_with = |config: &str, reference: &Path, more: &[&str]| {
        let args = ["bench", "--config", config, "--frames", "24", "--batch", "2", "--quick"];
        let tail = ["--cases", "call", "--torch", "python3", "--reference", s(reference)];
        diffkfc(&[&args[..], &tail[..], more].concat())
    };
    assert_one_line_error(
        &bench_with("tiny", &shared, &[]),
        &["--torch", "reference_diffkfc.py", "--config tiny"],
    );
    let echo = d.join("torch_reference.py");
    std::fs::write(&echo, "import json, sys\nprint(json.dumps({'train_step_ms': 1e9, 'cfg_call_ms': 1e9, 'args': sys.argv[1:]}))\n").unwrap();
    let o = bench_with("mid", &echo, &["--torch-compile"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let line = stdout(&o).lines().find(|l| l.contains("\"pytorch\"")).unwrap().to_string();
    let args =
        serde_json::from_str::<serde_json::Value>(&line).unwrap()["reference"]["args"].to_string();
    assert!(args.contains("\"mid\"") && args.contains("--compile"), "{args}");
    assert_one_line_error(
        &diffkfc(&[
            "bench",
            "--config",
            "torch-tiny",
            "--cases",
            "call",
            "--torch",
            "python3",
            "--reference",
            s(&d.join("none.py")),
        ]),
        &["--reference", "none.py"],
    );
    std::fs::write(&script, "import sys\nsys.exit('no torch here')\n").unwrap();
    assert_one_line_error(
        &diffkfc(&[
            "bench",
            "--config",
            "torch-tiny",
            "--quick",
            "--cases",
            "call",
            "--torch",
            "python3",
            "--reference",
            s(&script),
        ]),
        &["--torch", "no torch here"],
    );
    // --data: the loader case on a given dataset.
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "30"]).status.success());
    let o =
        diffkfc(&["bench", "--config", "tiny", "--quick", "--cases", "loader", "--data", s(&data)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(stdout(&o).lines().last().unwrap()).unwrap();
    assert_eq!((v["case"].as_str(), v["batches"].as_u64()), (Some("loader"), Some(20)));
    assert_one_line_error(&diffkfc(&["bench", "--config", "huge"]), &["--config", "huge"]);
}

#[test]
fn bad_configs_name_the_key() {
    let d = scratch("cfg");
    let p = d.join("bad.json");
    std::fs::write(&p, r#"{"model": "tiny", "training": {"batchsize": 3}}"#).unwrap();
    assert_one_line_error(
        &diffkfc(&["model", "summary", "--config", s(&p)]),
        &["bad.json", "training.batchsize"],
    );
    std::fs::write(&p, "{not json").unwrap();
    assert_one_line_error(
        &diffkfc(&["model", "summary", "--config", s(&p)]),
        &["bad.json", "not valid JSON"],
    );
    assert_one_line_error(
        &diffkfc(&["model", "summary", "--config", s(&d.join("none.json"))]),
        &["none.json"],
    );
    assert_one_line_error(
        &diffkfc(&["bench", "--config", &config("tiny"), "--device", "quantum"]),
        &["--device", "quantum"],
    );
}

#[test]
fn text_embed_prints_ids_and_embedding() {
    let Some(reference) =
        diffkfc_data::testing::fixtures::require("minilm/reference_embeddings.json")
    else {
        return;
    };
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(reference).unwrap()).unwrap();
    let item = &r["items"][0];
    let o = diffkfc(&["text-embed", "--text", item["text"].as_str().unwrap()]);
    if !o.status.success() {
        let err = stderr(&o);
        assert!(err.contains("fetch-text-encoder.sh"), "{err}");
        if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") {
            panic!("text encoder required: {err}");
        }
        eprintln!("SKIPPED: {err}");
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["token_ids"], item["token_ids"]);
    let e: Vec<f64> =
        v["embedding"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let re: Vec<f64> =
        item["embedding"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let cos: f64 = e.iter().zip(&re).map(|(a, b)| a * b).sum::<f64>()
        / re.iter().map(|b| b * b).sum::<f64>().sqrt();
    assert!(cos > 0.9999, "{cos}");
    assert_one_line_error(&diffkfc(&["text-embed", "--text", "   "]), &["--text", "empty"]);
    assert_one_line_error(
        &diffkfc(&["text-embed", "--text", "x", "--encoder-dir", "/nonexistent"]),
        &["fetch-text-encoder.sh"],
    );
}

/// One ownership rule for every folder a command writes: an exported model is written over by
/// `model export` alone (`eval train-evaluator --out MODEL` once wrote checkpoints into it), and
/// a folder of another kind is refused in one line unless `--force`.
#[test]
fn commands_refuse_folders_they_do_not_own() {
    if !have_text_encoder() {
        return;
    }
    let d = scratch("ownership");
    let data = synth(&d, 40, 4);
    let run = two_step_run(&d, &data, "run", None);
    let model = d.join("model");
    let o = diffkfc(&["model", "export", "--checkpoint", s(&run), "--out", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let files = |p: &std::path::Path| {
        let mut v: Vec<String> = std::fs::read_dir(p)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let before = files(&model);
    for force in [false, true] {
        let mut a = vec![
            "eval",
            "train-evaluator",
            "--data",
            s(&data),
            "--out",
            s(&model),
            "--max-steps",
            "2",
        ];
        if force {
            a.push("--force");
        }
        assert_one_line_error(
            &diffkfc(&a),
            &["is an exported model", "only `diffkfc model export`"],
        );
        let o = diffkfc(&[
            "train",
            "--config",
            s(&d.join("run.json")),
            "--data",
            s(&data),
            "--out",
            s(&model),
        ]);
        assert_one_line_error(&o, &["is an exported model"]);
    }
    assert_eq!(files(&model), before, "the model folder changed");
    let o = diffkfc(&[
        "sample",
        "--checkpoint",
        s(&model),
        "--text",
        "a person walks.",
        "--length",
        "20",
        "--steps",
        "2",
        "--out",
        s(&d.join("s")),
    ]);
    assert!(o.status.success(), "the model still loads: {}", stderr(&o));
    // Another kind: a run is not an evaluation report's folder, nor a model's, unless forced.
    let o = diffkfc(&["model", "export", "--checkpoint", s(&run), "--out", s(&d.join("s"))]);
    assert_one_line_error(&o, &["holds samples (diffkfc sample), not an exported model"]);
    let o = diffkfc(&[
        "eval",
        "train-evaluator",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--max-steps",
        "2",
    ]);
    assert_one_line_error(&o, &["holds a training run (diffkfc train)", "--force"]);
    // A model is exported again over itself.
    let o = diffkfc(&["model", "export", "--checkpoint", s(&run), "--out", s(&model)]);
    assert!(o.status.success(), "{}", stderr(&o));
}

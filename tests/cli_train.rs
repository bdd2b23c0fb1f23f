//! End-to-end: `diffkfc train` writes checkpoints, metrics and a loss curve, resumes, survives
//! SIGKILL, and rejects bad input with one-line errors.

mod common;
use common::*;
use std::path::Path;
use std::process::Command;

const CFG: &str = r#"{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0]},
  "training": {"batch_size": 4, "max_steps": 6, "checkpoint_every": 2, "keep_checkpoints": 2,
               "val_every": 3, "val_batches": 1, "log_every": 1}}"#;

fn setup(name: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let d = scratch(name);
    let data = d.join("synth");
    assert!(diffkfc(&["data", "synth", "--out", s(&data), "--clips", "20", "--seed", "9"]).status.success());
    std::fs::write(d.join("cfg.json"), CFG).unwrap();
    (d, data)
}

fn steps(run: &Path) -> Vec<u64> {
    // Training steps (validation-only lines carry no "loss").
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v.get("loss").is_some())
        .map(|v| v["step"].as_u64().unwrap())
        .collect()
}

#[test]
fn train_resume_and_outputs() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("train");
    let run = d.join("run");
    let cfg = d.join("cfg.json");
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run), "--max-steps", "4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("steps 0..4"), "{}", stdout(&o));
    for f in ["config.json", "metrics.jsonl", "loss.svg", "ckpt-00000004.safetensors", "ckpt-00000002.safetensors"] {
        assert!(run.join(f).exists(), "{f} missing");
    }
    assert_eq!(steps(&run), vec![1, 2, 3, 4]);
    let svg = std::fs::read_to_string(run.join("loss.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("<path"));
    // Without --resume an existing run is refused; with it, training continues.
    assert_one_line_error(&diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run)]), &["--resume"]);
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run), "--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("steps 4..6"), "{}", stdout(&o));
    assert_eq!(steps(&run), vec![1, 2, 3, 4, 5, 6]);
    // Two checkpoints kept.
    assert!(!run.join("ckpt-00000002.safetensors").exists() && run.join("ckpt-00000006.safetensors").exists());
    // A time budget stops cleanly with a checkpoint.
    let run2 = d.join("budget");
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run2), "--max-steps", "100000", "--time-budget", "3s"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("time budget reached"), "{}", stdout(&o));
    let last = *steps(&run2).last().unwrap();
    assert!(run2.join(format!("ckpt-{last:08}.safetensors")).exists());
}

#[test]
fn sigkill_then_resume() {
    if !have_text_encoder() {
        return;
    }
    let (d, data) = setup("kill");
    let run = d.join("run");
    let cfg = d.join("cfg.json");
    std::fs::write(&cfg, CFG.replace("\"checkpoint_every\": 2", "\"checkpoint_every\": 1")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_diffkfc"))
        .args(["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run), "--max-steps", "100000"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while !run.join("ckpt-00000003.safetensors").exists() && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(&data), "--out", s(&run), "--resume", "--max-steps", "12"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let st = steps(&run);
    assert_eq!(*st.last().unwrap(), 12);
    // Every step appears once, in order: the resumed run rewrote what followed its checkpoint.
    assert_eq!(st, (1..=12).collect::<Vec<u64>>());
}

#[test]
fn bad_train_arguments() {
    let d = scratch("trainbad");
    let cfg = d.join("cfg.json");
    std::fs::write(&cfg, CFG).unwrap();
    assert_one_line_error(&diffkfc(&["train", "--config", s(&cfg)]), &["--data"]);
    assert_one_line_error(&diffkfc(&["train", "--config", s(&cfg), "--data", s(&d.join("nothing"))]), &["nothing", "not found"]);
    assert_one_line_error(&diffkfc(&["train", "--config", s(&cfg), "--time-budget", "soon"]), &["soon"]);
}

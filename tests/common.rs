//! Helpers shared by the end-to-end tests: run the binary, scratch directories.
#![allow(dead_code)]

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn diffkfc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffkfc")).args(args).output().expect("run diffkfc")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A fresh scratch directory per test: removed when the test ends, kept for a look when it
/// panics.
pub fn scratch(name: &str) -> Scratch {
    let d = std::env::temp_dir().join(format!("diffkfc-e2e-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    Scratch(d)
}

/// See [`scratch`]; derefs to its path.
pub struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A failing run: non-zero exit, one line on stderr containing every `needles`, no panic.
pub fn assert_one_line_error(o: &Output, needles: &[&str]) {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure, got success; stderr: {err}");
    assert!(!err.contains("panicked") && !err.contains("RUST_BACKTRACE"), "panic: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
}

/// Whether the text encoder's weights are installed; absent, the caller skips (with a notice),
/// unless DIFFKFC_REQUIRE_FIXTURES=1 makes that a failure.
pub fn have_text_encoder() -> bool {
    let o = diffkfc(&["text-embed", "--text", "a person walks."]);
    if o.status.success() {
        return true;
    }
    if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") {
        panic!("text encoder required: {}", stderr(&o));
    }
    eprintln!("SKIPPED: no text encoder ({})", stderr(&o).trim());
    false
}

/// A synthetic dataset of `clips` clips (seed `seed`) in `dir/synth`.
pub fn synth(dir: &Path, clips: usize, seed: u64) -> PathBuf {
    let data = dir.join("synth");
    let o = diffkfc(&[
        "data",
        "synth",
        "--out",
        s(&data),
        "--clips",
        &clips.to_string(),
        "--seed",
        &seed.to_string(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    data
}

/// A run config that trains a one-layer tiny model for 2 steps: enough for a checkpoint that
/// sampling and evaluation can load.
pub const TWO_STEP_RUN: &str = r#"{"model": {"preset": "tiny", "dec_layers": 1, "dma_sizes": [2, 0]},
  "training": {"batch_size": 4, "max_steps": 2, "checkpoint_every": 2, "val_every": 0}}"#;

/// Train [`TWO_STEP_RUN`] (with `model.max_frames` when given) on `data` into `dir/name`.
pub fn two_step_run(dir: &Path, data: &Path, name: &str, max_frames: Option<usize>) -> PathBuf {
    let cfg = dir.join(format!("{name}.json"));
    let text = match max_frames {
        Some(n) => TWO_STEP_RUN.replace(
            "\"dma_sizes\": [2, 0]",
            &format!("\"dma_sizes\": [2, 0], \"max_frames\": {n}"),
        ),
        None => TWO_STEP_RUN.to_string(),
    };
    std::fs::write(&cfg, text).unwrap();
    let run = dir.join(name);
    let o = diffkfc(&["train", "--config", s(&cfg), "--data", s(data), "--out", s(&run)]);
    assert!(o.status.success(), "{}", stderr(&o));
    run
}

/// Debian's Chromium (or another Chrome on PATH); absent, the caller skips with a notice, unless
/// DIFFKFC_REQUIRE_CHROMIUM=1 (set by .ci/run, which installs it) makes that a failure.
pub fn chromium() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    let found = std::env::split_paths(&path)
        .flat_map(|d| ["chromium", "chromium-browser", "google-chrome"].map(|n| d.join(n)))
        .find(|b| b.is_file());
    if found.is_none() {
        if std::env::var("DIFFKFC_REQUIRE_CHROMIUM").is_ok_and(|v| v == "1") {
            panic!("chromium is not on PATH (apt-get install chromium)");
        }
        eprintln!("SKIPPED: chromium is not on PATH; the 3D page is not checked in a browser");
    }
    found
}

/// The first line of `r` containing `marker`, within 60 s (the rest is drained, so a child
/// writing to the pipe never blocks).
pub fn line_with(r: impl std::io::Read + Send + 'static, marker: &'static str) -> String {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(r).lines().map_while(Result::ok) {
            if l.contains(marker) {
                let _ = tx.send(l);
            }
        }
    });
    rx.recv_timeout(std::time::Duration::from_secs(60))
        .unwrap_or_else(|_| panic!("no line with {marker}"))
}

/// Debian's `blender` on PATH, or None after a notice (a failure with
/// DIFFKFC_REQUIRE_BLENDER=1, which .ci/run sets).
pub fn blender() -> Option<PathBuf> {
    let found = std::env::var_os("PATH")
        .and_then(|p| std::env::split_paths(&p).map(|d| d.join("blender")).find(|b| b.is_file()));
    if found.is_none() {
        if std::env::var("DIFFKFC_REQUIRE_BLENDER").is_ok_and(|v| v == "1") {
            panic!("blender is not on PATH (apt-get install blender)");
        }
        eprintln!("SKIPPED: blender is not on PATH; the Blender checks are skipped");
    }
    found
}

pub type Frames = std::collections::HashMap<String, std::collections::HashMap<String, [f64; 3]>>;

/// Pose-bone heads (metres, Y up) of a BVH or `.glb` at `frames` (0-based), as Blender
/// imports it (scripts/blender_positions.py).
pub fn blender_positions(blender: &Path, bvh: &Path, frames: &[usize], dir: &Path) -> Frames {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/blender_positions.py");
    let out = dir.join(format!("{}.json", bvh.file_stem().unwrap().to_str().unwrap()));
    let list: Vec<String> = frames.iter().map(|f| f.to_string()).collect();
    let o = std::process::Command::new(blender)
        .args([
            "-b",
            "--factory-startup",
            "--python",
            s(&script),
            "--",
            s(bvh),
            &list.join(","),
            s(&out),
        ])
        .output()
        .expect("run blender");
    assert!(o.status.success() && out.exists(), "blender failed: {}{}", stdout(&o), stderr(&o));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    eprintln!("Blender {}", v["blender"]);
    serde_json::from_value(v["frames"].clone()).unwrap()
}

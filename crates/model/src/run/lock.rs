//! Claiming a run directory for a training: only a new or empty directory, or one that is
//! already a run (its marker file or checkpoints), is written; an exported model directory
//! never is; and one training at a time holds it (an OS file lock, released when the process
//! ends, however it ends).

use std::fs::{File, OpenOptions, TryLockError};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{ModelError, Result};
use crate::run::checkpoint::Checkpoint;

/// The file that marks a directory as a diffkfc run.
pub const MARKER: &str = diffkfc_data::io::ownership::Output::Run.marker();
/// The file a training holds locked while it writes the run.
pub const LOCK: &str = ".diffkfc-run.lock";
/// The weights file of an exported model directory (`diffkfc model export`).
const MODEL_WEIGHTS: &str = "model.safetensors";

/// A run directory held by this process until dropped.
#[derive(Debug)]
pub struct RunLock {
    pub path: PathBuf,
    _file: File,
}

/// What a training may do with `dir`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Claim {
    /// Start a new run (the directory is new or empty, or `force` was given).
    New { force: bool },
    /// Continue the run's newest checkpoint.
    Resume,
}

impl RunLock {
    /// Whether a training may write `dir` as `claim` says (before any work; `claim` checks again).
    pub fn check(dir: &Path, claim: Claim) -> Result<()> {
        check_claim(dir, claim)
    }

    /// Check that a training may write `dir` as `claim` says, create it, mark it and lock it.
    pub fn claim(dir: &Path, claim: Claim) -> Result<RunLock> {
        check_claim(dir, claim)?;
        std::fs::create_dir_all(dir).map_err(ModelError::io(dir))?;
        let marker = dir.join(MARKER);
        if !marker.exists() {
            diffkfc_data::write_atomic(&marker, b"a diffkfc training run\n")?;
        }
        let path = dir.join(LOCK);
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(&path)
            .map_err(ModelError::io(&path))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(&path).unwrap_or_default();
                return Err(ModelError::Refused(format!(
                    "--out: {} is being written by another training ({}); wait for it or choose another --out",
                    dir.display(),
                    holder.trim()
                )));
            }
            Err(TryLockError::Error(e)) => return Err(ModelError::io(&path)(e)),
        }
        let mut f = &file;
        let _ = f.set_len(0);
        let _ = writeln!(f, "pid {}", std::process::id());
        Ok(RunLock { path: dir.to_path_buf(), _file: file })
    }
}

/// Whether `dir` is a run: marked, or holding checkpoints (runs made before the marker).
pub fn is_run(dir: &Path) -> bool {
    dir.join(MARKER).exists() || !Checkpoint::list(dir).is_empty()
}

fn check_claim(dir: &Path, claim: Claim) -> Result<()> {
    let refuse = |why: String| Err(ModelError::Refused(why));
    if dir.exists() && !dir.is_dir() {
        return refuse(format!("--out: {} is a file, not a run directory", dir.display()));
    }
    if dir.join(MODEL_WEIGHTS).exists() && Checkpoint::list(dir).is_empty() {
        return refuse(format!("--out: {} is an exported model ({MODEL_WEIGHTS}); training writes run directories: choose another --out (start from the model with --init {})", dir.display(), dir.display()));
    }
    // Another kind of diffkfc output (an evaluator, samples, a report, a dataset).
    let force = matches!(claim, Claim::New { force: true });
    diffkfc_data::io::ownership::refuse_other_kind(dir, MARKER, force, "--out")?;
    let has_checkpoints = !Checkpoint::list(dir).is_empty();
    match claim {
        // A run killed before its first checkpoint: resuming it means starting it.
        Claim::Resume if !has_checkpoints && dir.join(MARKER).exists() => Ok(()),
        Claim::Resume if !has_checkpoints => refuse(format!(
            "--resume: {} {}; drop --resume to start a new run there",
            dir.display(),
            if dir.exists() { "is not a diffkfc run" } else { "does not exist" }
        )),
        Claim::Resume => Ok(()),
        Claim::New { .. } if has_checkpoints => refuse(format!("--out: {} already holds checkpoints; pass --resume to continue it or choose another --out", dir.display())),
        Claim::New { force } => {
            let foreign: Vec<String> = std::fs::read_dir(dir)
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n != MARKER && n != LOCK)
                .collect();
            if !force && !foreign.is_empty() && !dir.join(MARKER).exists() {
                let mut shown = foreign;
                shown.sort();
                shown.truncate(3);
                return refuse(format!("--out: {} is not empty ({}) and is not a diffkfc run; choose a new or empty directory, or pass --force to write the run's files (config.json, Mean.npy, Std.npy, metrics.jsonl, loss.svg, ckpt-*.safetensors) there", dir.display(), shown.join(", ")));
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_is_held_by_one_training_at_a_time() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("held");
        let first = RunLock::claim(&d, Claim::New { force: false }).unwrap();
        assert!(d.join(MARKER).exists());
        let second = RunLock::claim(&d, Claim::New { force: false }).unwrap_err().to_string();
        assert!(second.contains("being written by another training"), "{second}");
        drop(first);
        RunLock::claim(&d, Claim::New { force: false }).unwrap();
        // Killed before its first checkpoint: still a run, so resuming it is allowed.
        RunLock::claim(&d, Claim::Resume).unwrap();
    }

    #[test]
    fn foreign_files_models_and_missing_runs_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("foreign");
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("config.json"), "mine").unwrap();
        let e = RunLock::claim(&d, Claim::New { force: false }).unwrap_err().to_string();
        assert!(e.contains("not a diffkfc run") && e.contains("config.json"), "{e}");
        assert_eq!(std::fs::read_to_string(d.join("config.json")).unwrap(), "mine");
        RunLock::claim(&d, Claim::New { force: true }).unwrap();
        let m = tmp.path().join("model");
        std::fs::create_dir_all(&m).unwrap();
        std::fs::write(m.join(MODEL_WEIGHTS), "w").unwrap();
        for claim in [Claim::New { force: true }, Claim::Resume] {
            let e = RunLock::claim(&m, claim).unwrap_err().to_string();
            assert!(e.contains("exported model"), "{e}");
        }
        let e = RunLock::claim(&tmp.path().join("none"), Claim::Resume).unwrap_err().to_string();
        assert!(e.contains("--resume") && e.contains("does not exist"), "{e}");
    }
}

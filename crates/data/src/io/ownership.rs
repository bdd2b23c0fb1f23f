//! One ownership rule for every folder a command writes (`train`, `eval train-evaluator`,
//! `eval --out`, `model export`, `sample --out`, `data synth --out`): a command writes a folder
//! that is new, empty, or already holds its own kind of output. A folder holding another kind
//! of diffkfc output, or files diffkfc did not write, is refused with one line unless `--force`;
//! an exported model is never written over except by `model export`. Each kind marks its
//! folders with a file of its own; folders written before the markers are told by their files.

use std::path::Path;

use crate::DataError;

/// The kinds of folder diffkfc writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Output {
    Run,
    Model,
    Evaluator,
    Report,
    Samples,
    Dataset,
}

impl Output {
    pub const ALL: [Output; 6] = [
        Output::Run,
        Output::Model,
        Output::Evaluator,
        Output::Report,
        Output::Samples,
        Output::Dataset,
    ];

    /// The file that marks a folder of this kind.
    pub const fn marker(self) -> &'static str {
        match self {
            Output::Run => ".diffkfc-run",
            Output::Model => ".diffkfc-model",
            Output::Evaluator => ".diffkfc-evaluator",
            Output::Report => ".diffkfc-eval",
            Output::Samples => ".diffkfc-sample",
            Output::Dataset => ".diffkfc-dataset",
        }
    }

    /// What a user calls it, with the command that writes it.
    pub fn noun(self) -> &'static str {
        match self {
            Output::Run => "a training run (diffkfc train)",
            Output::Model => "an exported model (diffkfc model export)",
            Output::Evaluator => "a text-motion evaluator (diffkfc eval train-evaluator)",
            Output::Report => "an evaluation report (diffkfc eval)",
            Output::Samples => "samples (diffkfc sample)",
            Output::Dataset => "a dataset (diffkfc data synth)",
        }
    }

    /// Mark `dir` (which exists) as holding this kind.
    pub fn mark(self, dir: &Path) -> Result<(), DataError> {
        let m = dir.join(self.marker());
        if m.exists() {
            return Ok(());
        }
        crate::write_atomic(&m, b"written by diffkfc\n")
    }
}

/// The names in `dir`, sorted (none when it is missing or unreadable).
pub(crate) fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// The kind of diffkfc output `dir` holds: by its marker, or (folders written before the
/// markers) by the files each kind writes. None for a missing, empty or foreign folder.
pub fn found(dir: &Path) -> Option<Output> {
    if let Some(k) = Output::ALL.into_iter().find(|k| dir.join(k.marker()).exists()) {
        return Some(k);
    }
    let n = names(dir);
    let has = |name: &str| n.iter().any(|x| x == name);
    let ckpt = n.iter().any(|x| x.starts_with("ckpt-") && x.ends_with(".safetensors"));
    if has("model.safetensors") && has("config.json") && !ckpt {
        Some(Output::Model)
    } else if has("manifest.json") && has("new_joint_vecs") {
        Some(Output::Dataset)
    } else if has("report.json") && has("report.md") {
        Some(Output::Report)
    } else if has("results.json") && n.iter().any(|x| x.starts_with("sample_")) {
        Some(Output::Samples)
    } else if ckpt && has("config.json") {
        Some(Output::Run)
    } else if ckpt && has("report.json") {
        Some(Output::Evaluator)
    } else {
        None
    }
}

/// Whether `kind` may be written into `dir` (before any work): Ok(true) when `dir` is new,
/// empty or already `kind`, Ok(false) when it is foreign and `force` lets the command write its
/// own file names into it. `flag` names the option in messages. A run's lock file and every
/// marker do not count as content.
pub fn check(dir: &Path, kind: Output, force: bool, flag: &str) -> Result<bool, DataError> {
    if refuse_other_kind(dir, kind.marker(), force, flag)? {
        return Ok(true);
    }
    let content: Vec<String> = names(dir)
        .into_iter()
        .filter(|n| !n.ends_with(".lock") && !Output::ALL.iter().any(|k| k.marker() == n))
        .collect();
    if content.is_empty() {
        return Ok(true);
    }
    if !force {
        let shown: Vec<&str> = content.iter().take(3).map(String::as_str).collect();
        let more = if content.len() > 3 { ", ..." } else { "" };
        return Err(DataError::Invalid(format!(
            "{flag}: {} holds files diffkfc did not write ({}{more}); choose a new or empty folder, or pass --force to write into it anyway",
            dir.display(),
            shown.join(", ")
        )));
    }
    Ok(false)
}

/// The part of the rule about other kinds: Err for a file, an exported model (unless `marker`
/// is the model's) or another kind's folder without `force`; Ok(true) when `dir` already holds
/// the kind `marker` marks, Ok(false) otherwise (missing, empty, foreign, or forced).
pub fn refuse_other_kind(
    dir: &Path,
    marker: &str,
    force: bool,
    flag: &str,
) -> Result<bool, DataError> {
    let refuse = |why: String| Err(DataError::Invalid(format!("{flag}: {} {why}", dir.display())));
    if dir.exists() && !dir.is_dir() {
        return refuse("is a file, not a folder".into());
    }
    if dir.join(marker).exists() {
        return Ok(true);
    }
    let wanted = Output::ALL.into_iter().find(|k| k.marker() == marker);
    match found(dir) {
        Some(k) if k.marker() == marker => Ok(true),
        Some(Output::Model) => refuse(format!(
            "is {}; only `diffkfc model export` writes over it: choose another folder",
            Output::Model.noun()
        )),
        Some(k) if !force => refuse(format!(
            "holds {}{}; choose another folder, or pass --force to write into it anyway",
            k.noun(),
            wanted.map_or(String::new(), |w| format!(", not {}", w.noun()))
        )),
        _ => Ok(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_empty_and_own_folders_are_written() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        assert!(check(&d.join("new"), Output::Report, false, "--out").unwrap());
        assert!(check(d, Output::Report, false, "--out").unwrap());
        Output::Report.mark(d).unwrap();
        std::fs::write(d.join("report.json"), "{}").unwrap();
        assert!(check(d, Output::Report, false, "--out").unwrap());
        assert_eq!(found(d), Some(Output::Report));
    }

    #[test]
    fn another_kind_is_refused_unless_forced() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        Output::Run.mark(d).unwrap();
        std::fs::write(d.join("ckpt-00000010.safetensors"), "x").unwrap();
        let e = check(d, Output::Evaluator, false, "--out").unwrap_err().to_string();
        assert!(
            e.contains("holds a training run (diffkfc train), not a text-motion evaluator"),
            "{e}"
        );
        assert!(!e.contains('\n'));
        assert!(!check(d, Output::Evaluator, true, "--out").unwrap());
    }

    #[test]
    fn a_model_is_never_written_by_another_command() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        std::fs::write(d.join("model.safetensors"), "x").unwrap();
        std::fs::write(d.join("config.json"), "{}").unwrap();
        assert_eq!(found(d), Some(Output::Model));
        for kind in
            [Output::Run, Output::Evaluator, Output::Report, Output::Samples, Output::Dataset]
        {
            for force in [false, true] {
                let e = check(d, kind, force, "--out").unwrap_err().to_string();
                assert!(e.contains("is an exported model"), "{kind:?} {force}: {e}");
            }
        }
        assert!(check(d, Output::Model, false, "--out").unwrap());
    }

    #[test]
    fn foreign_files_are_refused_unless_forced() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        std::fs::write(d.join("notes.txt"), "mine").unwrap();
        let e = check(d, Output::Samples, false, "--out").unwrap_err().to_string();
        assert!(e.contains("holds files diffkfc did not write (notes.txt)"), "{e}");
        assert!(!check(d, Output::Samples, true, "--out").unwrap());
        // A file where a folder should be.
        let f = d.join("notes.txt");
        let e = check(&f, Output::Samples, true, "--out").unwrap_err().to_string();
        assert!(e.contains("is a file, not a folder"), "{e}");
    }

    #[test]
    fn folders_from_before_the_markers_are_recognised() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        for n in ["Mean.npy", "Std.npy", "ckpt-00000800.safetensors", "report.json"] {
            std::fs::write(d.join(n), "x").unwrap();
        }
        assert_eq!(found(d), Some(Output::Evaluator));
        std::fs::write(d.join("config.json"), "{}").unwrap();
        assert_eq!(found(d), Some(Output::Run));
    }
}

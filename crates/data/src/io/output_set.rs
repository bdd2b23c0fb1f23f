//! A folder of outputs written as one set: the new set is assembled in a hidden sibling
//! (`.NAME.partial<PID>`) and swapped in whole, so an interrupted or failed run leaves the
//! previous complete set or nothing, never a mix. Only folders we made (marked) or empty ones
//! are replaced; a user's files found inside are carried over; a folder that is not ours is
//! refused unless forced, and then only our file names are written into it.

use std::path::{Path, PathBuf};

use crate::io::atomic::remove_dead_leftovers;
use crate::io::ownership::names as entries;
use crate::DataError;

/// An output set being written (`ours` must accept "results.json": see `begin`).
pub struct OutputSet {
    dir: PathBuf,
    staging: PathBuf,
    marker: &'static str,
    ours: fn(&str) -> bool,
    /// Into a folder that is not ours (`--force`): our files are moved in one by one.
    merge: bool,
    committed: bool,
}

/// How the set went in.
#[derive(Debug, PartialEq, Eq)]
pub enum Committed {
    /// A new folder.
    Created,
    /// The previous set was replaced (a user's files in it kept).
    Replaced { kept: Vec<String> },
    /// Our files written into a folder that is not ours (`--force`).
    Merged,
}

fn io(p: &Path) -> impl Fn(std::io::Error) -> DataError + '_ {
    move |err| DataError::Io { path: p.to_path_buf(), err }
}

impl OutputSet {
    /// Start the set that will be `dir`. `marker` names the file that marks our folders;
    /// `ours(name)` says which file names the set writes. `flag` names the option for messages.
    pub fn begin(
        dir: &Path,
        marker: &'static str,
        ours: fn(&str) -> bool,
        force: bool,
        flag: &str,
    ) -> Result<OutputSet, DataError> {
        let merge = Self::check(dir, marker, ours, force, flag)?;
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        std::fs::create_dir_all(parent).map_err(io(parent))?;
        for tag in ["partial", "old"] {
            remove_dead_leftovers(parent, &format!(".{name}"), tag);
        }
        let staging = parent.join(format!(".{name}.partial{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&staging);
        std::fs::create_dir_all(&staging).map_err(io(&staging))?;
        crate::write_atomic(&staging.join(marker), b"written by diffkfc\n")?;
        Ok(OutputSet { dir: dir.to_path_buf(), staging, marker, ours, merge, committed: false })
    }

    /// Whether a set may go into `dir` (as `begin` would decide, before any work): Ok(true)
    /// when it would be merged into a folder that is not ours.
    pub fn check(
        dir: &Path,
        marker: &str,
        ours: fn(&str) -> bool,
        force: bool,
        flag: &str,
    ) -> Result<bool, DataError> {
        // Another kind of diffkfc output (a run, a model, ...) is not this set's to replace.
        crate::io::ownership::refuse_other_kind(dir, marker, force, flag)?;
        let present = entries(dir);
        // Folders written before the marker existed hold only our names, results.json among them.
        let legacy = present.iter().any(|n| n == "results.json") && present.iter().all(|n| ours(n));
        let merge = !present.is_empty() && !dir.join(marker).exists() && !legacy;
        if merge && !force {
            let shown: Vec<&str> = present.iter().take(3).map(String::as_str).collect();
            return Err(DataError::Invalid(format!("{flag}: {} holds files diffkfc did not write ({}{}); choose a new or empty folder, or pass --force to write only diffkfc's file names into it", dir.display(), shown.join(", "), if present.len() > 3 { ", ..." } else { "" })));
        }
        Ok(merge)
    }

    /// Where the set's files are written until `commit`.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// Swap the set in.
    pub fn commit(mut self) -> Result<Committed, DataError> {
        let done = if self.merge { self.merge_in()? } else { self.swap_in()? };
        self.committed = true;
        Ok(done)
    }

    fn merge_in(&self) -> Result<Committed, DataError> {
        for n in entries(&self.staging).into_iter().filter(|n| n != self.marker) {
            let to = self.dir.join(&n);
            std::fs::rename(self.staging.join(&n), &to).map_err(io(&to))?;
        }
        let _ = std::fs::remove_dir_all(&self.staging);
        Ok(Committed::Merged)
    }

    fn swap_in(&self) -> Result<Committed, DataError> {
        if !self.dir.exists() {
            std::fs::rename(&self.staging, &self.dir).map_err(io(&self.dir))?;
            return Ok(Committed::Created);
        }
        // A user's files in our folder (notes, renders) go with the new set.
        let kept: Vec<String> = entries(&self.dir)
            .into_iter()
            .filter(|n| n != self.marker && !(self.ours)(n))
            .collect();
        for n in &kept {
            let to = self.staging.join(n);
            std::fs::rename(self.dir.join(n), &to).map_err(io(&to))?;
        }
        let old = self.staging.with_file_name(
            self.staging
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .replace(".partial", ".old"),
        );
        std::fs::rename(&self.dir, &old).map_err(io(&self.dir))?;
        std::fs::rename(&self.staging, &self.dir).map_err(io(&self.dir))?;
        let _ = std::fs::remove_dir_all(&old);
        Ok(Committed::Replaced { kept })
    }
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARK: &str = ".test-set";

    fn ours(n: &str) -> bool {
        n.starts_with("sample_") || n == "results.json"
    }

    fn write(set: &OutputSet, files: &[&str]) {
        for f in files {
            std::fs::write(set.path().join(f), f).unwrap();
        }
    }

    #[test]
    fn a_set_replaces_the_previous_one_whole_and_keeps_user_files() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let set = OutputSet::begin(&out, MARK, ours, false, "--out").unwrap();
        write(&set, &["sample_00.npy", "sample_01.npy", "results.json"]);
        assert_eq!(set.commit().unwrap(), Committed::Created);
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let set = OutputSet::begin(&out, MARK, ours, false, "--out").unwrap();
        write(&set, &["sample_00.npy", "results.json"]);
        // Before the commit the folder still holds the previous complete set.
        assert!(out.join("sample_01.npy").exists());
        let done = set.commit().unwrap();
        assert_eq!(done, Committed::Replaced { kept: vec!["notes.txt".into()] });
        assert_eq!(entries(&out), [MARK, "notes.txt", "results.json", "sample_00.npy"]);
        assert!(
            entries(out.parent().unwrap()) == ["out"],
            "leftovers: {:?}",
            entries(out.parent().unwrap())
        );
    }

    #[test]
    fn a_failed_run_leaves_the_previous_set_and_no_partial() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let set = OutputSet::begin(&out, MARK, ours, false, "--out").unwrap();
        write(&set, &["sample_00.npy"]);
        set.commit().unwrap();
        let set = OutputSet::begin(&out, MARK, ours, false, "--out").unwrap();
        write(&set, &["sample_00.npy"]);
        std::fs::write(set.path().join("sample_00.npy"), "half").unwrap();
        drop(set);
        assert_eq!(std::fs::read_to_string(out.join("sample_00.npy")).unwrap(), "sample_00.npy");
        assert_eq!(entries(out.parent().unwrap()), ["out"]);
        // A dead process's partial folder is removed by the next run.
        let dead = out.with_file_name(".out.partial4194305");
        std::fs::create_dir_all(&dead).unwrap();
        drop(OutputSet::begin(&out, MARK, ours, false, "--out").unwrap());
        assert!(!dead.exists());
    }

    #[test]
    fn a_folder_that_is_not_ours_is_refused_or_merged_into() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("thesis.tex"), "mine").unwrap();
        std::fs::write(out.join("sample_05.npy"), "mine too").unwrap();
        let e = OutputSet::begin(&out, MARK, ours, false, "--out").err().unwrap().to_string();
        assert!(e.contains("thesis.tex") && e.contains("--force"), "{e}");
        // Files that look like ours in an unmarked folder are the user's too.
        let only = tmp.path().join("lookalike");
        std::fs::create_dir_all(&only).unwrap();
        std::fs::write(only.join("sample_05.npy"), "mine").unwrap();
        assert!(OutputSet::begin(&only, MARK, ours, false, "--out").is_err());
        let set = OutputSet::begin(&out, MARK, ours, true, "--out").unwrap();
        write(&set, &["sample_00.npy"]);
        assert_eq!(set.commit().unwrap(), Committed::Merged);
        assert_eq!(entries(&out), ["sample_00.npy", "sample_05.npy", "thesis.tex"]);
        assert_eq!(std::fs::read_to_string(out.join("sample_05.npy")).unwrap(), "mine too");
    }
}

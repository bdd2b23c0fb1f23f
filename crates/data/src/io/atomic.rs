//! Writing files so that an interrupted run never leaves a half-written one: every output of
//! diffkfc (arrays, checkpoints, pictures, reports) goes through here.

use std::io::Write;
use std::path::Path;

use crate::DataError;

/// Write bytes to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DataError> {
    let io = |e| DataError::Io { path: path.to_path_buf(), err: e };
    // The rename would replace a device node, FIFO or symlink (as root, `-o /dev/null` would
    // destroy /dev/null): only regular files are overwritten.
    if let Ok(m) = std::fs::symlink_metadata(path) {
        if !m.file_type().is_file() {
            let kind = if m.file_type().is_symlink() {
                "a symbolic link"
            } else if m.is_dir() {
                "a directory"
            } else {
                "a device, FIFO or socket"
            };
            return Err(DataError::Invalid(format!(
                "{}: is {kind}, not a regular file: refusing to replace it",
                path.display()
            )));
        }
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    // Named by process id (not tempfile's random names) so `remove_stale_temps` can tell a
    // dead writer's leftover from a live one's.
    let tmp = path.with_file_name(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}

/// Remove temporary files `<prefix>.tmp<PID>` in `dir` left by processes that no longer run
/// (a `kill -9` in the middle of a write). Files of live processes are left alone.
pub fn remove_stale_temps(dir: &Path, prefix: &str) {
    remove_dead_leftovers(dir, prefix, "tmp");
}

/// Remove files or directories `<prefix>.<tag><PID>` in `dir` whose process no longer runs:
/// what an interrupted writer left (temporary files, partial output folders).
pub fn remove_dead_leftovers(dir: &Path, prefix: &str, tag: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let me = std::process::id();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix(prefix)
            .and_then(|r| r.strip_prefix('.'))
            .and_then(|r| r.strip_prefix(tag))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != me && !Path::new(&format!("/proc/{pid}")).exists() {
            let p = e.path();
            let _ = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
        }
    }
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::FileTypeExt;
    use std::path::Path;

    #[test]
    fn only_regular_files_are_replaced() {
        let d = std::env::temp_dir().join(format!("diffkfc-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let target = d.join("target.txt");
        std::fs::write(&target, b"keep").unwrap();
        let link = d.join("link.txt");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = super::write_atomic(&link, b"new").unwrap_err().to_string();
        assert!(e.contains("link.txt") && e.contains("symbolic link"), "{e}");
        assert_eq!(std::fs::read(&target).unwrap(), b"keep");
        let e = super::write_atomic(Path::new("/dev/null"), b"x").unwrap_err().to_string();
        assert!(e.contains("/dev/null") && e.contains("not a regular file"), "{e}");
        assert!(std::fs::metadata("/dev/null").unwrap().file_type().is_char_device());
        super::write_atomic(&d.join("plain.txt"), b"ok").unwrap();
        super::write_atomic(&d.join("plain.txt"), b"ok2").unwrap();
        assert_eq!(std::fs::read(d.join("plain.txt")).unwrap(), b"ok2");
        std::fs::remove_dir_all(d).unwrap();
    }

    #[test]
    fn stale_temps_of_dead_processes_are_removed() {
        let d = std::env::temp_dir().join(format!("diffkfc-stale-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        // PID 4194305 is above Linux's pid_max limit: never a live process.
        let dead = d.join("train.f32.tmp4194305");
        let live = d.join(format!("train.f32.tmp{}", std::process::id()));
        let other = d.join("val.f32.tmp4194305");
        for p in [&dead, &live, &other] {
            std::fs::write(p, b"x").unwrap();
        }
        super::remove_stale_temps(&d, "train.f32");
        assert!(!dead.exists() && live.exists() && other.exists());
        std::fs::remove_dir_all(d).unwrap();
    }
}

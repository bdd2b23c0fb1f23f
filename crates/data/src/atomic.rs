//! Writing files so that an interrupted run never leaves a half-written one: every output of
//! diffkfc (arrays, checkpoints, pictures, reports) goes through here.

use std::io::Write;
use std::path::Path;

use crate::DataError;

/// Write bytes to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DataError> {
    let io = |e| DataError::Io { path: path.to_path_buf(), err: e };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
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
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let me = std::process::id();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name.strip_prefix(prefix).and_then(|r| r.strip_prefix(".tmp")).and_then(|p| p.parse::<u32>().ok()) else { continue };
        if pid != me && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

#[cfg(test)]
mod tests {
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

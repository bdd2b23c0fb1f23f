//! Where the shared golden fixtures live, for tests in every crate.
//!
//! `DIFFKFC_FIXTURES` names the directory; otherwise `../shared/fixtures` beside the workspace.
//! Tests that need fixtures call [`require`]: when they are absent it prints a notice and the
//! test skips, unless `DIFFKFC_REQUIRE_FIXTURES=1` (set by `.ci/run`) makes absence a failure.

use std::path::PathBuf;

/// The fixtures directory, if present.
pub fn dir() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("DIFFKFC_FIXTURES") {
        let p = PathBuf::from(p);
        return p.is_dir().then_some(p);
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/fixtures");
    root.is_dir().then(|| root.canonicalize().unwrap_or(root))
}

/// The path of a fixture file, or `None` (after a printed notice) when fixtures are absent.
/// Panics when absent and `DIFFKFC_REQUIRE_FIXTURES=1`.
pub fn require(rel: &str) -> Option<PathBuf> {
    let found = dir().map(|d| d.join(rel)).filter(|p| p.exists());
    if found.is_none() {
        if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") {
            panic!("fixture {rel} not found (DIFFKFC_REQUIRE_FIXTURES=1); set DIFFKFC_FIXTURES or put ../shared/fixtures beside the workspace");
        }
        eprintln!("SKIPPED: fixture {rel} not found (set DIFFKFC_FIXTURES to run this test)");
    }
    found
}

/// Run a Python script (with `args`) as an independent reference: `Some(stdout)`, or `None`
/// (after a printed notice) when `python3` with `modules` is not installed. Panics when absent
/// and `DIFFKFC_REQUIRE_PYTHON=1` (set by `.ci/run`, which installs numpy and scipy), and when
/// the script itself fails.
pub fn python(modules: &[&str], script: &str, args: &[&std::path::Path]) -> Option<String> {
    let probe = format!("import {}", modules.join(", "));
    let have = std::process::Command::new("python3")
        .args(["-c", &probe])
        .output()
        .is_ok_and(|o| o.status.success());
    if !have {
        if std::env::var("DIFFKFC_REQUIRE_PYTHON").is_ok_and(|v| v == "1") {
            panic!("python3 with {} not found (DIFFKFC_REQUIRE_PYTHON=1)", modules.join(", "));
        }
        eprintln!("SKIPPED: python3 with {} not found", modules.join(", "));
        return None;
    }
    let o = std::process::Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 runs");
    assert!(o.status.success(), "python reference failed: {}", String::from_utf8_lossy(&o.stderr));
    Some(String::from_utf8(o.stdout).expect("utf-8"))
}

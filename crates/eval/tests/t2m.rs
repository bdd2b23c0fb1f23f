//! The T2M evaluator (`diffkfc_eval::t2m`) against an independent PyTorch implementation of its
//! modules (`scripts/t2m_reference.py`): a small evaluator with random weights in the original
//! `finest.tar` layout, converted by `scripts/convert-t2m-evaluator.py`, embeds real HumanML3D
//! fixture motions (four lengths, so packing matters) and four captions (a VIP word, an unknown
//! word, one past 20 tokens) as PyTorch does, within 1e-5; the same inputs embedded by the
//! official modules of Guo et al. (`scripts/t2m_official_reference.py`, recorded in
//! `tests/t2m/official/`) agree as closely. The recorded copy (`tests/t2m/`) is checked always; where a Python with torch is found (`DIFFKFC_TORCH_PYTHON`,
//! else `python3`), the script is run afresh as well.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use diffkfc_data::{io::npy, io::texts, testing::fixtures};
use diffkfc_eval::evaluator::TextMotionEvaluator;
use diffkfc_eval::t2m::T2mEvaluator;

/// Largest difference between diffkfc's embeddings and the reference's (`expected_*.npy` in
/// `expected`, inputs in `dir`), or None without fixtures.
fn check(dir: &Path, expected: &Path) -> Option<f32> {
    let (captions, errs) = texts::parse_file(&dir.join("captions.txt")).unwrap();
    assert!(errs.is_empty(), "{errs:?}");
    let device = Device::flex();
    let ev = T2mEvaluator::load(&dir.join("converted"), &captions, &device).unwrap();
    let mut motions = Vec::new();
    for k in 0.. {
        let Ok(spec) = std::fs::read_to_string(dir.join(format!("motions/{k}.txt"))) else {
            break;
        };
        let f: Vec<&str> = spec.split_whitespace().collect();
        let (start, frames): (usize, usize) = (f[1].parse().unwrap(), f[2].parse().unwrap());
        let m = npy::read_f32(fixtures::require(f[0])?).unwrap().data;
        let len = frames / 4 * 4;
        motions.push(m[start * 263..(start + len) * 263].to_vec());
    }
    let got_m = ev.embed_motions(&motions.iter().map(Vec::as_slice).collect::<Vec<_>>());
    let texts: Vec<&str> = captions.iter().map(|c| c.text.as_str()).collect();
    let got_t = ev.embed_texts(&texts).unwrap();
    let mut worst = 0f32;
    for (got, file) in [(got_m, "expected_motion.npy"), (got_t, "expected_text.npy")] {
        let want = npy::read_f32(expected.join(file)).unwrap();
        assert_eq!(want.shape, [got.len(), got[0].len()], "{file}");
        for (g, w) in got.iter().flatten().zip(&want.data) {
            worst = worst.max((*g as f32 - w).abs());
        }
    }
    Some(worst)
}

/// Every motion is zero-padded to 196 frames as the official loaders do: padding to the batch's
/// longest motion (176 frames here) moves that motion's embedding by about 0.1.
const TOLERANCE: f32 = 1e-5;

#[test]
fn embeddings_match_pytorch() {
    let recorded = std::env::var_os("DIFFKFC_T2M_RECORDED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/t2m"));
    let Some(e) = check(&recorded, &recorded) else {
        return;
    };
    eprintln!("recorded reference: largest difference {e:.2e}");
    assert!(e < TOLERANCE, "t2m embeddings differ from PyTorch's by {e}");
    // The same inputs through the official modules (scripts/t2m_official_reference.py).
    let e = check(&recorded, &recorded.join("official")).unwrap();
    eprintln!("official modules: largest difference {e:.2e}");
    assert!(e < TOLERANCE, "t2m embeddings differ from the official modules' by {e}");
    let python = std::env::var("DIFFKFC_TORCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let has_torch = std::process::Command::new(&python)
        .args(["-c", "import torch, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_torch {
        eprintln!("NOTICE: no Python with torch ({python}); checked against the recorded reference only (set DIFFKFC_TORCH_PYTHON to run scripts/t2m_reference.py afresh)");
        return;
    }
    let fresh: PathBuf = std::env::temp_dir().join(format!("diffkfc-t2m-{}", std::process::id()));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/t2m_reference.py");
    let o = std::process::Command::new(&python)
        .arg(&script)
        .args(["record", fresh.to_str().unwrap(), "--fixtures"])
        .arg(fixtures::dir().expect("fixtures were found above"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let e = check(&fresh, &fresh).unwrap();
    eprintln!("fresh PyTorch run: largest difference {e:.2e}");
    assert!(e < TOLERANCE, "t2m embeddings differ from a fresh PyTorch run by {e}");
    std::fs::remove_dir_all(fresh).unwrap();
}

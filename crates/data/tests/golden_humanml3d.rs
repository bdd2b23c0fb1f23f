//! Golden tests of the motion representation against real HumanML3D data
//! (`../shared/fixtures/humanml3d`, produced by HumanML3D's own reference code).

use diffkfc_data::motion::representation::{self as rep, Layout};
use diffkfc_data::{io::npy, testing::fixtures, T2M};

fn load(rel: &str) -> Option<npy::Array<f64>> {
    fixtures::require(&format!("humanml3d/{rel}")).map(|p| npy::read_f64(p).unwrap())
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Max |a - b| per feature group over rows of width 263.
fn group_errors(a: &[f64], b: &[f64]) -> Vec<(&'static str, f64)> {
    let layout = Layout::of(&T2M);
    let dim = layout.dim();
    layout
        .groups()
        .into_iter()
        .map(|(name, range)| {
            let mut m = 0.0f64;
            for (ra, rb) in a.chunks(dim).zip(b.chunks(dim)) {
                for k in range.clone() {
                    m = m.max((ra[k] - rb[k]).abs());
                }
            }
            (name, m)
        })
        .collect()
}

fn flat(j: &rep::Joints) -> Vec<f64> {
    j.iter().flatten().flatten().copied().collect()
}

#[test]
fn recover_from_ric_matches_released_joints() {
    let (Some(feats), Some(joints)) =
        (load("new_joint_vecs/012314.npy"), load("new_joints/012314.npy"))
    else {
        return;
    };
    assert_eq!(feats.shape, vec![170, 263]);
    let rec = rep::recover_from_ric(&T2M, &feats.data);
    let err = max_abs_diff(&flat(&rec), &joints.data);
    eprintln!("recover_from_ric(012314) max abs error vs new_joints: {err:.3e}");
    assert!(err < 1e-5, "{err}");
}

#[test]
fn process_file_matches_released_features() {
    let (Some(feats), Some(joints)) =
        (load("new_joint_vecs/012314.npy"), load("new_joints/012314.npy"))
    else {
        return;
    };
    let j = rep::joints_from_array(&joints.data, 170, 22, 22);
    let out: Vec<f64> =
        rep::features_from_joints(&T2M, &j, 0.002).unwrap().iter().map(|&v| v as f64).collect();
    assert_eq!(out.len(), 169 * 263);
    // Tolerances of the fixtures README (HumanML3D's own code re-run on new_joints), with headroom
    // of 1.5x for float32 vs float64 arithmetic.
    let tol = [3.0e-4, 1.4e-4, 3.5e-5, 6.7e-3, 1.3e-2, 4.1e-4, 0.0];
    for ((name, e), t) in group_errors(&out, &feats.data[..169 * 263]).into_iter().zip(tol) {
        eprintln!("process_file(012314) {name}: max abs error {e:.3e} (reference re-run: {t:.1e})");
        assert!(e <= t * 1.5 + 1e-6, "{name}: {e} > {t}");
    }
}

#[test]
fn process_file_from_raw_mocap_matches_reference() {
    let (Some(raw), Some(reff), Some(refj)) = (
        load("000021.npy"),
        load("000021_features_reference.npy"),
        load("000021_joints_reference.npy"),
    ) else {
        return;
    };
    assert_eq!(raw.shape, vec![180, 52, 3]);
    let j = rep::joints_from_array(&raw.data, 180, 52, 22);
    let out: Vec<f64> =
        rep::features_from_joints(&T2M, &j, 0.002).unwrap().iter().map(|&v| v as f64).collect();
    assert_eq!(out.len(), reff.data.len());
    for (name, e) in group_errors(&out, &reff.data) {
        eprintln!("process_file(000021) {name}: max abs error {e:.3e}");
        // The issue asks for 1e-3; we hold 1e-4 (measured: 2.1e-5 at worst, in the 6D rotations).
        assert!(e < 1e-4, "{name}: {e}");
    }
    let rec = rep::recover_from_ric(&T2M, &out);
    let err = max_abs_diff(&flat(&rec), &refj.data);
    eprintln!(
        "recover_from_ric(process_file(000021)) max abs error vs reference joints: {err:.3e}"
    );
    assert!(err < 1e-4, "{err}");
}

#[test]
fn target_lengths_match_000021() {
    let Some(raw) = load("000021.npy") else {
        return;
    };
    let j = rep::joints_from_array(&raw.data, 1, 52, 22);
    let offs = rep::bone_offsets(&T2M, &j[0]);
    let want = T2M.target_offsets().unwrap();
    for (a, b) in offs.iter().zip(&want) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-8, "{a:?} vs {b:?}");
        }
    }
}

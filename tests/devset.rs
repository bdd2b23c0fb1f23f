//! `scripts/devset.py`, the real dev set: the DeepMimic clips of PyPI's pybullet wheel through
//! our forward kinematics and HumanML3D's processing, beside the fixture clips. Needs numpy and
//! PyPI (skips with a notice where either is missing, unless DIFFKFC_REQUIRE_PYTHON=1).

mod common;

use common::*;
use std::path::Path;
use std::process::Command;

#[test]
fn the_dev_set_is_rigid_and_reads_as_a_dataset() {
    if diffkfc_data::testing::fixtures::python(&["numpy"], "", &[]).is_none()
        || diffkfc_data::testing::fixtures::require("humanml3d/Mean.npy").is_none()
    {
        return;
    }
    let dir = scratch("devset");
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/devset.py");
    let out = dir.join("devset");
    let o = Command::new("python3")
        .arg(&py)
        .args([s(&out), "--bin", env!("CARGO_BIN_EXE_diffkfc")])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    if !o.status.success()
        && err.contains("pip download")
        && std::env::var("DIFFKFC_REQUIRE_PYTHON").is_err()
    {
        eprintln!("SKIPPED: {err}");
        return;
    }
    assert!(o.status.success(), "{err}");
    let ids = std::fs::read_to_string(out.join("test.txt")).unwrap();
    assert_eq!(ids.lines().count(), 22, "{ids}");
    // Bones rigid in our forward kinematics and in the joints recovered from the features.
    let o = Command::new("python3").arg(&py).args(["--check", s(&out)]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The folder is a dataset the binary reads; a second build into it is refused.
    let o = diffkfc(&[
        "data",
        "joints",
        s(&out.join("new_joint_vecs/humanoid3d_walk.npy")),
        "-o",
        s(&dir.join("walk.npy")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let walk = diffkfc_data::io::npy::read_f32(dir.join("walk.npy")).unwrap();
    let (t, d) = (walk.shape[0], 66);
    let root = |f: usize| [walk.data[f * d] as f64, walk.data[f * d + 2] as f64];
    let speed = (1..t)
        .map(|f| (root(f)[0] - root(f - 1)[0]).hypot(root(f)[1] - root(f - 1)[1]))
        .sum::<f64>()
        * 20.0
        / (t - 1) as f64;
    // DeepMimic's walk covers about 1 m/s (its root, before HumanML3D's retargeting).
    assert!((0.7..1.3).contains(&speed), "walk speed {speed}");
    let o = Command::new("python3")
        .arg(&py)
        .args([s(&out), "--bin", env!("CARGO_BIN_EXE_diffkfc")])
        .output()
        .unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("not empty"));
}

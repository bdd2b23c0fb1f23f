//! Round trips of the motion representation on synthetic rigid motions: random smooth joint
//! rotations and root paths on the target skeleton, built by forward kinematics.

use diffkfc_data::motion::quat::{self, Vec3};
use diffkfc_data::motion::representation::{self as rep, Layout};
use diffkfc_data::{Skeleton, KIT, T2M};
use rand::{rngs::StdRng, Rng, SeedableRng};

/// A random smooth motion of `t` frames on the t2m target skeleton.
fn random_motion(seed: u64, t: usize) -> rep::Joints {
    random_motion_on(&T2M, &T2M.target_offsets().unwrap(), 1.0, seed, t)
}

/// A random smooth motion of `t` frames on `skel` with bone vectors `offsets`; `unit` is the
/// skeleton's length unit per metre (1000 for KIT-ML's millimetres).
fn random_motion_on(
    skel: &Skeleton,
    offsets: &[Vec3],
    unit: f64,
    seed: u64,
    t: usize,
) -> rep::Joints {
    let mut rng = StdRng::seed_from_u64(seed);
    let jn = skel.num_joints();
    // Per joint: rotation axis, amplitude, frequency, phase.
    let params: Vec<(Vec3, f64, f64, f64)> = (0..jn)
        .map(|_| {
            let axis =
                [rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5];
            (
                axis,
                rng.random::<f64>() * 0.6,
                0.5 + rng.random::<f64>() * 2.0,
                rng.random::<f64>() * 6.0,
            )
        })
        .collect();
    let yaw0 = rng.random::<f64>() * std::f64::consts::TAU;
    // Up to 0.2 rad/s: over the 161-frame smoothing window of the facing direction a faster
    // spin averages towards zero and makes the representation itself ill-conditioned.
    let yaw_rate = (rng.random::<f64>() - 0.5) * 0.4;
    let speed = [rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5];
    let mut rots = Vec::new();
    let mut root = Vec::new();
    for f in 0..t {
        let s = f as f64 / 20.0;
        let mut q: Vec<_> = params
            .iter()
            .map(|(axis, amp, freq, ph)| quat::from_axis_angle(*axis, amp * (freq * s + ph).sin()))
            .collect();
        q[0] = quat::qmul(quat::from_axis_angle([0.0, 1.0, 0.0], yaw0 + yaw_rate * s), q[0]);
        rots.push(q);
        root.push(quat::scale(
            [speed[0] * s + 0.1 * (2.0 * s).sin(), 0.95 + 0.05 * (3.0 * s).cos(), speed[1] * s],
            unit,
        ));
    }
    rep::forward_kinematics(skel, &rots, &root, offsets)
}

/// KIT-ML through HumanML3D's conversion rules, retargeted to a reference pose's bones as its
/// KIT processing does (the target skeleton is a clip's first frame): the features recover the
/// motion's shape on the reference's bone lengths, in millimetres.
#[test]
fn kit_motions_retarget_to_a_reference_skeleton() {
    // Adult proportions in millimetres along KIT's raw offset directions.
    let lengths = [
        0.0, 120.0, 230.0, 230.0, 160.0, 190.0, 290.0, 250.0, 190.0, 290.0, 250.0, 95.0, 420.0,
        410.0, 110.0, 60.0, 95.0, 420.0, 410.0, 110.0, 60.0,
    ];
    let offsets: Vec<Vec3> =
        KIT.raw_offsets.iter().zip(lengths).map(|(d, l)| quat::scale(*d, l)).collect();
    let j = random_motion_on(&KIT, &offsets, 1000.0, 3, 100);
    // Retargeted to its own first frame: the shape is kept.
    let own = rep::bone_lengths(&KIT, &j[0]);
    for (a, b) in own.iter().zip(lengths) {
        assert!((a - b).abs() < 1e-6, "{own:?}");
    }
    let feats = rep::features_from_joints_to(&KIT, &j, 0.002 * 1e6, Some(&own)).unwrap();
    assert_eq!(feats.len(), 99 * KIT.feature_dim());
    let rec = rep::recover_from_ric(&KIT, &feats.iter().map(|&v| v as f64).collect::<Vec<_>>());
    let mut worst = 0.0f64;
    for f in 0..99 {
        for a in 0..21 {
            for b in 0..21 {
                let d0 = quat::norm(quat::sub(j[f][a], j[f][b]));
                let d1 = quat::norm(quat::sub(rec[f][a], rec[f][b]));
                worst = worst.max((d0 - d1).abs());
            }
        }
    }
    eprintln!("KIT: joints -> features -> joints max distance error {worst:.2e} mm");
    assert!(worst < 0.1, "{worst} mm");
    // Onto a reference 10% larger: every bone of the result has the reference's length.
    let big: Vec<f64> = own.iter().map(|l| l * 1.1).collect();
    let feats = rep::features_from_joints_to(&KIT, &j, 0.002 * 1e6, Some(&big)).unwrap();
    let rec = rep::recover_from_ric(&KIT, &feats.iter().map(|&v| v as f64).collect::<Vec<_>>());
    for f in [0, 50, 98] {
        let got = rep::bone_lengths(&KIT, &rec[f]);
        for (g, w) in got.iter().zip(&big) {
            assert!((g - w).abs() < 0.05, "frame {f}: {got:?} vs {big:?}");
        }
    }
    // Without a reference KIT has no target: the error says how to give one.
    let e = rep::features_from_joints(&KIT, &j, 2000.0).unwrap_err().to_string();
    assert!(e.contains("--target-skeleton"), "{e}");
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn joints_features_joints_recovers_positions() {
    for seed in 0..5 {
        let j = random_motion(seed, 120);
        let feats = rep::features_from_joints(&T2M, &j, rep::FOOT_CONTACT_THRESHOLD).unwrap();
        let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
        let rec = rep::recover_from_ric(&T2M, &f64s);
        assert_eq!(rec.len(), 119);
        // The recovered motion is the input put on the floor, at the origin, facing +Z: the
        // same shape, so all pairwise joint distances and per-frame displacements agree.
        let mut worst = 0.0f64;
        for f in 0..119 {
            for a in 0..22 {
                for b in 0..22 {
                    let d0 = quat::norm(quat::sub(j[f][a], j[f][b]));
                    let d1 = quat::norm(quat::sub(rec[f][a], rec[f][b]));
                    worst = worst.max((d0 - d1).abs());
                }
                if f > 0 {
                    let v0 = quat::norm(quat::sub(j[f][a], j[f - 1][a]));
                    let v1 = quat::norm(quat::sub(rec[f][a], rec[f - 1][a]));
                    worst = worst.max((v0 - v1).abs());
                }
            }
        }
        eprintln!("seed {seed}: joints -> features -> joints max distance error {worst:.2e}");
        assert!(worst < 1e-4, "seed {seed}: {worst}");
        // And it faces +Z at frame 0 with the root above the origin.
        assert!(rec[0][0][0].abs() < 1e-5 && rec[0][0][2].abs() < 1e-5);
    }
}

#[test]
fn features_joints_features_is_stable() {
    let layout = Layout::of(&T2M);
    for seed in 10..15 {
        let j = random_motion(seed, 200);
        let f1 = rep::features_from_joints(&T2M, &j, rep::FOOT_CONTACT_THRESHOLD).unwrap();
        let rec = rep::recover_from_ric(&T2M, &f1.iter().map(|&v| v as f64).collect::<Vec<_>>());
        let f2 = rep::features_from_joints(&T2M, &rec, rep::FOOT_CONTACT_THRESHOLD).unwrap();
        let dim = layout.dim();
        // Compare away from the last 80 frames, where the facing smoothing (sigma 20, radius
        // 80) sees the one frame that recovery cannot return.
        let n = 199 - 1 - 81;
        for (name, range) in layout.groups() {
            let a: Vec<f32> = (0..n).flat_map(|f| f1[f * dim..][range.clone()].to_vec()).collect();
            let b: Vec<f32> = (0..n).flat_map(|f| f2[f * dim..][range.clone()].to_vec()).collect();
            let e = max_diff(&a, &b);
            eprintln!("seed {seed} {name}: features -> joints -> features max error {e:.2e}");
            // Measured: 1.3e-6 at worst (6D rotations).
            assert!(e < 1e-5, "seed {seed} {name}: {e}");
        }
    }
}

//! Motions and checks the foot post-processes' tests share.

use crate::motion::quat;
use crate::motion::representation::Joints;
use crate::T2M;

/// 40 frames of a body whose pelvis (and every joint but the feet) moves forward along +Z at
/// `pelvis_mps`, its left toe doing `left(f)` (its ankle 8 cm above and 12 cm behind it), its
/// right foot at rest on the floor.
pub fn feet_motion(pelvis_mps: f64, left: impl Fn(usize) -> [f64; 3]) -> Joints {
    (0..40)
        .map(|f| {
            let mut p = vec![[0.0, 0.9, pelvis_mps * f as f64 / 20.0]; 22];
            let l = left(f);
            p[T2M.feet_left[1]] = l;
            p[T2M.feet_left[0]] = [l[0], l[1] + 0.08, l[2] - 0.12];
            p[T2M.feet_right[1]] = [-0.1, 0.0, 0.05];
            p[T2M.feet_right[0]] = [-0.1, 0.08, -0.07];
            p
        })
        .collect()
}

/// Panics unless an edited motion kept what leg edits must keep: every leg bone's length within
/// 1e-4 m of the unedited motion's on every frame, and the feature rows (`dim` wide) of the
/// `keys` frames bit for bit.
pub fn assert_legs_and_keys_kept(
    (after, before): (&Joints, &Joints),
    (edited, unedited): (&[f32], &[f32]),
    dim: usize,
    keys: &[usize],
) {
    for (f, (a, b)) in after.iter().zip(before).enumerate() {
        for (p, c) in [(1usize, 4usize), (4, 7), (2, 5), (5, 8), (7, 10), (8, 11)] {
            let l = |j: &Vec<quat::Vec3>| quat::norm(quat::sub(j[c], j[p]));
            assert!((l(a) - l(b)).abs() < 1e-4, "frame {f}: bone {p}-{c}");
        }
    }
    for &k in keys {
        assert_eq!(edited[k * dim..(k + 1) * dim], unedited[k * dim..(k + 1) * dim], "key {k}");
    }
}

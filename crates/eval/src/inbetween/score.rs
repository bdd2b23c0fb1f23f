//! What the in-betweening benchmark measures of one motion against the clip it was keyed from:
//! the joint error on the frames between keys (global, and root-relative: each frame's joints
//! minus its pelvis), how far the root stands from the keyed places, and the realism numbers
//! (foot skating, planted share, K-TranS) that interpolation gives up.

use diffkfc_data::motion::plausibility::foot_skating_ratio;
use diffkfc_data::motion::quat;
use diffkfc_data::motion::representation::Joints;
use diffkfc_data::motion::skeleton::Skeleton;
use serde::Serialize;

use crate::gait::planted_share;
use crate::keyframe_metrics::{k_err_global, k_trans};

/// Half window of K-TranS (the paper's setting).
pub const K_TRANS_WINDOW: usize = 2;

/// One motion's numbers (metres, shares, metres per frame²).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Scores {
    /// Mean L2 joint error over the frames that are not keys, every joint.
    pub error_m: f64,
    /// The same with each frame's pelvis subtracted (the pelvis itself left out).
    pub error_local_m: f64,
    /// Mean ground distance of the root from the clip's at the keyed frames.
    pub key_place_m: f64,
    pub foot_skating: f64,
    pub planted_share: f64,
    pub k_trans: f64,
}

/// The scores of `motion` against `truth` (the same length) keyed at `keys`.
pub fn score(skel: &Skeleton, motion: &Joints, truth: &Joints, keys: &[usize]) -> Scores {
    let t = motion.len().min(truth.len());
    let between: Vec<usize> = (0..t).filter(|f| !keys.contains(f)).collect();
    let joints: Vec<usize> = (0..skel.num_joints()).collect();
    let global = k_err_global(motion, truth, &between, &joints).unwrap_or(0.0);
    // Root-relative: each frame's joints minus its pelvis, the pelvis itself left out.
    let relative = |j: &Joints| -> Joints {
        j.iter().map(|p| p.iter().map(|&q| quat::sub(q, p[0])).collect()).collect()
    };
    let local =
        k_err_global(&relative(motion), &relative(truth), &between, &joints[1..]).unwrap_or(0.0);
    let keyed: Vec<usize> = keys.iter().copied().filter(|&f| f < t).collect();
    let place: f64 = keyed
        .iter()
        .map(|&f| (motion[f][0][0] - truth[f][0][0]).hypot(motion[f][0][2] - truth[f][0][2]))
        .sum();
    let unit = skel.metres_per_unit;
    Scores {
        error_m: global * unit,
        error_local_m: local * unit,
        key_place_m: place / keyed.len().max(1) as f64 * unit,
        foot_skating: foot_skating_ratio(skel, motion),
        planted_share: planted_share(skel, motion),
        k_trans: k_trans(motion, &keyed, K_TRANS_WINDOW).unwrap_or(0.0) * unit,
    }
}

/// Linear interpolation of every joint's position between consecutive keys (the frames before
/// the first key hold it, as do those after the last).
pub fn interpolate(truth: &Joints, keys: &[usize]) -> Joints {
    let t = truth.len();
    let keys: Vec<usize> = keys.iter().copied().filter(|&f| f < t).collect();
    let (Some(&first), Some(&last)) = (keys.first(), keys.last()) else {
        return truth.clone();
    };
    (0..t)
        .map(|f| {
            if f <= first {
                return truth[first].clone();
            }
            if f >= last {
                return truth[last].clone();
            }
            let i = keys.partition_point(|&k| k <= f) - 1;
            let (a, b) = (keys[i], keys[i + 1]);
            let w = (f - a) as f64 / (b - a) as f64;
            truth[a]
                .iter()
                .zip(&truth[b])
                .map(|(p, q)| [0, 1, 2].map(|k| p[k] + w * (q[k] - p[k])))
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::T2M;

    /// A walk at constant velocity: every joint moves 5 cm a frame along +Z, feet lifted.
    fn constant_walk(t: usize) -> Joints {
        (0..t)
            .map(|f| {
                (0..22).map(|j| [0.1 * j as f64, 0.5 + 0.02 * j as f64, 0.05 * f as f64]).collect()
            })
            .collect()
    }

    #[test]
    fn keyed_on_every_frame_gives_zero_error() {
        let clip = constant_walk(40);
        let keys: Vec<usize> = (0..40).collect();
        let s = score(&T2M, &interpolate(&clip, &keys), &clip, &keys);
        assert_eq!((s.error_m, s.error_local_m, s.key_place_m), (0.0, 0.0, 0.0));
    }

    #[test]
    fn interpolating_a_constant_velocity_walk_is_exact() {
        let clip = constant_walk(61);
        let keys = [0, 20, 40, 60];
        let s = score(&T2M, &interpolate(&clip, &keys), &clip, &keys);
        assert!(s.error_m < 1e-12 && s.error_local_m < 1e-12, "{s:?}");
        assert!(s.k_trans < 1e-12);
    }

    #[test]
    fn a_known_offset_between_keys() {
        // Shift every joint of the frames between keys 0 and 10 by 3-4-5 cm: the global error
        // is 5 cm on 9 of the 19 frames between keys; root-relative nothing moved.
        let clip = constant_walk(21);
        let mut m = clip.clone();
        for p in m.iter_mut().take(10).skip(1) {
            p.iter_mut().for_each(|j| {
                j[0] += 0.03;
                j[2] += 0.04;
            });
        }
        let s = score(&T2M, &m, &clip, &[0, 10, 20]);
        assert!((s.error_m - 0.05 * 9.0 / 18.0).abs() < 1e-12, "{s:?}");
        assert!(s.error_local_m < 1e-12);
        assert_eq!(s.key_place_m, 0.0);
        // A keyed place 1 m off, at one of three keys.
        m[20][0][0] += 1.0;
        assert!((score(&T2M, &m, &clip, &[0, 10, 20]).key_place_m - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn interpolation_holds_outside_the_keys() {
        let clip = constant_walk(10);
        let i = interpolate(&clip, &[3, 6]);
        assert_eq!(i[0], clip[3]);
        assert_eq!(i[9], clip[6]);
        assert!((i[4][0][2] - clip[4][0][2]).abs() < 1e-12);
        assert_eq!(interpolate(&clip, &[]), clip);
    }
}

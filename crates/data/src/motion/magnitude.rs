//! One rule for the size of the motion values a user hands us (feature files, joint files,
//! BVH imports, keyframe poses): values a broken exporter or a unit mix-up writes are refused
//! with the limit in the message, before they become non-finite or kilometre-scale joints.

use crate::motion::quat;
use crate::motion::representation::{Joints, Layout};
use crate::motion::skeleton::Skeleton;

/// Farthest a joint may be from the origin (m): a motion of 1 km is a broken file.
pub const MAX_POSITION_M: f64 = 1000.0;
/// Leg lengths (hip to ankle through the root, m) that a human (child to giant) has.
pub const LEG_RANGE_M: (f64, f64) = (0.2, 3.0);
/// Feature limits, in metres where they are lengths: root yaw rate (rad per frame), root step
/// (m per frame: 40 m/s at 20 fps), root height, and every other channel (root-relative
/// positions, rotation 6D values, joint steps, contacts).
const MAX_YAW_RATE: f64 = std::f64::consts::PI;
const MAX_ROOT_STEP_M: f64 = 2.0;
const MAX_HEIGHT_M: f64 = 10.0;
const MAX_OTHER: f64 = 100.0;

/// Why a motion's values are out of a human's range (the messages users see).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MagnitudeError {
    #[error("frame {frame}, joint {joint} is {metres:.3e} m from the origin; positions must be finite and within {MAX_POSITION_M} m")]
    Position { frame: usize, joint: usize, metres: f64 },
    #[error("a pose needs {want} joints, got {got} (frame {frame})")]
    JointCount { want: usize, got: usize, frame: usize },
    #[error("the leg (ankle to root) is {metres:.3} m long; a human's is {lo} to {hi} m, in metres{unit}", lo = LEG_RANGE_M.0, hi = LEG_RANGE_M.1)]
    Leg {
        metres: f64,
        /// "; the positions look like millimetres (divide by 1000)" or empty.
        unit: String,
    },
    #[error("frame {frame}, feature {feature} ({what}) is {value}; it must be finite and at most {max} in size")]
    Feature { frame: usize, feature: usize, what: &'static str, value: f32, max: f64 },
}

/// Whether `x` is finite and at most `max` in size.
pub fn within(x: f64, max: f64) -> bool {
    x.is_finite() && x.abs() <= max
}

/// The bones (joint, parent) of the left leg, from the ankle up to the root.
fn leg_bones(skel: &Skeleton) -> Vec<(usize, usize)> {
    let parents = skel.parents();
    let (mut j, mut bones) = (skel.feet_left[0], Vec::new());
    while parents[j] >= 0 {
        bones.push((j, parents[j] as usize));
        j = parents[j] as usize;
    }
    bones
}

/// Joint positions within [`MAX_POSITION_M`] of the origin; the error names the frame and joint.
pub fn check_positions(skel: &Skeleton, j: &Joints) -> Result<(), MagnitudeError> {
    let mpu = skel.metres_per_unit;
    for (f, frame) in j.iter().enumerate() {
        if let Some(k) = frame.iter().position(|p| !within(quat::norm(*p) * mpu, MAX_POSITION_M)) {
            let metres = quat::norm(frame[k]) * mpu;
            return Err(MagnitudeError::Position { frame: f, joint: k, metres });
        }
    }
    Ok(())
}

/// Joint positions a user gives: within [`MAX_POSITION_M`] of the origin and with a human's leg
/// length; the error says which frame and joint, or which unit the positions look like.
pub fn check_joints(skel: &Skeleton, j: &Joints) -> Result<(), MagnitudeError> {
    let jn = skel.num_joints();
    if let Some((f, fr)) = j.iter().enumerate().find(|(_, fr)| fr.len() != jn) {
        return Err(MagnitudeError::JointCount { want: jn, got: fr.len(), frame: f });
    }
    check_leg(skel, j)?;
    check_positions(skel, j)
}

/// A human's leg length (a wrong unit is the likely cause of any other).
fn check_leg(skel: &Skeleton, j: &Joints) -> Result<(), MagnitudeError> {
    let mpu = skel.metres_per_unit;
    let bones = leg_bones(skel);
    let leg = |fr: &[[f64; 3]]| -> f64 {
        bones.iter().map(|&(a, b)| quat::norm(quat::sub(fr[a], fr[b]))).sum::<f64>() * mpu
    };
    let mut legs: Vec<f64> = j.iter().map(|fr| leg(fr)).collect();
    legs.sort_by(f64::total_cmp);
    let Some(&leg) = legs.get(legs.len() / 2) else {
        return Ok(());
    };
    let (lo, hi) = LEG_RANGE_M;
    if (lo..=hi).contains(&leg) {
        return Ok(());
    }
    let unit = [(1000.0, "millimetres (divide by 1000)"), (100.0, "centimetres (divide by 100)")]
        .into_iter()
        .find(|(k, _)| (lo..=hi).contains(&(leg / k)))
        .map_or(String::new(), |(_, u)| format!("; the positions look like {u}"));
    Err(MagnitudeError::Leg { metres: leg, unit })
}

/// What feature `c` of `layout` is, in the words of error messages and reports.
pub fn feature_group(layout: &Layout, c: usize) -> &'static str {
    match c {
        0 => "root yaw rate (rad per frame)",
        1 | 2 => "root velocity (per frame)",
        3 => "root height",
        c if layout.ric().contains(&c) => "root-relative joint position",
        c if layout.vel().contains(&c) => "joint velocity",
        _ => "rotation or contact value",
    }
}

/// Feature rows (T, D) within the physical limits above; the error names the frame, the
/// feature and its group.
pub fn check_features(skel: &Skeleton, data: &[f32]) -> Result<(), MagnitudeError> {
    let layout = Layout::of(skel);
    let d = layout.dim();
    let mpu = skel.metres_per_unit;
    let limit = |c: usize| -> (f64, &'static str) {
        let max = match c {
            0 => MAX_YAW_RATE,
            1 | 2 => MAX_ROOT_STEP_M / mpu,
            3 => MAX_HEIGHT_M / mpu,
            c if layout.ric().contains(&c) || layout.vel().contains(&c) => MAX_OTHER / mpu,
            _ => MAX_OTHER,
        };
        (max, feature_group(&layout, c))
    };
    for (i, &v) in data.iter().enumerate() {
        let (max, what) = limit(i % d);
        if !within(v as f64, max) {
            return Err(MagnitudeError::Feature {
                frame: i / d,
                feature: i % d,
                what,
                value: v,
                max,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    fn walk() -> Joints {
        diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 0, 0).0.joints
    }

    #[test]
    fn a_real_size_walk_passes_and_scaled_copies_are_named() {
        let j = walk();
        check_joints(&T2M, &j).unwrap();
        let scaled = |k: f64| -> Joints {
            j.iter().map(|f| f.iter().map(|p| quat::scale(*p, k)).collect()).collect()
        };
        let e = check_joints(&T2M, &scaled(1000.0)).unwrap_err().to_string();
        assert!(e.contains("millimetres"), "{e}");
        let e = check_joints(&T2M, &scaled(100.0)).unwrap_err().to_string();
        assert!(e.contains("centimetres"), "{e}");
        let e = check_joints(&T2M, &scaled(0.0)).unwrap_err().to_string();
        assert!(e.contains("0.000 m long"), "{e}");
        let mut far = j.clone();
        far[3][5][0] = 1e20;
        let e = check_joints(&T2M, &far).unwrap_err().to_string();
        assert!(e.contains("frame 3, joint 5"), "{e}");
        // A frame with too few joints is named, not indexed past its end.
        let mut short = j.clone();
        short[2].truncate(1);
        let e = check_joints(&T2M, &short).unwrap_err().to_string();
        assert!(e.contains("needs 22 joints, got 1 (frame 2)"), "{e}");
    }

    #[test]
    fn features_beyond_their_limits_are_named() {
        let f = diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 0, 0).1;
        check_features(&T2M, &f).unwrap();
        let d = T2M.feature_dim();
        for (c, v, what) in
            [(1, 1e30f32, "root velocity"), (10, 1e20, "root-relative"), (0, f32::NAN, "yaw")]
        {
            let mut bad = f.clone();
            bad[2 * d + c] = v;
            let e = check_features(&T2M, &bad).unwrap_err().to_string();
            assert!(e.contains(&format!("frame 2, feature {c}")) && e.contains(what), "{e}");
        }
    }
}

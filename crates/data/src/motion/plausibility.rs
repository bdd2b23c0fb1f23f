//! Physical plausibility measures of joint-position motions (metres, Y up): what the
//! synthetic set is tested against and what `eval` reports as foot skating; and whether a
//! motion can be drawn at all (a diverged sampler's cannot).

use crate::motion::quat::{self, Vec3};
use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;
use crate::DataError;

#[derive(Clone, Debug, serde::Serialize)]
pub struct Plausibility {
    /// Largest standard deviation of any bone's length over time (m).
    pub bone_length_std: f64,
    /// Lowest joint height (m); below zero is ground penetration.
    pub min_height: f64,
    /// Share of foot-on-ground frames in which the foot slides (see [`foot_skating_ratio`]).
    pub foot_skating: f64,
    /// Fastest joint speed between consecutive frames (m/s).
    pub max_speed: f64,
    /// Largest joint acceleration |x[t+1] - 2x`[t]` + x[t-1]| * fps^2 (m/s^2): velocity spikes.
    pub max_accel: f64,
}

pub fn measure(skel: &Skeleton, j: &Joints) -> Plausibility {
    let parents = skel.parents();
    let mut bone_std = 0.0f64;
    for (b, &p) in parents.iter().enumerate().skip(1) {
        let ls: Vec<f64> = j.iter().map(|f| quat::norm(quat::sub(f[b], f[p as usize]))).collect();
        let m = ls.iter().sum::<f64>() / ls.len() as f64;
        let v = ls.iter().map(|l| (l - m).powi(2)).sum::<f64>() / ls.len() as f64;
        bone_std = bone_std.max(v.sqrt());
    }
    let min_height = j.iter().flatten().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    let max_speed = j
        .windows(2)
        .flat_map(|w| w[0].iter().zip(&w[1]).map(|(a, b)| quat::norm(quat::sub(*b, *a))))
        .fold(0.0, f64::max)
        * skel.fps;
    let max_accel = j
        .windows(3)
        .flat_map(|w| {
            (0..w[0].len()).map(move |k| {
                quat::norm(quat::add(quat::sub(w[2][k], quat::scale(w[1][k], 2.0)), w[0][k]))
            })
        })
        .fold(0.0, f64::max)
        * skel.fps
        * skel.fps;
    Plausibility {
        bone_length_std: bone_std,
        min_height,
        foot_skating: foot_skating_ratio(skel, j),
        max_speed,
        max_accel,
    }
}

/// A toe below this height (m) is on the ground for the foot skating measure ...
pub const SKATE_HEIGHT_M: f64 = 0.05;
/// ... and skates when it moves horizontally faster than this (m/s).
pub const SKATE_SPEED_MPS: f64 = 0.5;

/// One toe's step from `a` to `b` (one frame): `None` when `b` is off the ground, else whether
/// it skates.
pub fn skates(skel: &Skeleton, a: Vec3, b: Vec3) -> Option<bool> {
    let unit = skel.metres_per_unit;
    (b[1] * unit < SKATE_HEIGHT_M).then(|| {
        ((b[0] - a[0]).powi(2) + (b[2] - a[2]).powi(2)).sqrt() * unit * skel.fps > SKATE_SPEED_MPS
    })
}

/// Ground penetration (PhysDiff's "Penetrate"): per frame, how far the lowest joint is below
/// the floor (height 0; nothing when above it), the mean over frames (m).
pub fn penetration(skel: &Skeleton, j: &Joints) -> f64 {
    if j.is_empty() {
        return 0.0;
    }
    let below = |f: &Vec<Vec3>| (-f.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min)).max(0.0);
    j.iter().map(below).sum::<f64>() / j.len() as f64 * skel.metres_per_unit
}

/// Foot skating ratio: among frames where a toe joint is below 5 cm, the share in which it
/// moves horizontally faster than 0.5 m/s. 0 when the feet never touch the ground.
pub fn foot_skating_ratio(skel: &Skeleton, j: &Joints) -> f64 {
    let (mut contact, mut skate) = (0usize, 0usize);
    for w in j.windows(2) {
        for foot in [skel.feet_left[1], skel.feet_right[1]] {
            if let Some(s) = skates(skel, w[0][foot], w[1][foot]) {
                contact += 1;
                skate += s as usize;
            }
        }
    }
    if contact == 0 {
        0.0
    } else {
        skate as f64 / contact as f64
    }
}

/// Farthest a joint may be from the origin and still be drawn (metres): the ground grid has a
/// line every 0.5 m, so a motion 1e30 m long would take forever.
pub const MAX_EXTENT_M: f64 = 10_000.0;

/// A motion that can be drawn: every coordinate finite and within `MAX_EXTENT_M`.
pub fn check_drawable(j: &Joints) -> Result<(), DataError> {
    for (t, frame) in j.iter().enumerate() {
        for (k, p) in frame.iter().enumerate() {
            if let Some(v) = p.iter().find(|v| !(v.is_finite() && v.abs() <= MAX_EXTENT_M)) {
                return Err(DataError::Invalid(format!("frame {t}, joint {k} is at {v} m: not finite or beyond {MAX_EXTENT_M} m, cannot draw it")));
            }
        }
    }
    Ok(())
}

/// The joints of generated features `[T, D]`, or why they cannot be a motion (a diverged
/// sampler): a non-finite feature, or joints that cannot be drawn.
pub fn drawable_joints(skel: &Skeleton, features: &[f32]) -> Result<Joints, DataError> {
    if !features.iter().all(|v| v.is_finite()) {
        return Err(DataError::Invalid("features not finite".into()));
    }
    let j = crate::motion::representation::recover_from_ric(
        skel,
        &features.iter().map(|&v| v as f64).collect::<Vec<_>>(),
    );
    check_drawable(&j)?;
    Ok(j)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    #[test]
    fn sliding_feet_are_counted() {
        // A rigid pose sliding along x at 1 m/s with toes at 1 cm: every contact frame skates.
        let pose: Vec<[f64; 3]> =
            (0..22).map(|i| [0.0, if i == 10 || i == 11 { 0.01 } else { 0.5 }, 0.0]).collect();
        let slide: Joints = (0..10)
            .map(|t| pose.iter().map(|p| [p[0] + t as f64 * 0.05, p[1], p[2]]).collect())
            .collect();
        assert_eq!(foot_skating_ratio(&T2M, &slide), 1.0);
        let still: Joints = (0..10).map(|_| pose.clone()).collect();
        assert_eq!(foot_skating_ratio(&T2M, &still), 0.0);
        assert_eq!(penetration(&T2M, &still), 0.0);
        // Sunk 3 cm on half of the frames: toes at -2 cm there, 1 cm below on average.
        let sunk: Joints = (0..10)
            .map(|t| {
                pose.iter().map(|p| [p[0], p[1] - if t < 5 { 0.03 } else { 0.0 }, p[2]]).collect()
            })
            .collect();
        assert!((penetration(&T2M, &sunk) - 0.01).abs() < 1e-12, "{}", penetration(&T2M, &sunk));
        let m = measure(&T2M, &slide);
        assert!((m.max_speed - 1.0).abs() < 1e-9 && m.bone_length_std < 1e-12);
    }
}

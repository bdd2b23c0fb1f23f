//! Gait measures of joint-position motions (Y up): whether a motion covers ground with stepping
//! legs or drags a still body along. Defined once here; `eval`, `sample`'s results.json and the
//! design panel (`diffkfc eval panel`) report them.
//! * **root speed**: mean horizontal speed of the root joint (m/s).
//! * **planted share**: share of frames on which a toe is within 5 cm of the motion's floor
//!   (the lowest height either toe reaches) and moves slower than 0.15 m/s horizontally, the
//!   mean of the two toes.
//! * **stride amplitude**: per toe, the standard deviation over frames of its horizontal offset
//!   from the pelvis along the travel direction (the root's velocity smoothed over 9 frames;
//!   the facing direction where that is slower than 0.1 m/s), the mean of the two toes (m).

use diffkfc_data::motion::representation::Joints;
use diffkfc_data::motion::skeleton::Skeleton;
use diffkfc_data::motion::travel::travel_directions;
use serde::Serialize;

/// A toe this close to the floor may be planted (m).
pub const PLANTED_HEIGHT_M: f64 = 0.05;
/// A planted toe moves slower than this horizontally (m/s).
pub const PLANTED_SPEED_MPS: f64 = 0.15;

/// The three gait numbers of one motion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GaitNumbers {
    pub root_speed_mps: f64,
    pub planted_share: f64,
    pub stride_amplitude_m: f64,
}

/// All three measures; a motion of fewer than 2 frames has none of them (zeros).
pub fn measure(skel: &Skeleton, j: &Joints) -> GaitNumbers {
    GaitNumbers {
        root_speed_mps: root_speed(skel, j),
        planted_share: planted_share(skel, j),
        stride_amplitude_m: stride_amplitude(skel, j),
    }
}

fn horizontal(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((b[0] - a[0]).powi(2) + (b[2] - a[2]).powi(2)).sqrt()
}

/// Mean horizontal speed of the root joint (m/s).
pub fn root_speed(skel: &Skeleton, j: &Joints) -> f64 {
    if j.len() < 2 {
        return 0.0;
    }
    let path: f64 = j.windows(2).map(|w| horizontal(w[0][0], w[1][0])).sum();
    path * skel.metres_per_unit * skel.fps / (j.len() - 1) as f64
}

/// Share of frames (each frame with its step to the next) on which a toe is planted, the mean
/// of the two toes' shares (a walk keeps each foot planted for about 60% of its frames).
pub fn planted_share(skel: &Skeleton, j: &Joints) -> f64 {
    if j.len() < 2 {
        return 0.0;
    }
    let toes = [skel.feet_left[1], skel.feet_right[1]];
    let floor = j.iter().flat_map(|f| toes.map(|t| f[t][1])).fold(f64::INFINITY, f64::min);
    let (h, v) =
        (PLANTED_HEIGHT_M / skel.metres_per_unit, PLANTED_SPEED_MPS / skel.metres_per_unit);
    let planted: usize = j
        .windows(2)
        .map(|w| {
            toes.iter()
                .filter(|&&t| w[0][t][1] - floor < h && horizontal(w[0][t], w[1][t]) * skel.fps < v)
                .count()
        })
        .sum();
    planted as f64 / (2 * (j.len() - 1)) as f64
}

/// Mean over the two toes of the std over frames of the toe's offset from the pelvis along
/// the travel direction (m).
pub fn stride_amplitude(skel: &Skeleton, j: &Joints) -> f64 {
    if j.len() < 2 {
        return 0.0;
    }
    let dirs = travel_directions(skel, j);
    let toes = [skel.feet_left[1], skel.feet_right[1]];
    let std_of = |toe: usize| {
        let off: Vec<f64> = j
            .iter()
            .zip(&dirs)
            .map(|(f, d)| (f[toe][0] - f[0][0]) * d[0] + (f[toe][2] - f[0][2]) * d[1])
            .collect();
        let m = off.iter().sum::<f64>() / off.len() as f64;
        (off.iter().map(|o| (o - m).powi(2)).sum::<f64>() / off.len() as f64).sqrt()
    };
    toes.iter().map(|&t| std_of(t)).sum::<f64>() / 2.0 * skel.metres_per_unit
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::T2M;

    /// A standing pose: pelvis at 0.9 m, toes on the floor 10 cm either side, facing +Z
    /// (left hip and shoulder at +x, as SMPL's).
    fn pose() -> Vec<[f64; 3]> {
        let mut p = vec![[0.0, 1.0, 0.0]; 22];
        p[0] = [0.0, 0.9, 0.0];
        for (k, x) in [(1, 0.1), (2, -0.1), (16, 0.2), (17, -0.2)] {
            p[k] = [x, if k < 3 { 0.9 } else { 1.4 }, 0.0];
        }
        p[10] = [0.1, 0.0, 0.05];
        p[11] = [-0.1, 0.0, 0.05];
        p
    }

    /// A walk in place: each toe stands still on the floor for half of a 20-frame cycle and
    /// swings 0.3 m forward and back, lifted, for the other half, the two in opposite phase;
    /// the pelvis still.
    fn walk_in_place(frames: usize) -> Joints {
        (0..frames)
            .map(|t| {
                let mut p = pose();
                for (toe, offset) in [(10, 0), (11, 10)] {
                    let k = (t + offset) % 20;
                    if k >= 10 {
                        let bump = (std::f64::consts::PI * (k - 10) as f64 / 10.0).sin();
                        p[toe][2] = 0.3 * bump;
                        p[toe][1] = 0.1 * bump;
                    } else {
                        p[toe][2] = 0.0;
                        p[toe][1] = 0.0;
                    }
                }
                p
            })
            .collect()
    }

    #[test]
    fn walk_in_place_has_stride_but_no_speed() {
        let g = measure(&T2M, &walk_in_place(80));
        assert!(g.root_speed_mps < 1e-12, "{g:?}");
        // Half of the frames at 0, half a sine bump of 0.3 m (mean 0.3 x 2/pi over the swing):
        // the std of that mix, computed from its frames.
        let z: Vec<f64> = (0..20)
            .map(|k| {
                if k >= 10 {
                    0.3 * (std::f64::consts::PI * (k - 10) as f64 / 10.0).sin()
                } else {
                    0.0
                }
            })
            .collect();
        let m = z.iter().sum::<f64>() / 20.0;
        let want = (z.iter().map(|v| (v - m).powi(2)).sum::<f64>() / 20.0).sqrt();
        assert!((g.stride_amplitude_m - want).abs() < 1e-9 && want > 0.1, "{g:?} vs {want}");
        // Each toe stands still on the floor for half the cycle.
        assert!((g.planted_share - 0.5).abs() < 0.02, "{g:?}");
    }

    #[test]
    fn sliding_rigid_pose_has_speed_no_stride_no_planted_frames() {
        // 1 m/s along +z, feet on the floor.
        let slide: Joints = (0..60)
            .map(|t| pose().into_iter().map(|p| [p[0], p[1], p[2] + t as f64 * 0.05]).collect())
            .collect();
        let g = measure(&T2M, &slide);
        assert!((g.root_speed_mps - 1.0).abs() < 1e-9, "{g:?}");
        assert!(g.stride_amplitude_m < 1e-9, "{g:?}");
        assert_eq!(g.planted_share, 0.0, "{g:?}");
    }

    #[test]
    fn still_pose_is_planted_throughout() {
        let still: Joints = (0..30).map(|_| pose()).collect();
        let g = measure(&T2M, &still);
        assert_eq!(g.planted_share, 1.0);
        assert_eq!(g.root_speed_mps, 0.0);
        assert!(g.stride_amplitude_m < 1e-12);
    }

    #[test]
    fn stride_follows_the_travel_direction() {
        // The walk in place carried along +x at 1 m/s while still facing +z: the toes' swing is
        // across the travel direction, so the stride along it is (nearly) nothing.
        let sideways: Joints = walk_in_place(80)
            .into_iter()
            .enumerate()
            .map(|(t, f)| f.into_iter().map(|p| [p[0] + t as f64 * 0.05, p[1], p[2]]).collect())
            .collect();
        let g = measure(&T2M, &sideways);
        assert!((g.root_speed_mps - 1.0).abs() < 1e-9);
        assert!(g.stride_amplitude_m < 1e-9, "{g:?}");
    }
}

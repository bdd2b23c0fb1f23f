//! The direction a motion travels in, frame by frame: what the gait measures
//! (`diffkfc_eval::gait`) and stride warping (`crate::postprocess::stride`) measure strides along.

use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;

/// Frames over which the root's velocity is averaged for the travel direction.
pub const TRAVEL_WINDOW: usize = 9;
/// Below this smoothed root speed the travel direction is the facing direction (m/s).
pub const MOVING_MPS: f64 = 0.1;

/// Unit horizontal travel direction per frame: the root's velocity averaged over
/// `TRAVEL_WINDOW` frames, or the facing direction where the root barely moves.
pub fn travel_directions(skel: &Skeleton, j: &Joints) -> Vec<[f64; 2]> {
    let t = j.len();
    let vel: Vec<[f64; 2]> = (0..t)
        .map(|f| {
            let (a, b) = if f + 1 < t { (f, f + 1) } else { (f.saturating_sub(1), f) };
            [j[b][0][0] - j[a][0][0], j[b][0][2] - j[a][0][2]]
        })
        .collect();
    let half = TRAVEL_WINDOW / 2;
    (0..t)
        .map(|f| {
            let win = &vel[f.saturating_sub(half)..(f + half + 1).min(t)];
            let n = win.len() as f64;
            let v = [
                win.iter().map(|v| v[0]).sum::<f64>() / n,
                win.iter().map(|v| v[1]).sum::<f64>() / n,
            ];
            let speed = v[0].hypot(v[1]) * skel.metres_per_unit * skel.fps;
            if speed >= MOVING_MPS {
                [v[0] / v[0].hypot(v[1]), v[1] / v[0].hypot(v[1])]
            } else {
                facing(skel, &j[f])
            }
        })
        .collect()
}

/// The horizontal facing direction of one frame (HumanML3D's: up x (hips + shoulders across)).
pub fn facing(skel: &Skeleton, frame: &[[f64; 3]]) -> [f64; 2] {
    let [r_hip, l_hip, r_sho, l_sho] = skel.face_joints;
    let across = [
        frame[r_hip][0] - frame[l_hip][0] + frame[r_sho][0] - frame[l_sho][0],
        frame[r_hip][2] - frame[l_hip][2] + frame[r_sho][2] - frame[l_sho][2],
    ];
    // (0, 1, 0) x (ax, 0, az) = (az, 0, -ax)
    let f = [across[1], -across[0]];
    let n = f[0].hypot(f[1]);
    if n > 0.0 {
        [f[0] / n, f[1] / n]
    } else {
        [0.0, 1.0]
    }
}

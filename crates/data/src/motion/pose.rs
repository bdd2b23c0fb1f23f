//! Features determined by a single pose (a joint-position keyframe): root height, root-relative
//! facing-normalised positions (RIC) and local rotations by IK. Velocities, the root's motion
//! and foot contacts need neighbouring frames and stay unobserved.

use crate::motion::quat::{self, Vec3};
use crate::motion::representation::{facing, inverse_kinematics, Facing, Layout};
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// (values [D], observed [D]) of one pose (Y up, metres, floor at y = 0).
pub fn pose_features(skel: &Skeleton, pose: &[Vec3]) -> Result<(Vec<f32>, Vec<bool>), DataError> {
    let jn = skel.num_joints();
    if pose.len() != jn {
        return Err(DataError::Invalid(format!("a pose needs {jn} joints, got {}", pose.len())));
    }
    if pose.iter().flatten().any(|v| !v.is_finite()) {
        return Err(DataError::Invalid("pose contains NaN or infinite values".into()));
    }
    let root = pose[0];
    let fwd = facing(skel, &vec![pose.to_vec()], Facing::Consistent)[0];
    let q = quat::qbetween(fwd, [0.0, 0.0, 1.0]);
    let local: Vec<Vec3> =
        pose.iter().map(|p| quat::qrot(q, [p[0] - root[0], p[1], p[2] - root[2]])).collect();
    let rots = inverse_kinematics(skel, &vec![local.clone()], false);
    let l = Layout::of(skel);
    let mut v = vec![0f32; l.dim()];
    let mut m = vec![false; l.dim()];
    v[3] = root[1] as f32;
    m[3] = true;
    for j in 1..jn {
        for k in 0..3 {
            v[l.ric().start + 3 * (j - 1) + k] = local[j][k] as f32;
            m[l.ric().start + 3 * (j - 1) + k] = true;
        }
        let c6 = quat::to_cont6d(rots[0][j]);
        for k in 0..6 {
            v[l.rot().start + 6 * (j - 1) + k] = c6[k] as f32;
            m[l.rot().start + 6 * (j - 1) + k] = true;
        }
    }
    Ok((v, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{io::npy, motion::representation as rep, testing::fixtures, T2M};

    /// A frame of real features is reproduced by the pose it decodes to (frame 0, where
    /// HumanML3D's root rotation is the identity and the body faces +Z).
    #[test]
    fn single_pose_matches_process_file_at_frame_zero() {
        let Some(p) = fixtures::require("humanml3d/000021_features_reference.npy") else {
            return;
        };
        let f = npy::read_f64(p).unwrap();
        let joints = rep::recover_from_ric(&T2M, &f.data);
        let (v, m) = pose_features(&T2M, &joints[0]).unwrap();
        let l = Layout::of(&T2M);
        let mut worst: f64 = 0.0;
        for k in (0..l.dim()).filter(|&k| m[k] && !l.rot().contains(&k)) {
            worst = worst.max((v[k] as f64 - f.data[k]).abs());
        }
        assert!(worst < 1e-3, "RIC/height error {worst}");
        assert!(!m[0] && !m[1] && m[3] && !m[l.vel().start] && !m[l.contacts().start]);
    }
}

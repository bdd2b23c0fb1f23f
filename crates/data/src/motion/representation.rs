//! The HumanML3D motion representation: joint positions <-> feature vectors.
//!
//! Layout per frame (J joints): `[0]` root angular velocity about Y, `[1:3]` root linear velocity
//! (x, z) in the facing frame, `[3]` root height, then (J-1)*3 root-relative joint positions (RIC),
//! (J-1)*6 local rotations (continuous 6D), J*3 local joint velocities, 4 foot contacts.
//! `features_from_joints` is HumanML3D's `process_file`; `recover_from_ric` its inverse for
//! positions. Arithmetic is in f64; files are f32.

use crate::motion::quat::{self, Quat, Vec3};
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// A joint-position sequence, frames of `J` points.
pub type Joints = Vec<Vec<Vec3>>;

/// Foot-contact threshold on squared per-frame displacement (HumanML3D's `feet_thre`).
pub const FOOT_CONTACT_THRESHOLD: f64 = 0.002;

/// Offsets of the feature groups in a feature vector of a skeleton with `j` joints.
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    pub joints: usize,
}

impl Layout {
    pub fn of(skel: &Skeleton) -> Self {
        Layout { joints: skel.num_joints() }
    }
    pub fn ric(&self) -> std::ops::Range<usize> {
        4..4 + (self.joints - 1) * 3
    }
    pub fn rot(&self) -> std::ops::Range<usize> {
        let s = self.ric().end;
        s..s + (self.joints - 1) * 6
    }
    pub fn vel(&self) -> std::ops::Range<usize> {
        let s = self.rot().end;
        s..s + self.joints * 3
    }
    pub fn contacts(&self) -> std::ops::Range<usize> {
        let s = self.vel().end;
        s..s + 4
    }
    pub fn dim(&self) -> usize {
        self.contacts().end
    }
    /// Named groups of feature indices, in order: what tolerances and statistics are kept per.
    pub fn groups(&self) -> [(&'static str, std::ops::Range<usize>); 7] {
        [
            ("root_angular_velocity", 0..1),
            ("root_linear_velocity", 1..3),
            ("root_height", 3..4),
            ("ric", self.ric()),
            ("rotations_6d", self.rot()),
            ("local_velocities", self.vel()),
            ("foot_contacts", self.contacts()),
        ]
    }
}

/// Root yaw rotation and root position of every frame (HumanML3D `recover_root_rot_pos`).
/// `feats` is row-major (T, D).
pub fn recover_root_rot_pos(feats: &[f64], dim: usize) -> (Vec<Quat>, Vec<Vec3>) {
    let t = feats.len() / dim;
    let mut quats = Vec::with_capacity(t);
    let mut pos = Vec::with_capacity(t);
    let mut angle = 0.0;
    let mut xz = [0.0, 0.0, 0.0];
    for i in 0..t {
        if i > 0 {
            angle += feats[(i - 1) * dim];
        }
        let q = quat::root_yaw_quat(angle);
        if i > 0 {
            let v = [feats[(i - 1) * dim + 1], 0.0, feats[(i - 1) * dim + 2]];
            xz = quat::add(xz, quat::qrot(quat::qinv(q), v));
        }
        quats.push(q);
        pos.push([xz[0], feats[i * dim + 3], xz[2]]);
    }
    (quats, pos)
}

/// Global joint positions from features (HumanML3D `recover_from_ric`).
pub fn recover_from_ric(skel: &Skeleton, feats: &[f64]) -> Joints {
    let dim = skel.feature_dim();
    let jn = skel.num_joints();
    let (quats, root) = recover_root_rot_pos(feats, dim);
    (0..quats.len())
        .map(|i| {
            let row = &feats[i * dim..(i + 1) * dim];
            let inv = quat::qinv(quats[i]);
            let mut frame = Vec::with_capacity(jn);
            frame.push(root[i]);
            for j in 0..jn - 1 {
                let r = [row[4 + 3 * j], row[5 + 3 * j], row[6 + 3 * j]];
                let p = quat::qrot(inv, r);
                frame.push([p[0] + root[i][0], p[1], p[2] + root[i][2]]);
            }
            frame
        })
        .collect()
}

/// [`recover_from_ric`] of f32 features, as files and the network hold them.
pub fn recover_from_ric_f32(skel: &Skeleton, feats: &[f32]) -> Joints {
    recover_from_ric(skel, &feats.iter().map(|&v| v as f64).collect::<Vec<_>>())
}

/// scipy's `gaussian_filter1d(x, sigma, axis=0, mode='nearest')` (truncate 4.0) on a sequence of
/// 3-vectors: HumanML3D smooths the facing direction with it before IK.
pub fn gaussian_filter_nearest(x: &[Vec3], sigma: f64) -> Vec<Vec3> {
    let radius = (4.0 * sigma + 0.5) as i64;
    let mut w: Vec<f64> =
        (-radius..=radius).map(|k| (-0.5 * (k * k) as f64 / (sigma * sigma)).exp()).collect();
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    let n = x.len() as i64;
    (0..n)
        .map(|i| {
            let mut acc = [0.0; 3];
            for (k, wk) in (-radius..=radius).zip(&w) {
                let src = (i + k).clamp(0, n - 1) as usize;
                acc = quat::add(acc, quat::scale(x[src], *wk));
            }
            acc
        })
        .collect()
}

/// How a facing direction is taken from the hips and shoulders.
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Facing {
    /// `process_file`'s initial facing: (r_hip - l_hip) + (r_sho - l_sho), normalised.
    Consistent,
    /// `inverse_kinematics_np`'s: it unpacks the face joints as (l_hip, r_hip, r_sho, l_sho), so
    /// its hip term is left-minus-right while its shoulder term is right-minus-left, and it
    /// leaves the cross product unnormalised for the smoothing that follows. Released HumanML3D
    /// features were made this way (the golden tests fail with the consistent version).
    Reference,
}

/// up x across for each frame.
pub(crate) fn facing(skel: &Skeleton, joints: &Joints, how: Facing) -> Vec<Vec3> {
    let [r_hip, l_hip, r_sho, l_sho] = skel.face_joints;
    let hips = |f: &[Vec3]| {
        if how == Facing::Reference {
            quat::sub(f[l_hip], f[r_hip])
        } else {
            quat::sub(f[r_hip], f[l_hip])
        }
    };
    joints
        .iter()
        .map(|f| {
            let across = quat::normalize(quat::add(hips(f), quat::sub(f[r_sho], f[l_sho])));
            let fwd = quat::cross([0.0, 1.0, 0.0], across);
            if how == Facing::Reference {
                fwd
            } else {
                quat::normalize(fwd)
            }
        })
        .collect()
}

/// Local joint rotations (quaternions) by inverse kinematics on the raw offset directions
/// (HumanML3D `Skeleton.inverse_kinematics_np`). Frame 0's root rotation is set to identity, as
/// the reference does (inputs are already turned to face +Z at frame 0).
pub fn inverse_kinematics(
    skel: &Skeleton,
    joints: &Joints,
    smooth_forward: bool,
) -> Vec<Vec<Quat>> {
    let mut forward = facing(skel, joints, Facing::Reference);
    if smooth_forward {
        forward = gaussian_filter_nearest(&forward, 20.0);
    }
    let forward: Vec<Vec3> = forward.into_iter().map(quat::normalize).collect();
    let jn = skel.num_joints();
    joints
        .iter()
        .zip(&forward)
        .enumerate()
        .map(|(t, (f, fwd))| {
            let mut q = vec![quat::IDENTITY; jn];
            let root = if t == 0 { quat::IDENTITY } else { quat::qbetween(*fwd, [0.0, 0.0, 1.0]) };
            q[0] = root;
            for chain in skel.kinematic_chain {
                let mut r = root;
                for w in chain.windows(2) {
                    let u = skel.raw_offsets[w[1]];
                    let v = quat::normalize(quat::sub(f[w[1]], f[w[0]]));
                    let local = quat::qmul(quat::qinv(r), quat::qbetween(u, v));
                    q[w[1]] = local;
                    r = quat::qmul(r, local);
                }
            }
            q
        })
        .collect()
}

/// Joint positions from local rotations, a root path and bone vectors
/// (HumanML3D `forward_kinematics_np` with the root rotation applied).
pub fn forward_kinematics(
    skel: &Skeleton,
    rotations: &[Vec<Quat>],
    root: &[Vec3],
    offsets: &[Vec3],
) -> Joints {
    rotations
        .iter()
        .zip(root)
        .map(|(q, &rp)| {
            let mut f = vec![[0.0; 3]; skel.num_joints()];
            f[0] = rp;
            for chain in skel.kinematic_chain {
                let mut r = q[0];
                for w in chain.windows(2) {
                    r = quat::qmul(r, q[w[1]]);
                    f[w[1]] = quat::add(quat::qrot(r, offsets[w[1]]), f[w[0]]);
                }
            }
            f
        })
        .collect()
}

/// Bone vectors of one pose along the raw offset directions (`get_offsets_joints`).
pub fn bone_offsets(skel: &Skeleton, pose: &[Vec3]) -> Vec<Vec3> {
    let parents = skel.parents();
    (0..skel.num_joints())
        .map(|i| {
            if i == 0 {
                skel.raw_offsets[0]
            } else {
                let len = quat::norm(quat::sub(pose[i], pose[parents[i] as usize]));
                quat::scale(skel.raw_offsets[i], len)
            }
        })
        .collect()
}

/// Bone lengths of `pose` (joint to parent; 0 for the root): the retarget's target when taken
/// from a reference clip's first frame, as HumanML3D's processing does (`000021` for
/// HumanML3D, `03950` for KIT-ML).
pub fn bone_lengths(skel: &Skeleton, pose: &[Vec3]) -> Vec<f64> {
    let parents = skel.parents();
    (0..skel.num_joints())
        .map(|i| match parents[i] {
            p if p < 0 => 0.0,
            p => quat::norm(quat::sub(pose[i], pose[p as usize])),
        })
        .collect()
}

/// Target bone vectors: the raw offset directions times `lengths` (the skeleton's own target
/// lengths when None; KIT-ML has none built in).
fn target_offsets(skel: &Skeleton, lengths: Option<&[f64]>) -> Result<Vec<Vec3>, DataError> {
    match lengths {
        Some(l) if l.len() == skel.num_joints() => {
            Ok(skel.raw_offsets.iter().zip(l).map(|(d, &l)| quat::scale(*d, l)).collect())
        }
        Some(l) => Err(DataError::Invalid(format!(
            "target skeleton: {} bone lengths for the {} skeleton's {} joints",
            l.len(),
            skel.name,
            skel.num_joints()
        ))),
        None => skel.target_offsets().ok_or_else(|| {
            DataError::Invalid(format!(
                "skeleton '{}' has no built-in target bone lengths: give a reference clip of your data (its first frame's bones, as HumanML3D's KIT processing takes 03950) with --target-skeleton",
                skel.name
            ))
        }),
    }
}

/// Retarget a motion to the skeleton's target bone lengths, scaling the root path by the ratio
/// of lower-leg lengths (HumanML3D `uniform_skeleton`).
pub fn uniform_skeleton(skel: &Skeleton, joints: &Joints) -> Result<Joints, DataError> {
    uniform_skeleton_to(skel, joints, None)
}

/// [`uniform_skeleton`] onto the bone `lengths` of [`bone_lengths`] (None: the skeleton's own).
pub fn uniform_skeleton_to(
    skel: &Skeleton,
    joints: &Joints,
    lengths: Option<&[f64]>,
) -> Result<Joints, DataError> {
    let tgt = target_offsets(skel, lengths)?;
    let src = bone_offsets(skel, &joints[0]);
    let leg = |o: &[Vec3]| -> f64 {
        skel.leg_bones.iter().map(|&b| o[b].iter().fold(0.0f64, |m, v| m.max(v.abs()))).sum()
    };
    let scale = leg(&tgt) / leg(&src);
    let root: Vec<Vec3> = joints.iter().map(|f| quat::scale(f[0], scale)).collect();
    let rotations = inverse_kinematics(skel, joints, false);
    Ok(forward_kinematics(skel, &rotations, &root, &tgt))
}

/// HumanML3D `process_file`: joint positions (T frames) to features (T-1 frames), f32 row-major.
pub fn features_from_joints(
    skel: &Skeleton,
    joints: &Joints,
    feet_threshold: f64,
) -> Result<Vec<f32>, DataError> {
    features_from_joints_to(skel, joints, feet_threshold, None)
}

/// [`features_from_joints`] retargeted onto the bone `lengths` of a reference pose
/// ([`bone_lengths`]; None: the skeleton's built-in target).
pub fn features_from_joints_to(
    skel: &Skeleton,
    joints: &Joints,
    feet_threshold: f64,
    lengths: Option<&[f64]>,
) -> Result<Vec<f32>, DataError> {
    validate_joints(skel, joints)?;
    let global = canonical(skel, uniform_skeleton_to(skel, joints, lengths)?);
    let t = global.len();
    let rotations = inverse_kinematics(skel, &global, true);
    let layout = Layout::of(skel);
    let dim = layout.dim();
    let mut out = vec![0f32; (t - 1) * dim];
    for (f, row) in out.chunks_exact_mut(dim).enumerate() {
        feature_row(skel, &layout, &global, &rotations, f, feet_threshold, row);
    }
    if let Some(k) = out.iter().position(|v| !v.is_finite()) {
        return Err(DataError::Invalid(format!(
            "frame {}: feature {} is not finite (a degenerate pose)",
            k / dim,
            k % dim
        )));
    }
    Ok(out)
}

/// Frame `f`'s features (HumanML3D's `process_file`): the root's angular and linear velocity
/// and height, the root-relative joint positions (RIC) and rotations, the joint velocities and
/// the four foot contacts (squared displacement to the next frame below `feet_threshold`).
fn feature_row(
    skel: &Skeleton,
    layout: &Layout,
    global: &Joints,
    rotations: &[Vec<Quat>],
    f: usize,
    feet_threshold: f64,
    row: &mut [f32],
) {
    let r_rot = |f: usize| rotations[f][0];
    // Root angular velocity: arcsin of the y part of r_rot[f+1] * r_rot[f]^-1.
    let rv = quat::qmul(r_rot(f + 1), quat::qinv(r_rot(f)));
    row[0] = rv[2].asin() as f32;
    let lin = quat::qrot(r_rot(f + 1), quat::sub(global[f + 1][0], global[f][0]));
    row[1] = lin[0] as f32;
    row[2] = lin[2] as f32;
    row[3] = global[f][0][1] as f32;
    // RIC: root-relative in xz, turned by the frame's own root rotation.
    for j in 1..skel.num_joints() {
        let p = global[f][j];
        let local = quat::qrot(r_rot(f), [p[0] - global[f][0][0], p[1], p[2] - global[f][0][2]]);
        let ric = layout.ric().start + (j - 1) * 3;
        row[ric..ric + 3].iter_mut().zip(local).for_each(|(r, v)| *r = v as f32);
        let rot = layout.rot().start + (j - 1) * 6;
        let c6 = quat::to_cont6d(rotations[f][j]);
        row[rot..rot + 6].iter_mut().zip(c6).for_each(|(r, v)| *r = v as f32);
    }
    for j in 0..skel.num_joints() {
        let v = quat::qrot(r_rot(f), quat::sub(global[f + 1][j], global[f][j]));
        for k in 0..3 {
            row[layout.vel().start + j * 3 + k] = v[k] as f32;
        }
    }
    let c = layout.contacts().start;
    let feet = [skel.feet_left[0], skel.feet_left[1], skel.feet_right[0], skel.feet_right[1]];
    for (k, &j) in feet.iter().enumerate() {
        let d = quat::sub(global[f + 1][j], global[f][j]);
        row[c + k] = if quat::dot(d, d) < feet_threshold { 1.0 } else { 0.0 };
    }
}

/// Joint positions put as HumanML3D puts them: the floor at y = 0, the first frame's root at the
/// xz origin, the whole motion turned so that frame 0 faces +Z.
fn canonical(skel: &Skeleton, mut pos: Joints) -> Joints {
    let floor = pos.iter().flatten().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    let init_root = pos[0][0];
    for p in pos.iter_mut().flatten() {
        p[1] -= floor;
        p[0] -= init_root[0];
        p[2] -= init_root[2];
    }
    let fwd0 = facing(skel, &pos[..1].to_vec(), Facing::Consistent)[0];
    let q_init = quat::qbetween(fwd0, [0.0, 0.0, 1.0]);
    for p in pos.iter_mut().flatten() {
        *p = quat::qrot(q_init, *p);
    }
    pos
}

/// Reject sequences `features_from_joints` cannot process, with a reason.
pub fn validate_joints(skel: &Skeleton, joints: &Joints) -> Result<(), DataError> {
    if joints.len() < 2 {
        return Err(DataError::Invalid(format!(
            "motion has {} frame(s); at least 2 are needed to compute velocities",
            joints.len()
        )));
    }
    if let Some(f) = joints.iter().position(|f| f.len() != skel.num_joints()) {
        return Err(DataError::Invalid(format!(
            "frame {f} has {} joints, expected {}",
            joints[f].len(),
            skel.num_joints()
        )));
    }
    if let Some(f) = joints.iter().position(|f| f.iter().flatten().any(|v| !v.is_finite())) {
        return Err(DataError::Invalid(format!("frame {f} contains NaN or infinite values")));
    }
    for (f, frame) in joints.iter().enumerate() {
        check_pose(skel, frame).map_err(|m| DataError::Invalid(format!("frame {f}: {m}")))?;
    }
    Ok(())
}

/// A pose rotations can be told from: no bone of zero length and a body whose facing can be
/// told (hips and shoulders giving a horizontal left-right direction).
pub fn check_pose(skel: &Skeleton, frame: &[Vec3]) -> Result<(), String> {
    for chain in skel.kinematic_chain {
        for w in chain.windows(2) {
            if quat::norm(quat::sub(frame[w[1]], frame[w[0]])) < 1e-6 {
                return Err(format!(
                    "joints {} and {} coincide (a bone of zero length)",
                    skel.joint_names[w[0]], skel.joint_names[w[1]]
                ));
            }
        }
    }
    let [r_hip, l_hip, r_sho, l_sho] = skel.face_joints;
    let across =
        quat::add(quat::sub(frame[r_hip], frame[l_hip]), quat::sub(frame[r_sho], frame[l_sho]));
    if across[0].hypot(across[2]) < 1e-6 {
        return Err("hips and shoulders give no left-right direction on the ground, so the facing is undefined".into());
    }
    Ok(())
}

/// Linear resampling of a joint sequence from `fps_in` to `fps_out` (frame k of the output is
/// at time k / fps_out).
pub fn resample(joints: &Joints, fps_in: f64, fps_out: f64) -> Joints {
    if joints.len() < 2 || (fps_in - fps_out).abs() < 1e-9 {
        return joints.clone();
    }
    let duration = (joints.len() - 1) as f64 / fps_in;
    let n = (duration * fps_out + 1e-9).floor() as usize + 1;
    (0..n)
        .map(|k| {
            let x = k as f64 * fps_in / fps_out;
            let i = (x.floor() as usize).min(joints.len() - 2);
            let a = x - i as f64;
            joints[i]
                .iter()
                .zip(&joints[i + 1])
                .map(|(p, q)| quat::add(quat::scale(*p, 1.0 - a), quat::scale(*q, a)))
                .collect()
        })
        .collect()
}

/// Z-up (AMASS / SMPL world) to Y-up as HumanML3D's `raw_pose_processing` does:
/// (x, y, z) -> (-x, z, y), a proper rotation.
pub fn z_up_to_y_up(joints: &mut Joints) {
    for p in joints.iter_mut().flatten() {
        *p = [-p[0], p[2], p[1]];
    }
}

/// (T, J, 3) array data to a joint sequence, keeping the first `take` joints.
pub fn joints_from_array(data: &[f64], frames: usize, joints: usize, take: usize) -> Joints {
    (0..frames)
        .map(|f| {
            (0..take)
                .map(|j| {
                    let o = (f * joints + j) * 3;
                    [data[o], data[o + 1], data[o + 2]]
                })
                .collect()
        })
        .collect()
}

/// Flatten a joint sequence to (T, J, 3) f32 row-major.
pub fn joints_to_f32(joints: &Joints) -> Vec<f32> {
    joints.iter().flatten().flat_map(|p| p.iter().map(|&v| v as f32)).collect()
}

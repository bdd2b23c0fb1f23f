//! Motions in and out of BVH rigs.
//!
//! **Export** ([`export`]): a T-pose rig with the common joint names (Hips, LeftUpLeg, ...,
//! the names Mixamo, LaFAN1 and most retargeting tools expect), no helper joints, Y up,
//! centimetres. Bone lengths are the motion's own (mean over frames); at the joints with several
//! children (Hips, Spine2) the children's rest offsets are the motion's own configuration, turned
//! to the T-pose, and the joint's rotation per frame is the best rigid fit (Horn's quaternion
//! method). Every other joint turns by the shortest arc from its parent's orientation onto the
//! bone's direction, so twist is inherited, not invented. A rigid motion (every real HumanML3D
//! clip) is reproduced exactly; a generated one, whose bones stretch a little from frame to
//! frame, to within that stretch ([`export_error`]).
//!
//! **Import** ([`import`]): any BVH whose joint names follow a known convention (ours, Mixamo
//! with or without `mixamorig:`, LaFAN1, CMU, our earlier snake_case names) or a rig map,
//! in any units and up axis (stated or detected) and at any frame rate, to the skeleton's joint
//! positions in metres, Y up, at its frame rate.

use crate::io::bvh::{self, Bvh, BvhJoint, Channel};
use crate::motion::quat::{self, Quat, Vec3};
use crate::motion::representation::{resample, Joints};
use crate::motion::skeleton::Skeleton;
use crate::DataError;

use super::rig_names::map_joints;
pub use super::rig_names::T2M_NAMES;

const CM: f64 = 100.0;

/// Names and T-pose bone directions of a skeleton's rig.
pub(crate) struct Rig {
    names: Vec<&'static str>,
    tpose: Vec<Vec3>,
}

/// Direction of the bone ending at each joint in a T-pose facing +Z (left is +X): legs down,
/// feet forward, spine and head up, arms straight out.
const T2M_TPOSE: [Vec3; 22] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.0, 0.0, 1.0],
    [0.0, 1.0, 0.0],
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
];

pub(crate) fn rig(skel: &Skeleton) -> Rig {
    if skel.name == "t2m" {
        Rig { names: T2M_NAMES.to_vec(), tpose: T2M_TPOSE.to_vec() }
    } else {
        Rig { names: skel.joint_names.to_vec(), tpose: skel.raw_offsets.to_vec() }
    }
}

pub(crate) fn children(parents: &[i64], j: usize) -> Vec<usize> {
    (0..parents.len()).filter(|&c| parents[c] == j as i64).collect()
}

/// Largest-eigenvalue eigenvector of a symmetric 4x4 matrix (cyclic Jacobi).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (rp, rq) = (a[p], a[q]);
                a[p] = std::array::from_fn(|k| c * rp[k] - s * rq[k]);
                a[q] = std::array::from_fn(|k| s * rp[k] + c * rq[k]);
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4).max_by(|&i, &j| a[i][i].total_cmp(&a[j][j])).unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

/// The rotation taking the vectors `from` closest onto `to` (least squares; Horn 1987).
pub fn best_rotation(from: &[Vec3], to: &[Vec3]) -> Quat {
    let mut s = [[0.0; 3]; 3];
    for (a, b) in from.iter().zip(to) {
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
    }
    let [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = s;
    let n = [
        [xx + yy + zz, yz - zy, zx - xz, xy - yx],
        [yz - zy, xx - yy - zz, xy + yx, zx + xz],
        [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
        [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
    ];
    quat::qnormalize(top_eigenvector(n))
}

/// Rest offsets (metres) of every joint: T-pose direction times the motion's mean bone length,
/// and at branching joints the motion's own child configuration turned to the T-pose.
pub(crate) fn rest_offsets(skel: &Skeleton, rig: &Rig, joints: &Joints) -> Vec<Vec3> {
    let parents = skel.parents();
    let t = joints.len() as f64;
    let mut rest: Vec<Vec3> = (0..skel.num_joints())
        .map(|c| match parents[c] {
            p if p < 0 => [0.0; 3],
            p => {
                let len =
                    joints.iter().map(|f| quat::norm(quat::sub(f[c], f[p as usize]))).sum::<f64>()
                        / t;
                quat::scale(quat::normalize(rig.tpose[c]), len)
            }
        })
        .collect();
    for b in 0..skel.num_joints() {
        let kids = children(&parents, b);
        if kids.len() < 2 {
            continue;
        }
        let tpose: Vec<Vec3> = kids.iter().map(|&c| rest[c]).collect();
        let mut cur = tpose.clone();
        // Procrustes mean: fit each frame, average the children in the fitted frame, repeat.
        for _ in 0..3 {
            let mut acc = vec![[0.0; 3]; kids.len()];
            for f in joints {
                let actual: Vec<Vec3> = kids.iter().map(|&c| quat::sub(f[c], f[b])).collect();
                let g = quat::qinv(best_rotation(&cur, &actual));
                for (a, v) in acc.iter_mut().zip(&actual) {
                    *a = quat::add(*a, quat::scale(quat::qrot(g, *v), 1.0 / t));
                }
            }
            let turn = quat::qinv(best_rotation(&tpose, &acc));
            cur = acc.iter().map(|v| quat::qrot(turn, *v)).collect();
        }
        for (&c, v) in kids.iter().zip(cur) {
            rest[c] = v;
        }
    }
    rest
}

/// Global rotation of every joint of one frame, given the rest offsets.
pub(crate) fn global_rotations(
    parents: &[i64],
    kids: &[Vec<usize>],
    rest: &[Vec3],
    pose: &[Vec3],
) -> Vec<Quat> {
    let mut g = vec![quat::IDENTITY; pose.len()];
    for j in topological(parents) {
        let base = if parents[j] < 0 { quat::IDENTITY } else { g[parents[j] as usize] };
        g[j] = match kids[j].as_slice() {
            [] => base,
            [c] => {
                let d = quat::sub(pose[*c], pose[j]);
                if quat::norm(d) < 1e-9 {
                    base
                } else {
                    quat::qmul(quat::qbetween(quat::qrot(base, rest[*c]), d), base)
                }
            }
            many => {
                let from: Vec<Vec3> = many.iter().map(|&c| rest[c]).collect();
                let to: Vec<Vec3> = many.iter().map(|&c| quat::sub(pose[c], pose[j])).collect();
                best_rotation(&from, &to)
            }
        };
    }
    g
}

/// Joints with every parent before its children.
pub(crate) fn topological(parents: &[i64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..parents.len()).filter(|&j| parents[j] < 0).collect();
    let mut i = 0;
    while i < order.len() {
        let j = order[i];
        order.extend(children(parents, j));
        i += 1;
    }
    order
}

/// A motion posed on its rig: the rig's joint names and parents, the rest offsets (T-pose
/// directions, the motion's own bone lengths; skeleton units), and per frame the root's place
/// and every joint's rotation relative to its parent (the root's to the world). The BVH and
/// glTF exports both write this.
pub struct PosedRig {
    pub names: Vec<&'static str>,
    pub parents: Vec<i64>,
    pub rest: Vec<Vec3>,
    /// T-pose direction of the bone ending at each joint (where a leaf's end site points).
    pub tpose: Vec<Vec3>,
    pub root: Vec<Vec3>,
    pub local: Vec<Vec<Quat>>,
}

/// Fit `joints` to the skeleton's rig ([`PosedRig`]).
pub fn pose(skel: &Skeleton, joints: &Joints) -> PosedRig {
    let rig = rig(skel);
    let parents = skel.parents();
    let kids: Vec<Vec<usize>> = (0..skel.num_joints()).map(|j| children(&parents, j)).collect();
    let rest = rest_offsets(skel, &rig, joints);
    let local = joints
        .iter()
        .map(|pose| {
            let g = global_rotations(&parents, &kids, &rest, pose);
            (0..g.len())
                .map(|j| match parents[j] {
                    p if p < 0 => g[j],
                    p => quat::qmul(quat::qinv(g[p as usize]), g[j]),
                })
                .collect()
        })
        .collect();
    let root = joints.iter().map(|f| f[0]).collect();
    PosedRig { names: rig.names, parents, rest, tpose: rig.tpose, root, local }
}

/// The motion as a BVH rig (T-pose rest, common names, Y up, centimetres, the skeleton's rate).
pub fn export(skel: &Skeleton, joints: &Joints) -> Bvh {
    let posed = pose(skel, joints);
    let parents = &posed.parents;
    let kids: Vec<Vec<usize>> = (0..skel.num_joints()).map(|j| children(parents, j)).collect();
    let rest = &posed.rest;
    let dfs = depth_first(topological(parents)[0], &kids);
    let slot: Vec<usize> = {
        let mut s = vec![0; skel.num_joints()];
        for (i, &j) in dfs.iter().enumerate() {
            s[j] = i;
        }
        s
    };
    // File units (centimetres) per skeleton unit.
    let k = CM * skel.metres_per_unit;
    let rot = vec![Channel::Rotation(2), Channel::Rotation(1), Channel::Rotation(0)];
    let bvh_joints: Vec<BvhJoint> = dfs
        .iter()
        .map(|&j| {
            let root = parents[j] < 0;
            let channels = if root {
                [
                    vec![Channel::Position(0), Channel::Position(1), Channel::Position(2)],
                    rot.clone(),
                ]
                .concat()
            } else {
                rot.clone()
            };
            let end_site = kids[j].is_empty().then(|| {
                let len = (0.5 * quat::norm(rest[j])).max(0.03 / skel.metres_per_unit);
                quat::scale(quat::normalize(posed.tpose[j]), len * k)
            });
            BvhJoint {
                name: posed.names[j].to_string(),
                parent: (!root).then(|| slot[parents[j] as usize]),
                offset: quat::scale(rest[j], k),
                channels,
                end_site,
            }
        })
        .collect();
    let frames = channel_rows(&posed, &dfs, k);
    Bvh { joints: bvh_joints, frame_time: 1.0 / skel.fps, frames }
}

/// The joints under `j` (itself first) in depth-first order, so that a BVH file lists each
/// subtree in one block.
fn depth_first(j: usize, kids: &[Vec<usize>]) -> Vec<usize> {
    let mut out = vec![j];
    for &c in &kids[j] {
        out.extend(depth_first(c, kids));
    }
    out
}

/// Each frame's channel values in `dfs` order: the root's position (times `k`, file units per
/// skeleton unit) and every joint's ZYX Euler angles, each kept near its previous frame's.
fn channel_rows(posed: &PosedRig, dfs: &[usize], k: f64) -> Vec<Vec<f64>> {
    let mut prev: Vec<Option<[f64; 3]>> = vec![None; posed.parents.len()];
    posed
        .local
        .iter()
        .zip(&posed.root)
        .map(|(local, root)| {
            let mut row = Vec::with_capacity(3 + 3 * dfs.len());
            for &j in dfs {
                if posed.parents[j] < 0 {
                    row.extend(root.iter().map(|v| v * k));
                }
                let e = bvh::zyx_degrees(local[j], prev[j]);
                prev[j] = Some(e);
                row.extend(e);
            }
            row
        })
        .collect()
}

/// BVH text of a motion ([`export`]).
pub fn write(skel: &Skeleton, joints: &Joints) -> String {
    export(skel, joints).to_text()
}

/// Joint positions of BVH text ([`import`]).
pub fn read(skel: &Skeleton, text: &str, opts: &ImportOptions) -> Result<Joints, DataError> {
    import(skel, &Bvh::parse(text)?, opts)
}

/// The joints a BVH of [`export`] places, in the skeleton's order and units.
pub fn exported_positions(skel: &Skeleton, b: &Bvh) -> Result<Joints, DataError> {
    import(
        skel,
        b,
        &ImportOptions { metres_per_unit: Some(1.0 / CM), up: Some(Up::Y), ..Default::default() },
    )
}

/// Mean and largest distance (metres) between a motion and its BVH export's joints.
pub fn export_error(skel: &Skeleton, joints: &Joints, b: &Bvh) -> (f64, f64) {
    let Ok(back) = exported_positions(skel, b) else {
        return (f64::NAN, f64::NAN);
    };
    let d: Vec<f64> = back
        .iter()
        .flatten()
        .zip(joints.iter().flatten())
        .map(|(a, b)| quat::norm(quat::sub(*a, *b)))
        .collect();
    let m = skel.metres_per_unit;
    (m * d.iter().sum::<f64>() / d.len().max(1) as f64, m * d.iter().copied().fold(0.0, f64::max))
}

/// Which way is up in a BVH file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Up {
    Y,
    Z,
    NegY,
    NegZ,
    X,
    NegX,
}

impl Up {
    pub fn parse(s: &str) -> Option<Up> {
        Some(match s.to_ascii_lowercase().as_str() {
            "y" | "+y" => Up::Y,
            "z" | "+z" => Up::Z,
            "-y" => Up::NegY,
            "-z" => Up::NegZ,
            "x" | "+x" => Up::X,
            "-x" => Up::NegX,
            _ => return None,
        })
    }

    /// A rotation taking this up axis to +Y.
    fn to_y(self, p: Vec3) -> Vec3 {
        let [x, y, z] = p;
        match self {
            Up::Y => p,
            Up::Z => [x, z, -y],
            Up::NegZ => [x, -z, y],
            Up::NegY => [x, -y, -z],
            Up::X => [-y, x, z],
            Up::NegX => [y, -x, z],
        }
    }
}

/// How to read a BVH: units and up axis (None: detected), and joint names to use before the
/// known conventions (pairs of a skeleton joint, in either naming, and a joint of the file).
#[derive(Clone, Debug, Default)]
pub struct ImportOptions {
    pub metres_per_unit: Option<f64>,
    pub up: Option<Up>,
    pub rig_map: Vec<(String, String)>,
}

/// Units a file may use, for the error message and detection: (name, metres per unit).
pub const UNITS: [(&str, f64); 4] = [("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("in", 0.0254)];

/// A BVH's motion as the skeleton's joint positions (its units, Y up, its frame rate).
pub fn import(skel: &Skeleton, b: &Bvh, opts: &ImportOptions) -> Result<Joints, DataError> {
    let index = map_joints(skel, b, &opts.rig_map, &rig(skel).names)?;
    let world = b.world_positions();
    let mut joints: Joints = world.iter().map(|f| index.iter().map(|&k| f[k]).collect()).collect();
    if joints.is_empty() {
        return Err(DataError::Invalid("BVH: no frames".into()));
    }
    let scale = match opts.metres_per_unit {
        Some(s) => s,
        None => detect_units(skel, &joints),
    };
    let up = match opts.up {
        Some(u) => u,
        None => detect_up(skel, &joints),
    };
    for p in joints.iter_mut().flatten() {
        *p = up.to_y(quat::scale(*p, scale / skel.metres_per_unit));
    }
    Ok(resample(&joints, 1.0 / b.frame_time, skel.fps))
}

/// Leg length (hip to ankle along the left leg) averaged over frames, in file units.
fn leg_length(skel: &Skeleton, joints: &Joints) -> f64 {
    let parents = skel.parents();
    let mut chain = vec![skel.feet_left[0]];
    while let Some(&j) = chain.last() {
        let p = parents[j];
        if p <= 0 || chain.len() > 2 {
            break;
        }
        chain.push(p as usize);
    }
    joints
        .iter()
        .map(|f| chain.windows(2).map(|w| quat::norm(quat::sub(f[w[0]], f[w[1]]))).sum::<f64>())
        .sum::<f64>()
        / joints.len() as f64
}

/// Metres per unit: the candidate unit giving a leg (hip to ankle) nearest 0.8 m.
fn detect_units(skel: &Skeleton, joints: &Joints) -> f64 {
    let leg = leg_length(skel, joints).max(1e-12);
    UNITS
        .iter()
        .map(|u| u.1)
        .min_by(|a, b| (leg * a / 0.8).ln().abs().total_cmp(&(leg * b / 0.8).ln().abs()))
        .unwrap_or(1.0)
}

/// Up axis: the axis (with sign) along which the head sits furthest above the ankles.
fn detect_up(skel: &Skeleton, joints: &Joints) -> Up {
    let head = skel.joint_names.iter().position(|n| *n == "head").unwrap_or(skel.num_joints() - 1);
    let mut d = [0.0; 3];
    for f in joints {
        let ankles = quat::scale(quat::add(f[skel.feet_left[0]], f[skel.feet_right[0]]), 0.5);
        d = quat::add(d, quat::sub(f[head], ankles));
    }
    let a = (0..3).max_by(|&i, &j| d[i].abs().total_cmp(&d[j].abs())).unwrap_or(1);
    match (a, d[a] >= 0.0) {
        (0, true) => Up::X,
        (0, false) => Up::NegX,
        (2, true) => Up::Z,
        (2, false) => Up::NegZ,
        (_, false) => Up::NegY,
        _ => Up::Y,
    }
}

#[cfg(test)]
#[path = "rig_tests.rs"]
mod tests;

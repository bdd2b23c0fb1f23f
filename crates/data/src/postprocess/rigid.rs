//! One rigid motion: a network predicts joint positions whose bones stretch from frame to
//! frame, which a BVH (fixed offsets, rotations only) cannot represent, so the file an animator
//! imports would not be the motion the page shows. Here every frame is refitted to one
//! skeleton: each joint's global rotation is fitted as the BVH export fits it (the bone's swing,
//! or the best rotation of a joint's several children) and the joints are placed by forward
//! kinematics from the root with fixed bone offsets. Bone directions are kept; lengths become
//! the skeleton's.

use crate::io::rig;
use crate::motion::quat::{self, Vec3};
use crate::motion::representation::{recover_from_ric, recover_root_rot_pos, Joints, Layout};
use crate::motion::skeleton::Skeleton;
use crate::postprocess::floor::{self, FloorReport};

/// What making a motion rigid did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RigidReport {
    /// Largest per-bone standard deviation of bone length before (metres).
    pub bone_std_before_m: f64,
    /// Largest move of any joint (metres).
    pub max_move_m: f64,
    /// Largest move of a joint on a held frame (a pose keyframe; metres).
    pub max_key_move_m: f64,
    /// The body kept on the floor it stood on ([`floor::keep_on_floor`]).
    pub floor: FloorReport,
}

/// The bone offsets every frame is refitted to: those of the held frames (the pose keyframes:
/// the keyed character's own bones, so keyed poses stay where they are) or, with none, the
/// motion's own average bones (`rig`'s rest pose, a Procrustes mean for joints with several
/// children).
pub fn rest(skel: &Skeleton, joints: &Joints, hold: &[bool]) -> Vec<Vec3> {
    let held: Joints =
        joints.iter().zip(hold).filter(|(_, &h)| h).map(|(j, _)| j.clone()).collect();
    let from = if held.is_empty() { joints } else { &held };
    rig::rest_offsets(skel, &rig::rig(skel), from)
}

/// The joints refitted to the bone offsets `rest` ([`rest`]), frame by frame; the root stays.
pub fn rigid_joints(skel: &Skeleton, joints: &Joints, rest: &[Vec3]) -> Joints {
    let parents = skel.parents();
    let kids: Vec<Vec<usize>> =
        (0..skel.num_joints()).map(|j| rig::children(&parents, j)).collect();
    let order = rig::topological(&parents);
    joints
        .iter()
        .map(|pose| {
            let g = rig::global_rotations(&parents, &kids, rest, pose);
            let mut out = pose.clone();
            for &j in &order {
                for &c in &kids[j] {
                    out[c] = quat::add(out[j], quat::qrot(g[j], rest[c]));
                }
            }
            out
        })
        .collect()
}

/// Largest over bones of the standard deviation of the bone's length over frames (in the
/// skeleton's units).
pub fn bone_length_std(skel: &Skeleton, joints: &Joints) -> f64 {
    let parents = skel.parents();
    let t = joints.len().max(1) as f64;
    (0..skel.num_joints())
        .filter(|&c| parents[c] >= 0)
        .map(|c| {
            let l: Vec<f64> = joints
                .iter()
                .map(|f| quat::norm(quat::sub(f[c], f[parents[c] as usize])))
                .collect();
            let mean = l.iter().sum::<f64>() / t;
            (l.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / t).sqrt()
        })
        .fold(0.0, f64::max)
}

/// Make de-normalised features `feats` [T, D] rigid in place: their joints refitted
/// ([`rigid_joints`]), the root-relative positions and local velocities rewritten to match
/// (rotations and contacts unchanged, the root's place and heading too), then kept on the floor
/// the motion stood on ([`floor::keep_on_floor`]: the body lifted, sunk feet raised). `hold`
/// marks pose keyframes: their rows stay as given (their bones are the ones every frame is
/// refitted to), and how far they are from rigid is reported apart.
pub fn make_rigid(skel: &Skeleton, feats: &mut [f32], hold: &[bool]) -> RigidReport {
    let layout = Layout::of(skel);
    let d = layout.dim();
    let t = feats.len() / d;
    let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
    let joints = recover_from_ric(skel, &f64s);
    let (rq, _) = recover_root_rot_pos(&f64s, d);
    let fixed = rigid_joints(skel, &joints, &rest(skel, &joints, hold));
    let unit = skel.metres_per_unit;
    let mut report = RigidReport {
        bone_std_before_m: bone_length_std(skel, &joints) * unit,
        ..Default::default()
    };
    let delta: Vec<Vec<Vec3>> = joints
        .iter()
        .zip(&fixed)
        .map(|(a, b)| a.iter().zip(b).map(|(p, q)| quat::sub(*q, *p)).collect())
        .collect();
    for f in 0..t {
        let next = &delta[(f + 1).min(t - 1)];
        let row = &mut feats[f * d..(f + 1) * d];
        let held = hold.get(f).copied().unwrap_or(false);
        for j in 1..skel.num_joints() {
            let moved = quat::norm(delta[f][j]) * unit;
            report.max_move_m = report.max_move_m.max(moved);
            if held {
                // A keyed row stays as given, velocities included (its bones define the rest).
                report.max_key_move_m = report.max_key_move_m.max(moved);
                continue;
            }
            let ric = quat::qrot(rq[f], delta[f][j]);
            let vel = if f + 1 < t {
                quat::qrot(rq[f], quat::sub(next[j], delta[f][j]))
            } else {
                [0.0; 3]
            };
            for k in 0..3 {
                row[layout.ric().start + (j - 1) * 3 + k] += ric[k] as f32;
                row[layout.vel().start + j * 3 + k] += vel[k] as f32;
            }
        }
    }
    let refit = floor::Refit { before: &joints, after: &fixed, root: &rq, old: &f64s };
    report.floor = floor::keep_on_floor(skel, feats, &refit, hold);
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{io::npy, io::rig, motion::representation as rep, testing::fixtures, T2M};

    fn max_err(a: &Joints, b: &Joints) -> f64 {
        a.iter()
            .flatten()
            .zip(b.iter().flatten())
            .map(|(x, y)| quat::norm(quat::sub(*x, *y)))
            .fold(0.0, f64::max)
    }

    /// A real HumanML3D clip's features (its joints are built on the target skeleton).
    fn real_features() -> Option<Vec<f32>> {
        let p = fixtures::require("humanml3d/new_joint_vecs/012314.npy")?;
        Some(npy::read_f32(p).unwrap().data)
    }

    /// Every bone stretched by its own per-frame factor of up to +-6%, as a network's output is.
    fn stretched(joints: &Joints) -> Joints {
        let parents = T2M.parents();
        let order = rig::topological(&parents);
        joints
            .iter()
            .enumerate()
            .map(|(f, pose)| {
                let mut out = pose.clone();
                for &j in &order {
                    if parents[j] >= 0 {
                        let p = parents[j] as usize;
                        let s = 1.0 + 0.06 * ((f * 7 + j * 13) as f64 * 0.37).sin();
                        let bone = quat::scale(quat::sub(pose[j], pose[p]), s);
                        out[j] = quat::add(out[p], bone);
                    }
                }
                out
            })
            .collect()
    }

    #[test]
    fn real_motion_stays_where_it_is() {
        let Some(mut feats) = real_features() else {
            return;
        };
        let before = rep::recover_from_ric_f32(&T2M, &feats);
        assert!(bone_length_std(&T2M, &before) < 1e-4, "the fixture is rigid");
        let hold = vec![true; before.len()];
        let r = make_rigid(&T2M, &mut feats, &hold);
        assert!(r.max_move_m < 1e-3 && r.max_key_move_m == r.max_move_m, "{r:?}");
    }

    #[test]
    fn stretched_bones_become_one_skeleton_that_a_bvh_reproduces() {
        let Some(feats) = real_features() else {
            return;
        };
        let real = rep::recover_from_ric_f32(&T2M, &feats);
        let loose = stretched(&real);
        assert!(bone_length_std(&T2M, &loose) > 0.005, "the test motion stretches");
        let fixed = rigid_joints(&T2M, &loose, &rest(&T2M, &loose, &[]));
        assert!(bone_length_std(&T2M, &fixed) < 1e-6);
        // Directions are kept, so the refit lands near the unstretched real motion.
        assert!(max_err(&fixed, &real) < 0.05, "{}", max_err(&fixed, &real));
        // The BVH of the rigid motion, read back by plain forward kinematics of its text.
        let text = rig::write(&T2M, &fixed);
        let back =
            rig::exported_positions(&T2M, &crate::io::bvh::Bvh::parse(&text).unwrap()).unwrap();
        assert!(max_err(&back, &fixed) < 1e-3, "BVH off by {} m", max_err(&back, &fixed));
        // The loose motion itself is not reproducible by a BVH: what this module is for.
        let text = rig::write(&T2M, &loose);
        let back =
            rig::exported_positions(&T2M, &crate::io::bvh::Bvh::parse(&text).unwrap()).unwrap();
        assert!(max_err(&back, &loose) > 5e-3);
    }

    #[test]
    fn features_are_rewritten_to_the_rigid_joints() {
        let Some(feats) = real_features() else {
            return;
        };
        let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
        let real = rep::recover_from_ric(&T2M, &f64s);
        // Stretch the features' positions the way `make_rigid` writes them back.
        let loose = stretched(&real);
        let (rq, _) = rep::recover_root_rot_pos(&f64s, 263);
        let mut feats2 = feats.clone();
        for (f, (a, b)) in real.iter().zip(&loose).enumerate() {
            for j in 1..22 {
                let r = quat::qrot(rq[f], quat::sub(b[j], a[j]));
                for k in 0..3 {
                    feats2[f * 263 + 4 + (j - 1) * 3 + k] += r[k] as f32;
                }
            }
        }
        let r = make_rigid(&T2M, &mut feats2, &vec![false; real.len()]);
        assert!(r.bone_std_before_m > 0.005 && r.max_key_move_m == 0.0, "{r:?}");
        let out = rep::recover_from_ric_f32(&T2M, &feats2);
        assert!(bone_length_std(&T2M, &out) < 1e-5, "{}", bone_length_std(&T2M, &out));
        // The root keeps its place and heading; it only rises or sinks with the floor's lift.
        for f in 0..out.len() {
            let d = quat::sub(out[f][0], loose[f][0]);
            assert!(d[0].hypot(d[2]) < 1e-5 && d[1].abs() <= r.floor.lift_m.abs() + 1e-5);
        }
    }

    /// Joints of features `feats` (263 wide) moved by `shift(f, joint)`, written the way
    /// `make_rigid` writes them (root height, root-relative positions).
    fn moved(feats: &[f32], shift: impl Fn(usize, usize) -> Vec3) -> Vec<f32> {
        let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
        let (rq, _) = rep::recover_root_rot_pos(&f64s, 263);
        let mut out = feats.to_vec();
        for (f, q) in rq.iter().enumerate() {
            out[f * 263 + 3] += shift(f, 0)[1] as f32;
            for j in 1..22 {
                let r = quat::qrot(*q, shift(f, j));
                for k in 0..3 {
                    out[f * 263 + 4 + (j - 1) * 3 + k] += r[k] as f32;
                }
            }
        }
        out
    }

    #[test]
    fn a_network_body_refitted_to_the_keyed_bones_stays_on_the_floor() {
        let Some(feats) = real_features() else {
            return;
        };
        let real = rep::recover_from_ric_f32(&T2M, &feats);
        let t = real.len();
        // The network's own body: the real clip with the torso 5 cm lower on the hips (hips
        // 5 cm nearer the pelvis), feet where they were; two keyed rows keep the real body.
        let legs = [1, 2, 4, 5, 7, 8, 10, 11];
        let mut hold = vec![false; t];
        hold[40] = true;
        hold[120] = true;
        let mut net = moved(&feats, |f, j| {
            [0.0, if hold[f] || legs.contains(&j) { 0.0 } else { -0.05 }, 0.0]
        });
        let lowest = |j: &Joints, f: usize| {
            [7, 8, 10, 11].map(|k| j[f][k][1]).into_iter().fold(f64::INFINITY, f64::min)
        };
        // Refitted from the same pelvis alone, the real hips drop the feet 5 cm into the floor.
        let loose = rep::recover_from_ric_f32(&T2M, &net);
        let plain = rigid_joints(&T2M, &loose, &rest(&T2M, &loose, &hold));
        let sunk = (0..t).filter(|&f| lowest(&plain, f) < lowest(&real, f) - 0.04).count();
        assert!(sunk > t * 9 / 10, "{sunk} of {t} frames sunk");
        let r = make_rigid(&T2M, &mut net, &hold);
        let out = rep::recover_from_ric_f32(&T2M, &net);
        // Away from the keys the body is lifted onto its feet; beside them (where the lift
        // fades out) the knees bend, and no foot is under the floor anywhere.
        let far = |f: usize| f.abs_diff(40).min(f.abs_diff(120)) >= floor::LIFT_FADE;
        let worst = (0..t)
            .filter(|&f| far(f))
            .map(|f| (lowest(&out, f) - lowest(&real, f)).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.01, "feet off the real clip's floor by {worst} m; {r:?}");
        let under = (0..t).map(|f| lowest(&real, f).min(0.0) - lowest(&out, f)).fold(0.0, f64::max);
        assert!(under < 0.003, "a foot {under} m under the floor; {r:?}");
        assert!((r.floor.lift_m - 0.05).abs() < 0.01, "{r:?}");
        for f in [40, 120] {
            assert_eq!(&net[f * 263..(f + 1) * 263], &feats[f * 263..(f + 1) * 263]);
        }
    }

    #[test]
    fn a_leg_folded_by_short_bones_bends_its_knee_instead_of_sinking() {
        let Some(feats) = real_features() else {
            return;
        };
        let real = rep::recover_from_ric_f32(&T2M, &feats);
        let (hip, knee, ankle) = (2, 5, 8);
        // Frames 60..68: the right knee drawn 70% of the way to the hip-ankle line, so the
        // thigh and shin are shorter with hip and foot in place (as a network folds a leg).
        let folded = |f: usize| (60..68).contains(&f);
        let net = moved(&feats, |f, j| {
            if !folded(f) || j != knee {
                return [0.0; 3];
            }
            let (h, k, a) = (real[f][hip], real[f][knee], real[f][ankle]);
            let u = quat::normalize(quat::sub(a, h));
            let on_line = quat::add(h, quat::scale(u, quat::dot(quat::sub(k, h), u)));
            quat::scale(quat::sub(on_line, k), 0.7)
        });
        let loose = rep::recover_from_ric_f32(&T2M, &net);
        let plain = rigid_joints(&T2M, &loose, &rest(&T2M, &loose, &[]));
        let sunk = (60..68).map(|f| loose[f][11][1] - plain[f][11][1]).fold(0.0, f64::max);
        assert!(sunk > 0.03, "the plain refit sinks the folded foot {sunk} m");
        let mut out = net.clone();
        let r = make_rigid(&T2M, &mut out, &vec![false; real.len()]);
        let out = rep::recover_from_ric_f32(&T2M, &out);
        assert!(bone_length_std(&T2M, &out) < 1e-4, "{}", bone_length_std(&T2M, &out));
        for f in 60..68 {
            let floor = loose[f][ankle][1].min(loose[f][11][1]).min(0.0);
            let low = out[f][ankle][1].min(out[f][11][1]);
            assert!(low > floor - 0.003, "frame {f}: foot at {low}, floor {floor}; {r:?}");
        }
        assert!(r.floor.raised >= 8 && r.floor.lift_m.abs() < 0.01, "{r:?}");
    }
}

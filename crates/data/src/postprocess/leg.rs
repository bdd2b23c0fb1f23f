//! One leg of a motion in HumanML3D features, as the foot post-processes edit it (the lock,
//! stride warping, pinning): its joints, two-bone IK of the thigh and shin at the frame's own
//! bone lengths, and writing moved knees, ankles and toes back into the features (positions,
//! local velocities, rotations) with held frames untouched.

use crate::motion::quat::{self, Quat, Vec3};
use crate::motion::representation::{Joints, Layout};
use crate::motion::skeleton::Skeleton;

/// One leg's joints, from the hip to the toe.
#[derive(Clone, Copy)]
pub(crate) struct Leg {
    pub hip: usize,
    pub knee: usize,
    pub ankle: usize,
    pub toe: usize,
    /// Index of the toe's contact channel among the 4 contact channels.
    pub contact: usize,
}

impl Leg {
    /// At frame `j` (the frame's own bone lengths: generated motions stretch them a little):
    /// the hip's distance to the ankle moved by `o`, and the thigh and shin together.
    pub fn reach(&self, j: &[Vec3], o: Vec3) -> (f64, f64) {
        let length = quat::norm(quat::sub(j[self.knee], j[self.hip]))
            + quat::norm(quat::sub(j[self.ankle], j[self.knee]));
        (quat::norm(quat::sub(quat::add(j[self.ankle], o), j[self.hip])), length)
    }
}

pub(crate) fn legs(skel: &Skeleton) -> Vec<Leg> {
    let mut out = Vec::new();
    for (feet, contact) in [(skel.feet_left, 1), (skel.feet_right, 3)] {
        let [ankle, toe] = feet;
        for chain in skel.kinematic_chain {
            if let Some(p) = chain.iter().position(|&j| j == ankle) {
                if p >= 2 && chain.get(p + 1) == Some(&toe) {
                    out.push(Leg { hip: chain[p - 2], knee: chain[p - 1], ankle, toe, contact });
                }
            }
        }
    }
    out
}

/// Knee position for a hip `h`, a moved ankle target `a` and the frame's own thigh and shin
/// lengths, bending towards the original knee `k0`; the ankle is pulled in when out of reach.
/// Returns (knee, ankle).
pub(crate) fn two_bone(h: Vec3, k0: Vec3, a0: Vec3, a: Vec3) -> (Vec3, Vec3) {
    let (l1, l2) = (quat::norm(quat::sub(k0, h)), quat::norm(quat::sub(a0, k0)));
    let ha = quat::sub(a, h);
    let dist = quat::norm(ha);
    if dist < 1e-9 || l1 < 1e-9 || l2 < 1e-9 {
        return (k0, a0);
    }
    // Reachable distances; bones too short to tell apart leave no room (the leg stays).
    let (lo, hi) = ((l1 - l2).abs() + 1e-6, (l1 + l2) * (1.0 - 1e-6));
    if lo > hi || !(lo + hi).is_finite() {
        return (k0, a0);
    }
    let u = quat::scale(ha, 1.0 / dist);
    let d = dist.clamp(lo, hi);
    let a = quat::add(h, quat::scale(u, d));
    let along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d);
    let up = (l1 * l1 - along * along).max(0.0).sqrt();
    let hk = quat::sub(k0, h);
    let bend = quat::sub(hk, quat::scale(u, quat::dot(hk, u)));
    let bend = if quat::norm(bend) > 1e-9 { quat::normalize(bend) } else { return (k0, a0) };
    (quat::add(h, quat::add(quat::scale(u, along), quat::scale(bend, up))), a)
}

pub(crate) fn read6(row: &[f64], at: usize) -> Quat {
    quat::from_matrix(quat::cont6d_to_matrix([
        row[at],
        row[at + 1],
        row[at + 2],
        row[at + 3],
        row[at + 4],
        row[at + 5],
    ]))
}

/// New knee, ankle and toe positions (as deltas [knee, ankle, toe] per frame, zero elsewhere)
/// where the ankle moves by `o[f]` (two-bone IK from the hip), and which frames moved; held
/// frames never move.
pub(crate) fn leg_deltas(
    joints: &Joints,
    leg: Leg,
    o: &[Vec3],
    hold: &[bool],
) -> (Vec<[Vec3; 3]>, Vec<bool>) {
    let t = joints.len();
    let mut delta = vec![[[0.0; 3]; 3]; t];
    let mut moved = vec![false; t];
    for f in (0..t).filter(|&f| quat::norm(o[f]) != 0.0 && !hold[f]) {
        let j = &joints[f];
        let (k, a) = two_bone(j[leg.hip], j[leg.knee], j[leg.ankle], quat::add(j[leg.ankle], o[f]));
        let toe_new = quat::add(a, quat::sub(j[leg.toe], j[leg.ankle]));
        delta[f] =
            [quat::sub(k, j[leg.knee]), quat::sub(a, j[leg.ankle]), quat::sub(toe_new, j[leg.toe])];
        moved[f] = true;
    }
    (delta, moved)
}

/// A motion's joints, root rotations and original features, as the leg edits read them.
pub(crate) struct Posed<'a> {
    pub joints: &'a Joints,
    pub root: &'a [Quat],
    pub old: &'a [f64],
}

/// Write a leg's moved knee, ankle and toe (`delta` per frame, `moved` frames) into the
/// features: positions, local velocities and the leg's rotations; held rows stay as they are,
/// velocities included.
pub(crate) fn apply_leg(
    skel: &Skeleton,
    feats: &mut [f32],
    p: &Posed,
    leg: Leg,
    (delta, moved): (&[[Vec3; 3]], &[bool]),
    hold: &[bool],
) {
    let layout = Layout::of(skel);
    let d = layout.dim();
    let t = feats.len() / d;
    let chain = [leg.knee, leg.ankle, leg.toe];
    for f in (0..t).filter(|&f| !hold[f] && (moved[f] || (f + 1 < t && moved[f + 1]))) {
        let row = &mut feats[f * d..(f + 1) * d];
        let next = if f + 1 < t { delta[f + 1] } else { delta[f] };
        for (c, &jt) in chain.iter().enumerate() {
            let ric = quat::qrot(p.root[f], delta[f][c]);
            let vel = quat::qrot(p.root[f], quat::sub(next[c], delta[f][c]));
            for k in 0..3 {
                row[layout.ric().start + (jt - 1) * 3 + k] += ric[k] as f32;
                row[layout.vel().start + jt * 3 + k] += vel[k] as f32;
            }
        }
        if moved[f] {
            let old = &p.old[f * d..(f + 1) * d];
            relocal(skel, &layout, leg, p.root[f], &p.joints[f], &delta[f], old, row);
        }
    }
}

/// Rewrite the local rotations of the knee, ankle and toe slots (HumanML3D stores at a joint the
/// rotation of the bone that ends there) after the thigh and shin turned: each bone's global
/// rotation is turned by the swing from its old to its new direction; the foot keeps its own.
#[allow(clippy::too_many_arguments)]
fn relocal(
    skel: &Skeleton,
    layout: &Layout,
    leg: Leg,
    root: Quat,
    j: &[Vec3],
    delta: &[Vec3; 3],
    old: &[f64],
    row: &mut [f32],
) {
    let chain = skel.kinematic_chain.iter().find(|c| c.contains(&leg.hip)).expect("leg in a chain");
    let rot = |jt: usize| layout.rot().start + (jt - 1) * 6;
    // Global rotations down the chain to the hip slot.
    let mut g = root;
    for &jt in &chain[1..] {
        g = quat::qmul(g, read6(old, rot(jt)));
        if jt == leg.hip {
            break;
        }
    }
    let g_hip = g;
    let g_knee = quat::qmul(g_hip, read6(old, rot(leg.knee)));
    let g_ankle = quat::qmul(g_knee, read6(old, rot(leg.ankle)));
    let g_toe = quat::qmul(g_ankle, read6(old, rot(leg.toe)));
    let (k1, a1) = (quat::add(j[leg.knee], delta[0]), quat::add(j[leg.ankle], delta[1]));
    let thigh = quat::qbetween(quat::sub(j[leg.knee], j[leg.hip]), quat::sub(k1, j[leg.hip]));
    let shin = quat::qbetween(quat::sub(j[leg.ankle], j[leg.knee]), quat::sub(a1, k1));
    let g_knee1 = quat::qmul(thigh, g_knee);
    let g_ankle1 = quat::qmul(shin, g_ankle);
    let locals = [
        (leg.knee, quat::qmul(quat::qinv(g_hip), g_knee1)),
        (leg.ankle, quat::qmul(quat::qinv(g_knee1), g_ankle1)),
        (leg.toe, quat::qmul(quat::qinv(g_ankle1), g_toe)),
    ];
    for (jt, q) in locals {
        let c6 = quat::to_cont6d(q);
        for k in 0..6 {
            row[rot(jt) + k] = c6[k] as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_bone_reaches_and_leaves_degenerate_legs_as_they_are() {
        // A straight leg of two 0.4 m bones bends its knee forward to reach 0.6 m.
        let (h, k0, a0) = ([0.0, 1.0, 0.0], [0.0, 0.6, 0.01], [0.0, 0.2, 0.0]);
        let (k, a) = two_bone(h, k0, a0, [0.0, 0.4, 0.0]);
        assert!((quat::norm(quat::sub(k, h)) - 0.4).abs() < 1e-3);
        assert!((quat::norm(quat::sub(a, k)) - quat::norm(quat::sub(a0, k0))).abs() < 1e-3);
        assert!(k[2] > 0.01 && (a[1] - 0.4).abs() < 1e-9);
        // Bones of 1e-8 m (a collapsed body) have no reachable distance: unchanged, not NaN.
        let tiny = |v: f64| [0.0, v, 0.0];
        assert_eq!(
            two_bone(tiny(3e-8), tiny(2e-8), tiny(1e-8), tiny(0.5)),
            (tiny(2e-8), tiny(1e-8))
        );
        let nan = [f64::NAN; 3];
        assert_eq!(two_bone(h, nan, a0, a0).1, a0);
    }
}

//! Stride warping (as engines retarget locomotion: Unreal's Stride Warping, its retargeter's
//! Speed Planting): a generated walk whose legs step too short for the speed its root moves at
//! glides; scaling each foot's offset from its hip along the travel direction by the factor
//! that stills the stance foot turns the glide into steps, before the foot lock pins them.
//!
//! Per stance span (a toe near the floor, `contacts::low`: a gliding foot is fast, so speed
//! cannot find it), the factor is the one that keeps the toe in place: the hip's travel along
//! the travel direction plus the toe's travel relative to the ankle (the foot rolling over its
//! toe), over the ankle's backward travel relative to its hip; clamped to [`FACTOR_RANGE`],
//! interpolated between spans and smoothed over [`SMOOTH`] frames, faded to 1 over
//! [`KEY_FADE`] frames at held (keyed) frames so keys stay exact. Only the along-travel
//! component of the hip-to-ankle offset scales (sideways and height kept); the thigh and shin
//! are re-solved by two-bone IK at their own lengths, the pelvis lowered where a leg would
//! over-extend (between keys, [`pelvis`]), the ankle clamped beyond that; the root never moves
//! sideways or along the path. Where the legs do not cycle (no span whose foot moves
//! back relative to the hip), nothing changes and the report says so.

use crate::motion::quat::Vec3;
use crate::motion::representation::{recover_from_ric, recover_root_rot_pos, Joints, Layout};
use crate::motion::skeleton::Skeleton;
use crate::motion::travel::travel_directions;
use crate::postprocess::contacts::{self, THRESHOLDS};
use crate::postprocess::leg::{apply_leg, leg_deltas, legs, Leg, Posed};
use crate::postprocess::{key_weights, pelvis, window};

/// Smallest and largest stride factor.
pub const FACTOR_RANGE: (f64, f64) = (0.5, 2.0);
/// Frames over which the factor fades to 1 towards a held frame.
pub const KEY_FADE: usize = 5;
/// Frames the per-frame factor is averaged over.
pub const SMOOTH: usize = 9;
/// A stance whose foot moves back relative to the hip slower than this (m/s), or whose root
/// moves slower, is not a step to scale.
const MIN_SPEED_MPS: f64 = 0.1;

/// One stance span's factor.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StanceWarp {
    pub foot: &'static str,
    pub start: usize,
    pub end: usize,
    /// The root's speed along the travel direction (m/s) and the ankle's backward speed
    /// relative to its hip (m/s) over the span.
    pub root_speed_mps: f64,
    pub foot_speed_mps: f64,
    /// Their ratio, clamped to [`FACTOR_RANGE`].
    pub factor: f64,
}

/// What stride warping did to one motion.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct StrideReport {
    /// Whether any stance was scaled.
    pub warped: bool,
    /// Why nothing was scaled, when nothing was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<&'static str>,
    /// Mean factor over the frames (1 where nothing changed).
    pub mean_factor: f64,
    /// The largest pelvis drop (m) that let an over-extended leg reach its warped place.
    pub pelvis_drop_m: f64,
    pub spans: Vec<StanceWarp>,
    /// The factor per frame (empty where nothing changed).
    #[serde(skip)]
    pub factors: Vec<f64>,
}

impl StrideReport {
    /// Mark the warp undone (the motion was kept unwarped), saying why; the spans stay for
    /// the record.
    pub fn undo(&mut self, why: &'static str) {
        self.warped = false;
        self.note = Some(why);
        self.mean_factor = 1.0;
        self.pelvis_drop_m = 0.0;
        self.factors.clear();
    }
}

/// The along-travel offset of `joint` from the leg's hip at frame `f` (horizontal, units).
fn along(j: &Joints, dirs: &[[f64; 2]], f: usize, hip: usize, joint: usize) -> f64 {
    let (a, h) = (j[f][joint], j[f][hip]);
    (a[0] - h[0]) * dirs[f][0] + (a[2] - h[2]) * dirs[f][1]
}

/// How far `joint` travels along the travel direction over frames `s..=e` (units).
fn travel(j: &Joints, dirs: &[[f64; 2]], (s, e): (usize, usize), joint: usize) -> f64 {
    (s..e)
        .map(|f| {
            let (p, q) = (j[f][joint], j[f + 1][joint]);
            (q[0] - p[0]) * dirs[f][0] + (q[2] - p[2]) * dirs[f][1]
        })
        .sum()
}

/// The stance spans of the motion with their factors (both feet).
fn stances(skel: &Skeleton, j: &Joints, dirs: &[[f64; 2]], legs: &[Leg]) -> Vec<StanceWarp> {
    let (unit, fps) = (skel.metres_per_unit, skel.fps);
    let low = contacts::low(skel, j, &THRESHOLDS);
    let mut out = Vec::new();
    for (leg, on) in legs.iter().zip(&low) {
        for (s, e) in contacts::spans(on).into_iter().filter(|(s, e)| e > s) {
            let secs = (e - s) as f64 / fps;
            let back =
                along(j, dirs, s, leg.hip, leg.ankle) - along(j, dirs, e, leg.hip, leg.ankle);
            let root = travel(j, dirs, (s, e), 0);
            let (foot_speed, root_speed) = (back * unit / secs, root * unit / secs);
            if foot_speed < MIN_SPEED_MPS || root_speed < MIN_SPEED_MPS {
                continue;
            }
            // The toe stays put when the hip's travel, the scaled ankle's travel relative to
            // the hip and the toe's relative to the ankle (the foot rolling over it) cancel.
            let hip = travel(j, dirs, (s, e), leg.hip);
            let roll =
                along(j, dirs, e, leg.ankle, leg.toe) - along(j, dirs, s, leg.ankle, leg.toe);
            let factor = ((hip + roll) / back).clamp(FACTOR_RANGE.0, FACTOR_RANGE.1);
            let foot = if leg.ankle == skel.feet_left[0] { "left" } else { "right" };
            out.push(StanceWarp {
                foot,
                start: s,
                end: e,
                root_speed_mps: root_speed,
                foot_speed_mps: foot_speed,
                factor,
            });
        }
    }
    out
}

/// The factor per frame: the spans' factors at their middles, linear between them and flat
/// beyond, averaged over [`SMOOTH`] frames, faded to 1 towards held frames.
fn factor_curve(spans: &[StanceWarp], hold: &[bool]) -> Vec<f64> {
    let t = hold.len();
    let mut at: Vec<(f64, f64)> =
        spans.iter().map(|s| ((s.start + s.end) as f64 / 2.0, s.factor)).collect();
    at.sort_by(|a, b| a.0.total_cmp(&b.0));
    let raw: Vec<f64> = (0..t)
        .map(|f| {
            let x = f as f64;
            match at.iter().position(|&(m, _)| m >= x) {
                Some(0) => at[0].1,
                None => at[at.len() - 1].1,
                Some(i) => {
                    let ((m0, k0), (m1, k1)) = (at[i - 1], at[i]);
                    k0 + (k1 - k0) * (x - m0) / (m1 - m0).max(1e-9)
                }
            }
        })
        .collect();
    key_weights(hold, KEY_FADE)
        .iter()
        .enumerate()
        .map(|(f, w)| {
            let win = &raw[window(f, SMOOTH, t)];
            let k = win.iter().sum::<f64>() / win.len() as f64;
            1.0 + (k - 1.0) * w
        })
        .collect()
}

/// Warp the strides of de-normalised features `feats` [T, D] in place; `hold[f]` marks frames
/// that must not change (pose keyframes).
pub fn warp_strides(skel: &Skeleton, feats: &mut [f32], hold: &[bool]) -> StrideReport {
    let d = Layout::of(skel).dim();
    let t = feats.len() / d;
    if t < 3 {
        return StrideReport {
            note: Some("too short to have strides"),
            mean_factor: 1.0,
            ..Default::default()
        };
    }
    let w = Walk::of(skel, feats);
    let spans = stances(skel, &w.joints, &w.dirs, &legs(skel));
    if spans.is_empty() {
        return StrideReport {
            note: Some(
                "the legs do not cycle: no stance whose foot moves back under a moving root",
            ),
            mean_factor: 1.0,
            ..Default::default()
        };
    }
    let k = factor_curve(&spans, hold);
    let pelvis_drop_m = w.scale(skel, feats, hold, &k);
    let mean_factor = k.iter().sum::<f64>() / t as f64;
    StrideReport { warped: true, note: None, mean_factor, pelvis_drop_m, spans, factors: k }
}

/// Scale each ankle's along-travel offset from its hip by `k[f]` at frame f (the knee by IK,
/// the toe with the ankle, the pelvis lowered where a leg would over-extend); held frames stay.
/// Returns the largest pelvis drop (m).
pub fn scale_strides(skel: &Skeleton, feats: &mut [f32], hold: &[bool], k: &[f64]) -> f64 {
    Walk::of(skel, feats).scale(skel, feats, hold, k)
}

/// A motion's features as numbers, its joints and its travel directions, read once for both
/// finding the stances and scaling them.
struct Walk {
    f64s: Vec<f64>,
    joints: Joints,
    dirs: Vec<[f64; 2]>,
}

impl Walk {
    fn of(skel: &Skeleton, feats: &[f32]) -> Walk {
        let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
        let joints = recover_from_ric(skel, &f64s);
        let dirs = travel_directions(skel, &joints);
        Walk { f64s, joints, dirs }
    }

    /// [`scale_strides`] of the motion this walk was read from (`feats`), the pelvis lowered
    /// where a leg would over-extend ([`pelvis`]); returns the largest drop (m).
    fn scale(&self, skel: &Skeleton, feats: &mut [f32], hold: &[bool], k: &[f64]) -> f64 {
        let (rq, _) = recover_root_rot_pos(&self.f64s, Layout::of(skel).dim());
        let legs = legs(skel);
        let offsets: Vec<Vec<Vec3>> = legs
            .iter()
            .map(|leg| {
                (0..self.joints.len())
                    .map(|f| {
                        let a =
                            along(&self.joints, &self.dirs, f, leg.hip, leg.ankle) * (k[f] - 1.0);
                        [a * self.dirs[f][0], 0.0, a * self.dirs[f][1]]
                    })
                    .collect()
            })
            .collect();
        let drop = pelvis::drop(skel, &self.joints, &legs, &offsets, hold);
        let joints = pelvis::lowered(&self.joints, &drop);
        pelvis::lower(skel, feats, &drop, hold);
        let posed = Posed { joints: &joints, root: &rq, old: &self.f64s };
        for (leg, o) in legs.iter().zip(offsets) {
            // The ankle's place stays where the unlowered leg put it.
            let o: Vec<Vec3> = o.iter().zip(&drop).map(|(o, &h)| [o[0], o[1] + h, o[2]]).collect();
            let (delta, moved) = leg_deltas(&joints, *leg, &o, hold);
            apply_leg(skel, feats, &posed, *leg, (&delta, &moved), hold);
        }
        drop.iter().copied().fold(0.0, f64::max) * skel.metres_per_unit
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::plausibility::foot_skating_ratio;
    use crate::motion::quat;
    use crate::motion::representation::{
        features_from_joints, recover_from_ric_f32, FOOT_CONTACT_THRESHOLD,
    };
    use crate::T2M;

    /// A synthetic forward walk's joints.
    fn walk() -> Joints {
        for i in 0..400 {
            let (c, f) = diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 3, i);
            if c.meta.actions.len() == 1 && c.meta.actions[0].action == "walk_forward" {
                return recover_from_ric_f32(&T2M, &f);
            }
        }
        panic!("a walk among the first synthetic clips")
    }

    /// The walk with each leg's forward offset from its hip scaled by `s` (the root untouched):
    /// a simulated glide, as a network that steps too short makes.
    fn glide(j: &Joints, s: f64) -> Vec<f32> {
        let mut f = features_from_joints(&T2M, j, FOOT_CONTACT_THRESHOLD).unwrap();
        let t = f.len() / T2M.feature_dim();
        scale_strides(&T2M, &mut f, &vec![false; t], &vec![s; t]);
        f
    }

    fn joints(f: &[f32]) -> Joints {
        recover_from_ric_f32(&T2M, f)
    }

    #[test]
    fn a_shortened_stride_is_stretched_back() {
        let real = walk();
        let real_skate = foot_skating_ratio(&T2M, &real);
        for s in [0.6, 0.8] {
            let mut f = glide(&real, s);
            let before = foot_skating_ratio(&T2M, &joints(&f));
            let t = f.len() / T2M.feature_dim();
            let rep = warp_strides(&T2M, &mut f, &vec![false; t]);
            let after_j = joints(&f);
            let after = foot_skating_ratio(&T2M, &after_j);
            assert!(rep.warped, "{rep:?}");
            // The factors undo the scaling: about 1 / s.
            let mean = rep.spans.iter().map(|w| w.factor).sum::<f64>() / rep.spans.len() as f64;
            eprintln!("stride scale {s}: foot skating {before:.3} -> {after:.3} (the walk's own {real_skate:.3}), mean factor {mean:.3} over {} spans", rep.spans.len());
            assert!((mean - 1.0 / s).abs() < 0.25 / s, "scale {s}: mean factor {mean}");
            assert!(
                after < before && after <= (1.5 * real_skate).max(0.05),
                "scale {s}: {before} -> {after} (real {real_skate})"
            );
            // Bones keep their lengths; the root stays on its path, lowered at most a little.
            let bj = joints(&glide(&real, s));
            for (a, b) in after_j.iter().zip(&bj) {
                let (ra, rb) = (a[0], b[0]);
                assert!((ra[0] - rb[0]).abs() < 1e-6 && (ra[2] - rb[2]).abs() < 1e-6);
                assert!((-1e-6..=pelvis::MAX_DROP_M).contains(&(rb[1] - ra[1])));
                for (p, c) in [(1usize, 4usize), (4, 7), (2, 5), (5, 8)] {
                    let l = |j: &Vec<Vec3>| quat::norm(quat::sub(j[c], j[p]));
                    assert!((l(a) - l(b)).abs() < 1e-4);
                }
            }
        }
    }

    #[test]
    fn held_frames_stay_and_a_still_motion_is_left_alone() {
        let real = walk();
        let mut f = glide(&real, 0.7);
        let orig = f.clone();
        let t = f.len() / T2M.feature_dim();
        let d = T2M.feature_dim();
        let hold: Vec<bool> = (0..t).map(|i| i == t / 2).collect();
        warp_strides(&T2M, &mut f, &hold);
        assert_eq!(f[t / 2 * d..(t / 2 + 1) * d], orig[t / 2 * d..(t / 2 + 1) * d]);
        // Standing still: nothing cycles, nothing changes.
        let still: Joints = (0..40).map(|_| real[0].clone()).collect();
        let mut sf = features_from_joints(&T2M, &still, FOOT_CONTACT_THRESHOLD).unwrap();
        let before = sf.clone();
        let free = vec![false; sf.len() / d];
        let rep = warp_strides(&T2M, &mut sf, &free);
        assert!(!rep.warped && rep.note.is_some() && sf == before, "{rep:?}");
    }

    #[test]
    fn an_overextended_leg_lowers_the_pelvis_between_keys_and_reaches() {
        let real = walk();
        let f0 = features_from_joints(&T2M, &real, FOOT_CONTACT_THRESHOLD).unwrap();
        let t = f0.len() / T2M.feature_dim();
        let hold: Vec<bool> = (0..t).map(|f| f == 0 || f == t / 2).collect();
        // A stride 1.3x the walk's own: its feet land further than its legs reach.
        let k: Vec<f64> = (0..t).map(|f| if hold[f] { 1.0 } else { 1.3 }).collect();
        let mut f = f0.clone();
        let drop = scale_strides(&T2M, &mut f, &hold, &k);
        assert!(drop > 0.01 && drop <= pelvis::MAX_DROP_M + 1e-9, "drop {drop}");
        let (a, b) = (joints(&f), &joints(&f0));
        let dirs = travel_directions(&T2M, b);
        let mut reached = 0;
        for fr in (0..t).filter(|&fr| !hold[fr]) {
            let dy = b[fr][0][1] - a[fr][0][1];
            assert!((-1e-6..=pelvis::MAX_DROP_M + 1e-6).contains(&dy), "frame {fr}: drop {dy}");
            for (p, c) in [(1usize, 4usize), (4, 7), (2, 5), (5, 8)] {
                let l = |j: &Vec<Vec3>| quat::norm(quat::sub(j[c], j[p]));
                assert!((l(&a[fr]) - l(&b[fr])).abs() < 1e-4, "frame {fr}: bone {p}-{c}");
            }
            // Where the drop was not capped, each ankle lies where the factor puts it.
            let want = |ankle: usize, hip: usize| {
                let o = along(b, &dirs, fr, hip, ankle) * 0.3;
                [
                    b[fr][ankle][0] + o * dirs[fr][0],
                    b[fr][ankle][1],
                    b[fr][ankle][2] + o * dirs[fr][1],
                ]
            };
            let miss = [(7usize, 1usize), (8, 2)]
                .iter()
                .map(|&(an, hp)| quat::norm(quat::sub(a[fr][an], want(an, hp))))
                .fold(0.0, f64::max);
            if dy < pelvis::MAX_DROP_M - 1e-3 && miss < 1e-3 {
                reached += 1;
            }
        }
        // Keys unchanged; the frames the fade leaves undropped near them are the only misses.
        for fr in (0..t).filter(|&fr| hold[fr]) {
            let d = T2M.feature_dim();
            assert_eq!(f[fr * d..(fr + 1) * d], f0[fr * d..(fr + 1) * d]);
        }
        let free = hold.iter().filter(|h| !**h).count();
        eprintln!("stride 1.3x: pelvis drop up to {drop:.3} m; {reached} of {free} free frames put both ankles within 1 mm of their warped places");
        assert!(reached as f64 >= 0.95 * free as f64, "{reached} of {free} frames reach");
    }
}

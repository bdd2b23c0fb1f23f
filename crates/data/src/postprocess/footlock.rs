//! Foot locking: after the keyframe fit, a planted foot (by the network's contact channel, or
//! by the motion's geometry: `contacts`) is held still on the ground plane and its leg reaches
//! it by two-bone IK (`leg`; motion contacts are pinned by `pin`).
//! Generated walks slide their planted feet (foot skating); this removes the slide without
//! touching the root, so keyed places and headings stay exact, and it leaves held frames
//! (the pose keyframes) unchanged.

use crate::motion::plausibility::skates;
use crate::motion::quat::{self, Vec3};
use crate::motion::representation::{recover_from_ric, recover_root_rot_pos, Joints, Layout};
use crate::motion::skeleton::Skeleton;
use crate::postprocess::contacts;
use crate::postprocess::leg::{apply_leg, leg_deltas, legs, Leg, Posed};
pub use crate::postprocess::pin::Outcome;
use crate::postprocess::pin::{self, fade_beside, moves_to};
use crate::postprocess::{key_weights, steps};
use std::ops::RangeInclusive;

/// A toe contact channel above this marks its foot planted.
pub const CONTACT: f32 = 0.5;
/// Frames over which a lock's offset fades out before and after a planted span (0.2 s).
pub const BLEND: usize = 4;
/// Largest move of a planted foot (metres): a span that slides further than twice this is not
/// a planted step but a dragged foot; it is left as it is and counted in
/// [`LockReport::dragged`]. What keeps a lock from stretching the leg is the reach test
/// ([`REACH_SLACK_M`]); on the reference model caps of 0.5 and 1.0 m lock the same spans.
pub const MAX_SHIFT_M: f64 = 0.5;

/// How far short of its anchor a held foot may stay (metres): a span is locked only if at every
/// frame the leg, straightened if need be, reaches within this of the anchor (two-bone IK pulls
/// an out-of-reach foot in along the hip-ankle line, which is a slide of that size). Spans
/// needing more are left as they are and counted in [`LockReport::out_of_reach`]: holding them
/// would stretch the leg straight and still slide.
pub const REACH_SLACK_M: f64 = 0.02;

/// A toe raised more than this (metres) counts as lifted in [`LockReport::lifted`].
const LIFTED_M: f64 = 0.005;

/// What locking did to one motion.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct LockReport {
    /// Frames (per foot, summed) whose foot was moved.
    pub frames: usize,
    /// Largest horizontal move of a foot (metres): how far the motion's own feet slid.
    pub max_shift_m: f64,
    /// Planted spans left unlocked because their foot slides more than a step can absorb.
    pub dragged: usize,
    /// Planted spans left unlocked because the leg could reach the held foot only straight.
    pub out_of_reach: usize,
    /// Planted spans left unlocked because holding them would make the foot skate more.
    pub worse: usize,
    /// Frames (per foot, summed) whose toe was lifted off the floor in a swing (`steps`).
    pub lifted: usize,
    /// Largest lowering of the pelvis that lets the legs reach held stances (m; `steps`).
    pub pelvis_drop_m: f64,
    /// Why the post-process asked for was replaced by another (`fit::hold_feet`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// Every planted span, with how far its toe slid before and after locking.
    pub spans: Vec<PlantSpan>,
}

impl LockReport {
    /// One leg's spans and moves: its toe per frame, the knee, ankle and toe deltas per frame
    /// and which frames moved (`unit`: metres per skeleton unit).
    fn add_leg(
        &mut self,
        (foot, source): (&'static str, ContactSource),
        spans: &[(usize, usize, Outcome)],
        toe: &[Vec3],
        (delta, moved): (&[[Vec3; 3]], &[bool]),
        unit: f64,
    ) {
        let count = |o: Outcome| spans.iter().filter(|s| s.2 == o).count();
        self.worse += count(Outcome::Worse);
        self.dragged += count(Outcome::Dragged);
        self.out_of_reach += count(Outcome::OutOfReach);
        self.frames += moved.iter().filter(|&&m| m).count();
        let most = delta.iter().map(|d| quat::norm(d[1]) * unit).fold(0.0, f64::max);
        self.max_shift_m = self.max_shift_m.max(most);
        self.spans.extend(spans.iter().map(|&(start, end, outcome)| PlantSpan {
            foot,
            source,
            warp_factor: 1.0,
            start,
            end,
            outcome,
            drift_before_m: drift(|f| toe[f], start, end, unit),
            drift_after_m: drift(|f| quat::add(toe[f], delta[f][2]), start, end, unit),
        }));
    }
}

/// Where the planted spans come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactSource {
    /// The motion's own geometry: a toe or ankle low and slow (`contacts::detect`).
    #[default]
    Motion,
    /// The network's foot-contact channels (HumanML3D's speed-only labels: a glide counts).
    Network,
    /// The motion's gait: a toe low and slow, or low and slower than the pelvis; the swing
    /// between held stances lifted off the floor where it would skate (`steps`).
    Gait,
}

/// One planted span of one foot: frames `start..=end` whose toe the motion labels in contact.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PlantSpan {
    pub foot: &'static str,
    pub source: ContactSource,
    /// The stride warp's factor at the span's middle (1 without stride warping).
    pub warp_factor: f64,
    pub start: usize,
    pub end: usize,
    pub outcome: Outcome,
    /// Largest horizontal distance of the toe from its place at the span's first frame
    /// (metres), before and after locking.
    pub drift_before_m: f64,
    pub drift_after_m: f64,
}

/// Horizontal offset of one foot per frame: inside a planted span, from its toe to the span's
/// anchor (the toe's mean place, or its place at the nearest held frame, so held frames get 0);
/// outside, the span-end offsets fading over up to `blend` free frames. Spans needing a move
/// over `max_shift`, or a move `reachable(frame, offset)` refuses, are skipped; returns the
/// offsets and every span (first frame, last frame, outcome).
fn offsets(
    toe: &[Vec3],
    planted: &[bool],
    hold: &[bool],
    blend: usize,
    max_shift: f64,
    reachable: impl Fn(usize, Vec3) -> bool,
) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>) {
    let t = toe.len();
    let mut o = vec![[0.0; 3]; t];
    let mut spans = Vec::new();
    for (s, e) in contacts::spans(planted) {
        let mean = (s..=e).fold([0.0; 3], |a, f| quat::add(a, toe[f]));
        let span = moves_to(toe, hold, (s, e), quat::scale(mean, 1.0 / (e - s + 1) as f64));
        if span.iter().any(|v| quat::norm(*v) > max_shift) {
            spans.push((s, e, Outcome::Dragged));
            continue;
        }
        if span.iter().enumerate().any(|(i, v)| !hold[s + i] && !reachable(s + i, *v)) {
            spans.push((s, e, Outcome::OutOfReach));
            continue;
        }
        spans.push((s, e, Outcome::Locked));
        o[s..=e].copy_from_slice(&span);
        fade_beside(&mut o, (s, e), blend, |f| !planted[f] && !hold[f]);
    }
    (o, spans)
}

/// Largest horizontal distance (metres) of `toe` over `start..=end` from its place at `start`.
fn drift(toe: impl Fn(usize) -> Vec3, start: usize, end: usize, unit: f64) -> f64 {
    let a = toe(start);
    (start..=end).map(toe).map(|p| (p[0] - a[0]).hypot(p[2] - a[2]) * unit).fold(0.0, f64::max)
}

/// Toe steps (frame f to f + 1, f in `range`) that skate with the toe moved by `o`
/// (`plausibility::skates`: the foot skating measure's own test).
fn skating(skel: &Skeleton, toe: &[Vec3], o: &[Vec3], range: RangeInclusive<usize>) -> usize {
    range
        .filter(|&f| f + 1 < toe.len())
        .filter(|&f| {
            let (a, b) = (quat::add(toe[f], o[f]), quat::add(toe[f + 1], o[f + 1]));
            skates(skel, a, b) == Some(true)
        })
        .count()
}

/// The offsets `plan` makes of the planted spans, less the spans whose hold would make the toe
/// skate on more frames of the span and its fades than it does unheld (a slow slide pinned
/// catches up where the hold fades, on the ground, faster than it slid), and none at all if
/// the foot would still skate more overall. Without a lift heights never change, so the foot
/// skating ratio of the motion never rises; a lift takes frames off the floor, so its caller
/// compares ratios (`fit::hold_feet`).
fn no_worse(
    skel: &Skeleton,
    toe: &[Vec3],
    planted: &[bool],
    fade: usize,
    plan: impl Fn(&[bool]) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>),
) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>) {
    let t = toe.len();
    let zero = vec![[0.0; 3]; t];
    let (o, spans) = plan(planted);
    let held = |o: &Outcome| matches!(o, Outcome::Locked | Outcome::Faded);
    let worse: Vec<(usize, usize)> = spans
        .iter()
        .filter(|(s, e, out)| {
            let w = s.saturating_sub(fade + 1)..=(e + fade).min(t - 1);
            held(out) && skating(skel, toe, &o, w.clone()) > skating(skel, toe, &zero, w)
        })
        .map(|&(s, e, _)| (s, e))
        .collect();
    let (o, mut spans) = if worse.is_empty() {
        (o, spans)
    } else {
        let mut kept = planted.to_vec();
        worse.iter().for_each(|&(s, e)| kept[s..=e].fill(false));
        let (o, mut spans) = plan(&kept);
        spans.extend(worse.iter().map(|&(s, e)| (s, e, Outcome::Worse)));
        spans.sort_by_key(|s| s.0);
        (o, spans)
    };
    if skating(skel, toe, &o, 0..=t - 1) > skating(skel, toe, &zero, 0..=t - 1) {
        spans.iter_mut().filter(|s| held(&s.2)).for_each(|s| s.2 = Outcome::Worse);
        return (zero, spans);
    }
    (o, spans)
}

/// One leg's motion, as planning its offsets reads it.
struct Planner<'a> {
    skel: &'a Skeleton,
    joints: &'a Joints,
    leg: Leg,
    toe: &'a [Vec3],
    hold: &'a [bool],
    source: ContactSource,
}

impl Planner<'_> {
    /// The network's spans, each held whole or left (a leg reaching within `slack`).
    fn network(
        &self,
        planted: &[bool],
        blend: usize,
        max_shift: f64,
        slack: f64,
    ) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>) {
        let reachable = |f: usize, o: Vec3| {
            let (wanted, length) = self.leg.reach(&self.joints[f], o);
            wanted <= length + slack
        };
        offsets(self.toe, planted, self.hold, blend, max_shift, reachable)
    }

    /// The motion's spans pinned with the reach fall-off (`pin`); for the gait, each stance cut
    /// to what the leg holds fully and the swings lifted (`steps`).
    fn motion(
        &self,
        planted: &[bool],
        max_shift: f64,
        lift_weights: &[f64],
    ) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>) {
        let weight = |f: usize, o: Vec3| {
            let (wanted, length) = self.leg.reach(&self.joints[f], o);
            pin::reach_weight(wanted / length.max(1e-9))
        };
        let (toe, hold) = (self.toe, self.hold);
        if self.source != ContactSource::Gait {
            return pin::offsets(toe, planted, hold, pin::BLEND, max_shift, weight);
        }
        let planted = steps::trim(toe, planted, hold, |f, o| weight(f, o) >= 1.0);
        let (mut o, spans) = pin::offsets(toe, &planted, hold, pin::BLEND, max_shift, weight);
        steps::lift(self.skel, toe, &mut o, lift_weights, &planted);
        (o, spans)
    }
}

/// Lock the planted feet of de-normalised features `feats` [T, D] in place. `hold[f]` marks
/// frames that must not change (pose keyframes). Positions, local velocities and the leg's
/// rotations are updated together; the root and the contact labels are not touched.
pub fn lock_feet(
    skel: &Skeleton,
    feats: &mut [f32],
    hold: &[bool],
    blend: usize,
    max_shift_m: f64,
    source: ContactSource,
) -> LockReport {
    let layout = Layout::of(skel);
    let d = layout.dim();
    let t = feats.len() / d;
    let mut report = LockReport::default();
    if t < 2 {
        return report;
    }
    let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
    let joints = recover_from_ric(skel, &f64s);
    let (rq, _) = recover_root_rot_pos(&f64s, d);
    let unit = skel.metres_per_unit;
    let slack = REACH_SLACK_M / unit;
    // The motion's own contacts, found once for both feet where they are asked for.
    let detected = match source {
        ContactSource::Network => None,
        ContactSource::Motion => Some(contacts::detect(skel, &joints, &contacts::THRESHOLDS)),
        ContactSource::Gait => Some(steps::stances(skel, &joints, &contacts::THRESHOLDS)),
    };
    let lift_weights = key_weights(hold, pin::BLEND);
    for (li, leg) in legs(skel).into_iter().enumerate() {
        let toe: Vec<Vec3> = joints.iter().map(|j| j[leg.toe]).collect();
        let planted: Vec<bool> = match &detected {
            None => (0..t)
                .map(|f| feats[f * d + layout.contacts().start + leg.contact] > CONTACT)
                .collect(),
            Some(found) => found[li].clone(),
        };
        let planner = Planner { skel, joints: &joints, leg, toe: &toe, hold, source };
        let plan = |planted: &[bool]| match source {
            ContactSource::Network => planner.network(planted, blend, max_shift_m / unit, slack),
            _ => planner.motion(planted, max_shift_m / unit, &lift_weights),
        };
        let fade = if source == ContactSource::Network { blend } else { pin::BLEND };
        let (o, spans) = no_worse(skel, &toe, &planted, fade, plan);
        report.lifted += o.iter().filter(|v| v[1] * unit > LIFTED_M).count();
        let (delta, moved) = leg_deltas(&joints, leg, &o, hold);
        let foot = if leg.contact == 1 { "left" } else { "right" };
        report.add_leg((foot, source), &spans, &toe, (&delta, &moved), unit);
        let posed = Posed { joints: &joints, root: &rq, old: &f64s };
        apply_leg(skel, feats, &posed, leg, (&delta, &moved), hold);
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::plausibility::foot_skating_ratio;
    use crate::motion::quat::Vec3;
    use crate::motion::representation::{features_from_joints, recover_from_ric_f32};
    use crate::postprocess::leg::read6;
    use crate::T2M;

    /// A synthetic walk's features, and the same with its planted feet sliding forward.
    fn walk() -> Vec<f32> {
        let mut clip = None;
        for i in 0..400 {
            let (c, f) = diffkfc_synth::clip(diffkfc_synth::Body::Legacy, 3, i);
            if c.meta.actions.len() == 1 && c.meta.actions[0].action == "walk_forward" {
                clip = Some(f);
                break;
            }
        }
        clip.expect("a walk among the first synthetic clips")
    }

    fn joints(skel: &Skeleton, f: &[f32]) -> crate::motion::representation::Joints {
        recover_from_ric_f32(skel, f)
    }

    #[test]
    fn nothing_planted_or_all_held_is_identity() {
        let f = walk();
        let layout = Layout::of(&T2M);
        let (d, t) = (layout.dim(), f.len() / layout.dim());
        let mut none = f.clone();
        for r in 0..t {
            none[r * d + layout.contacts().start..(r + 1) * d].iter_mut().for_each(|v| *v = 0.0);
        }
        let before = none.clone();
        assert_eq!(
            lock_feet(&T2M, &mut none, &vec![false; t], BLEND, MAX_SHIFT_M, ContactSource::Network)
                .frames,
            0
        );
        assert_eq!(none, before);
        let mut held = f.clone();
        lock_feet(&T2M, &mut held, &vec![true; t], BLEND, MAX_SHIFT_M, ContactSource::Network);
        assert_eq!(held, f);
    }

    /// The synthetic walk with its lower legs swung back and forth along z by `amplitude`
    /// metres over `period` frames, keeping the clean clip's contact labels (the slide would
    /// erase them): its planted feet skate.
    fn sliding_walk(amplitude: f64, period: f64) -> Vec<f32> {
        let clean = walk();
        let layout = Layout::of(&T2M);
        let d = layout.dim();
        let mut j = joints(&T2M, &clean);
        for (f, frame) in j.iter_mut().enumerate() {
            for &k in &[4usize, 5, 7, 8, 10, 11] {
                frame[k][2] += amplitude * (std::f64::consts::TAU * f as f64 / period).sin();
            }
        }
        let mut sliding =
            features_from_joints(&T2M, &j, crate::motion::representation::FOOT_CONTACT_THRESHOLD)
                .unwrap();
        let c = layout.contacts();
        for r in 0..(sliding.len() / d).min(clean.len() / d) {
            sliding[r * d + c.start..r * d + c.end]
                .copy_from_slice(&clean[r * d + c.start..r * d + c.end]);
        }
        sliding
    }

    #[test]
    fn sliding_planted_feet_are_held_and_stay_consistent() {
        let layout = Layout::of(&T2M);
        let d = layout.dim();
        // 6 cm at 2 Hz: planted feet skate at up to 0.75 m/s.
        let sliding = sliding_walk(0.06, 10.0);
        let t1 = sliding.len() / d;
        let hold: Vec<bool> = (0..t1).map(|f| f == t1 / 2).collect();
        let before_j = joints(&T2M, &sliding);
        let skate0 = foot_skating_ratio(&T2M, &before_j);
        let mut locked = sliding.clone();
        let rep = lock_feet(&T2M, &mut locked, &hold, BLEND, MAX_SHIFT_M, ContactSource::Network);
        let after_j = joints(&T2M, &locked);
        let skate1 = foot_skating_ratio(&T2M, &after_j);
        assert!(
            rep.frames > 0 && rep.dragged == 0 && skate0 > 0.3 && skate1 < 0.1,
            "skating {skate0} -> {skate1}, {rep:?}"
        );
        // Locked spans are pinned where the leg reaches (to 1 mm) and within the reach slack
        // where it reaches only straight, from a slide of centimetres; joint velocities stay
        // continuous at the spans' ends (the toe's acceleration no larger than the slide's).
        let locked_spans: Vec<&PlantSpan> =
            rep.spans.iter().filter(|s| s.outcome == Outcome::Locked).collect();
        assert!(
            !locked_spans.is_empty() && locked_spans.len() + rep.out_of_reach == rep.spans.len()
        );
        for s in &locked_spans {
            assert!(s.drift_after_m < REACH_SLACK_M, "{s:?}");
        }
        // This walk's stance legs are nearly straight, so the reach (not the anchor) bounds the
        // pin: on average the slide shrinks more than tenfold.
        let mean = |f: fn(&PlantSpan) -> f64| {
            locked_spans.iter().map(|s| f(s)).sum::<f64>() / locked_spans.len() as f64
        };
        let (before, after) = (mean(|s| s.drift_before_m), mean(|s| s.drift_after_m));
        assert!(after * 10.0 < before, "drift {before} -> {after} m");
        assert!(locked_spans.iter().any(|s| s.drift_before_m > 0.02), "{locked_spans:?}");
        let accel = |j: &[Vec<Vec3>], f: usize, k: usize| {
            let v = |f: usize| quat::sub(j[f + 1][k], j[f][k]);
            quat::norm(quat::sub(v(f + 1), v(f)))
        };
        for s in &locked_spans {
            for f in [s.start.saturating_sub(2), s.start, s.end.saturating_sub(1), s.end] {
                if f + 2 < t1 {
                    let k = if s.foot == "left" { 10 } else { 11 };
                    let worst = (0..t1 - 2).map(|g| accel(&before_j, g, k)).fold(0.0, f64::max);
                    assert!(accel(&after_j, f, k) <= worst * 1.05, "{s:?} frame {f}");
                }
            }
        }
        // The held frame, the root and the upper body are untouched.
        let row = |v: &[f32], f: usize| v[f * d..(f + 1) * d].to_vec();
        assert_eq!(row(&locked, t1 / 2), row(&sliding, t1 / 2));
        for f in 0..t1 {
            assert_eq!(locked[f * d..f * d + 4], sliding[f * d..f * d + 4]);
            for k in [0usize, 3, 6, 9, 12, 15, 16, 17, 20, 21] {
                assert_eq!(after_j[f][k], before_j[f][k]);
            }
        }
        // Bone lengths hold, planted toes move less than 0.5 m/s, and the rotation slots agree
        // with the new positions: each bone's global rotation takes its rest direction to it.
        for (f, (a, b)) in after_j.iter().zip(&before_j).enumerate() {
            for (p, c) in [(1usize, 4usize), (4, 7), (7, 10), (2, 5), (5, 8), (8, 11)] {
                let l = |j: &Vec<Vec3>| quat::norm(quat::sub(j[c], j[p]));
                assert!((l(a) - l(b)).abs() < 1e-5, "frame {f} bone {p}-{c}");
            }
            let r = row(&locked, f).iter().map(|&v| v as f64).collect::<Vec<_>>();
            let rot = |jt: usize| read6(&r, layout.rot().start + (jt - 1) * 6);
            let (rq, _) =
                recover_root_rot_pos(&locked.iter().map(|&v| v as f64).collect::<Vec<_>>(), d);
            let g4 = quat::qmul(quat::qmul(rq[f], rot(1)), rot(4));
            let g7 = quat::qmul(g4, rot(7));
            for (g, p, c) in [(g4, 1usize, 4usize), (g7, 4, 7)] {
                let dir = quat::normalize(quat::sub(a[c], a[p]));
                let want = quat::qrot(g, T2M.raw_offsets[c]);
                assert!(
                    quat::norm(quat::sub(dir, want)) < 1e-3,
                    "frame {f} bone {p}-{c}: {dir:?} vs {want:?}"
                );
            }
        }
        // Local velocities match the positions they describe (but at the held frame, kept as is).
        for f in (0..t1 - 1).filter(|&f| !hold[f]) {
            let (rq, _) =
                recover_root_rot_pos(&locked.iter().map(|&v| v as f64).collect::<Vec<_>>(), d);
            let v = quat::qrot(rq[f], quat::sub(after_j[f + 1][10], after_j[f][10]));
            for k in 0..3 {
                assert!(
                    (locked[f * d + layout.vel().start + 30 + k] as f64 - v[k]).abs() < 1e-4,
                    "frame {f}"
                );
            }
        }
    }

    #[test]
    fn offsets_fade_and_respect_held_frames() {
        let toe: Vec<Vec3> = (0..20).map(|f| [0.0, 0.0, 0.05 * f as f64]).collect();
        let planted: Vec<bool> = (0..20).map(|f| (5..=10).contains(&f)).collect();
        let mut hold = vec![false; 20];
        let any = |_: usize, _: Vec3| true;
        let (o, spans) = offsets(&toe, &planted, &hold, 4, 1.0, any);
        assert_eq!(spans, vec![(5, 10, Outcome::Locked)]);
        // Planted frames land on their mean place; the fade is monotone and ends at zero.
        for f in 5..=10 {
            assert!((toe[f][2] + o[f][2] - 0.375).abs() < 1e-12);
        }
        assert!(
            o[11][2].abs() < o[10][2].abs()
                && o[14][2].abs() < o[11][2].abs()
                && o[15] == [0.0; 3]
                && o[0] == [0.0; 3]
        );
        hold[8] = true;
        let (o, _) = offsets(&toe, &planted, &hold, 4, 1.0, any);
        assert_eq!(o[8], [0.0; 3]);
        assert!((toe[5][2] + o[5][2] - toe[8][2]).abs() < 1e-12);
        // A foot dragged 25 cm over the span is not a planted step: left alone.
        let (o, spans) = offsets(&toe, &planted, &[false; 20], 4, 0.1, any);
        assert_eq!((spans, o), (vec![(5, 10, Outcome::Dragged)], vec![[0.0; 3]; 20]));
        // A span the leg cannot reach at one of its frames is left alone; held frames are not
        // asked (they do not move).
        let short = |f: usize, _: Vec3| f != 9;
        let (o, spans) = offsets(&toe, &planted, &[false; 20], 4, 1.0, short);
        assert_eq!((spans, o), (vec![(5, 10, Outcome::OutOfReach)], vec![[0.0; 3]; 20]));
        let mut hold9 = vec![false; 20];
        hold9[9] = true;
        let (_, spans) = offsets(&toe, &planted, &hold9, 4, 1.0, short);
        assert_eq!(spans, vec![(5, 10, Outcome::Locked)]);
        // A span right after a held frame keeps the foot where that frame has it: no snap.
        let mut hold4 = vec![false; 20];
        hold4[4] = true;
        let (o, _) = offsets(&toe, &planted, &hold4, 4, 1.0, any);
        for f in 5..=10 {
            assert!((toe[f][2] + o[f][2] - toe[4][2]).abs() < 1e-12, "frame {f}");
        }
    }

    /// A stance leg pulled past its reach: the lock leaves the span rather than straighten it.
    #[test]
    fn unreachable_spans_are_left_alone() {
        // 40 cm: to hold the feet, the legs would have to reach far past their length.
        let mut sliding = sliding_walk(0.4, 20.0);
        let t1 = sliding.len() / Layout::of(&T2M).dim();
        let rep =
            lock_feet(&T2M, &mut sliding, &vec![false; t1], BLEND, 2.0, ContactSource::Network);
        assert!(rep.out_of_reach > 0, "{rep:?}");
    }

    #[test]
    fn a_hold_that_would_skate_more_is_left() {
        // A toe on the ground gliding along z at `speed` m/s; frames 10..=40 planted.
        let toe = |speed: f64| -> Vec<Vec3> {
            (0..60).map(|f| [0.0, 0.01, speed / T2M.fps * f as f64]).collect()
        };
        let planted: Vec<bool> = (0..60).map(|f| (10..=40).contains(&f)).collect();
        let hold = vec![false; 60];
        let zero = vec![[0.0; 3]; 60];
        for (speed, want) in [(0.25, Outcome::Worse), (0.8, Outcome::Locked)] {
            let toe = toe(speed);
            let plan = |p: &[bool]| pin::offsets(&toe, p, &hold, pin::BLEND, 10.0, |_, _| 1.0);
            let (o, spans) = no_worse(&T2M, &toe, &planted, pin::BLEND, plan);
            assert_eq!(spans, vec![(10, 40, want)], "{speed} m/s");
            let (before, after) =
                (skating(&T2M, &toe, &zero, 0..=59), skating(&T2M, &toe, &o, 0..=59));
            eprintln!("glide {speed} m/s: skating steps {before} unheld, {after} with the guard");
            assert!(after <= before);
            if want == Outcome::Worse {
                // Held, its 0.25 m/s slide would be caught up at about 0.7 m/s in the fades.
                let (o, _) = plan(&planted);
                assert!(skating(&T2M, &toe, &o, 0..=59) > before);
            } else {
                // The span's 30 steps are still; the fades were skating already.
                assert!(after + 30 <= before, "{after} of {before}");
            }
        }
    }
}

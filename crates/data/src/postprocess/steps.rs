//! Steps out of a shuffle (`--feet steps`). A network that barely swings its legs keeps its
//! toes on the floor while they slide along at about the body's speed (the reference models'
//! keyed walks: toes low on 80-97% of the frames at 0.5-0.7 m/s; their sources: 67% at 0.05),
//! so nothing in it is slow enough to be a contact and pinning finds little to hold. Here a
//! stance is also a stretch where the toe is low and moves slower than the pelvis (a stance
//! foot falls behind the hip; in a real walk it stands still), it is pinned (`pin`), and where
//! the foot then catches up faster than a planted foot may slide (the foot skating measure's
//! 0.5 m/s) it is lifted clear of the floor: a swing. The foot keeps its own orientation and
//! the knee is re-solved (`leg`); held frames and the root are untouched.

use crate::motion::plausibility::skates;
use crate::motion::quat::{self, Vec3};
use crate::motion::representation::{recover_from_ric, recover_root_rot_pos, Joints, Layout};
use crate::motion::skeleton::Skeleton;
use crate::postprocess::contacts::{self, drop_short, Thresholds, THRESHOLDS};
use crate::postprocess::leg::{apply_leg, leg_deltas, legs, Posed};
use crate::postprocess::{pelvis, pin};

/// A stance starts where a low toe moves slower than this share of the pelvis's speed ...
pub const SLOWER: f64 = 0.8;
/// ... and ends where it moves faster than the pelvis.
pub const FASTER: f64 = 1.0;
/// Frames over which the pelvis's speed is averaged (a stride's sway cancels).
const PELVIS_WINDOW: usize = 9;
/// A toe that would skate is lifted to this height above the floor (metres): above the foot
/// skating measure's 5 cm, the height of a real swing's toe early and late in the swing.
pub const CLEARANCE_M: f64 = 0.06;
/// The largest lift (metres): a toe sunk far below the floor is not pulled out of it.
pub const MAX_LIFT_M: f64 = 0.12;
/// The lift spreads this many frames either side of the frames that need it and is smoothed
/// over as many, so the foot rises and lands in a few frames rather than popping.
pub const SPREAD: usize = 2;
/// The longest swing (frames, 0.8 s; a walk's swing lasts about 0.4 s): a toe that would
/// skate for longer is a glide, and lifted it would hover; it is left on the floor.
pub const MAX_SWING: usize = 16;
/// The largest lowering of the pelvis for stances (m): the evaluator's FID rises with a
/// crouch (docs/feet.md), so less than the stride warp's.
pub const MAX_DROP_M: f64 = 0.06;
/// A toe slower than this (m/s) on the floor stands (the planted share's test).
pub const STILL_MPS: f64 = 0.15;
/// Holds that move the toe less than this (metres) never lower the pelvis.
pub const SLIP_M: f64 = 0.05;
/// A stance set into a glide lasts this many frames (0.35 s) ...
pub const STEP_STANCE: usize = 7;
/// ... and is followed by a swing of about this many.
pub const STEP_SWING: usize = 7;

/// Per frame whether each foot ([left, right]) stands: low and slow (`contacts::detect`), or
/// low and slower than the pelvis (a stance of a gliding gait), and in every glide longer than
/// a swing, stances set at even steps (`split_glides`).
pub fn stances(skel: &Skeleton, j: &Joints, th: &Thresholds) -> [Vec<bool>; 2] {
    let t = j.len();
    let speed = |joint: usize, f: usize| contacts::ground_speed(skel, j, joint, f);
    let pelvis: Vec<f64> = (0..t)
        .map(|f| {
            let w = super::window(f, PELVIS_WINDOW, t);
            w.clone().map(|g| speed(0, g)).sum::<f64>() / w.len() as f64
        })
        .collect();
    let slow = contacts::detect(skel, j, th);
    let low = contacts::low(skel, j, th);
    let feet = [skel.feet_left[1], skel.feet_right[1]];
    let mut out = [Vec::new(), Vec::new()];
    for (k, toe) in feet.into_iter().enumerate() {
        let gliding = contacts::hysteresis(
            t,
            |f| low[k][f] && speed(toe, f) < th.speed_on_mps.max(SLOWER * pelvis[f]),
            |f| low[k][f] && speed(toe, f) < th.speed_off_mps.max(FASTER * pelvis[f]),
        );
        let mut both: Vec<bool> = (0..t).map(|f| slow[k][f] || gliding[f]).collect();
        // The foot skating measure's own test: its floor is absolute.
        let sliding: Vec<bool> = (0..t)
            .map(|f| f + 1 < t && skates(skel, j[f][toe], j[f + 1][toe]) == Some(true))
            .collect();
        split_glides(&mut both, &sliding);
        out[k] = drop_short(both, th.min_frames);
    }
    out
}

/// Lower the pelvis of de-normalised features [T, D] where holding the stances still would
/// take a leg past its reach (`pelvis::drop`, spread and faded towards held frames, capped at
/// [`MAX_DROP_M`]), the feet kept where they were by bending the knees; returns the largest drop (m).
/// A network that shuffles keeps its legs nearly straight, so without it a held foot can
/// barely fall behind the hip before the reach fall-off lets it go.
pub fn lower_for_stances(skel: &Skeleton, feats: &mut [f32], hold: &[bool], max_shift: f64) -> f64 {
    let old: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
    let j = recover_from_ric(skel, &old);
    let (rq, _) = recover_root_rot_pos(&old, Layout::of(skel).dim());
    let found = stances(skel, &j, &THRESHOLDS);
    let legs = legs(skel);
    let full = |_: usize, _: Vec3| 1.0;
    let offsets: Vec<Vec<Vec3>> = legs
        .iter()
        .enumerate()
        .map(|(k, leg)| {
            let toe: Vec<Vec3> = j.iter().map(|p| p[leg.toe]).collect();
            let unit = skel.metres_per_unit;
            let (o, _) = pin::offsets(&toe, &found[k], hold, pin::BLEND, max_shift / unit, full);
            // A hold that moves the toe a few centimetres is a real stance's roll over the
            // toe, left to the leg's own reach: only a glide held still lowers the body.
            o.into_iter()
                .map(|v| if quat::norm(v) * unit < SLIP_M { [0.0; 3] } else { v })
                .collect()
        })
        .collect();
    let cap = MAX_DROP_M / skel.metres_per_unit;
    let drop: Vec<f64> =
        pelvis::drop(skel, &j, &legs, &offsets, hold).into_iter().map(|h| h.min(cap)).collect();
    if drop.iter().all(|&h| h == 0.0) {
        return 0.0;
    }
    let lowered = pelvis::lowered(&j, &drop);
    pelvis::lower(skel, feats, &drop, hold);
    let posed = Posed { joints: &lowered, root: &rq, old: &old };
    let back: Vec<Vec3> = drop.iter().map(|&h| [0.0, h, 0.0]).collect();
    for leg in legs {
        let (delta, moved) = leg_deltas(&lowered, leg, &back, hold);
        apply_leg(skel, feats, &posed, leg, (&delta, &moved), hold);
    }
    drop.iter().copied().fold(0.0, f64::max) * skel.metres_per_unit
}

/// One foot's stances cut to the frames where the leg can hold the toe fully at the stance's
/// place (`fits(frame, move)`; the place is the toe's at the middle of what is left, or at a
/// held frame in or beside it): past that the hold would give way and the toe slide on the
/// floor, so those frames become swing instead (lifted where they would skate).
pub fn trim(
    toe: &[Vec3],
    planted: &[bool],
    hold: &[bool],
    fits: impl Fn(usize, Vec3) -> bool,
) -> Vec<bool> {
    let mut out = planted.to_vec();
    for (s, e) in contacts::spans(planted) {
        let (mut a, mut b) = (s, e);
        // The place moves with the middle as the ends are cut: a few rounds settle it.
        for _ in 0..4 {
            let want = pin::moves_to(toe, hold, (a, b), toe[(a + b) / 2]);
            let ok = |i: usize| hold[a + i] || fits(a + i, want[i]);
            let m = (b - a) / 2;
            if !ok(m) {
                (a, b) = (usize::MAX, 0);
                break;
            }
            let lo = (0..m).rev().take_while(|&i| ok(i)).count();
            let hi = (m + 1..=b - a).take_while(|&i| ok(i)).count();
            let (na, nb) = (a + m - lo, a + m + hi);
            if (na, nb) == (a, b) {
                break;
            }
            (a, b) = (na, nb);
        }
        (s..=e).filter(|f| !(a..=b).contains(f)).for_each(|f| out[f] = false);
    }
    drop_short(out, THRESHOLDS.min_frames)
}

/// Stances set into every glide (a run of `sliding` frames outside `stance`, longer than a
/// swing): [`STEP_STANCE`] frames every [`STEP_STANCE`] + [`STEP_SWING`], evenly spread, so
/// that the pinning holds the foot there and the lift carries it between them.
fn split_glides(stance: &mut [bool], sliding: &[bool]) {
    let glide: Vec<bool> = (0..stance.len()).map(|f| sliding[f] && !stance[f]).collect();
    for (s, e) in contacts::spans(&glide) {
        let n = e + 1 - s;
        if n <= MAX_SWING {
            continue;
        }
        let steps = (n as f64 / (STEP_STANCE + STEP_SWING) as f64).round().max(1.0) as usize;
        for i in 0..steps {
            let centre = s + (2 * i + 1) * n / (2 * steps);
            let first = centre.saturating_sub(STEP_STANCE / 2).max(s);
            stance[first..(first + STEP_STANCE).min(e + 1)].fill(true);
        }
    }
}

/// Add to one foot's offsets `o` (toe moved by `o[f]`) the heights of its steps, scaled by
/// `weight[f]` (0 on held frames, rising away from them): on `planted` frames of a stance that
/// was a glide (its hold moves the toe [`SLIP_M`] or more) the toe is pressed down to the floor
/// (the toe's lowest height, not below 0: a stance does not hover); elsewhere,
/// and on a stance's first frame (a toe that arrives fast lands a frame later), it is lifted
/// wherever it would skate, each such frame raised to [`CLEARANCE_M`], spread over
/// [`SPREAD`] free frames either side and smoothed; runs of such frames longer than
/// [`MAX_SWING`] (less gaps of a frame) are glides and left on the floor. Lifting never makes a
/// step skate: only a toe on the floor can.
pub fn lift(skel: &Skeleton, toe: &[Vec3], o: &mut [Vec3], weight: &[f64], planted: &[bool]) {
    let t = toe.len();
    let unit = skel.metres_per_unit;
    let first = |f: usize| planted[f] && (f == 0 || !planted[f - 1]);
    let need = needs(skel, toe, o, |f| !planted[f] || first(f));
    // Only swing frames spread their lift: a stance's first frame rises by itself alone.
    let swing: Vec<f64> = (0..t).map(|f| if planted[f] { 0.0 } else { need[f] }).collect();
    let smooth = spread(&swing);
    let floor = toe.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min).max(0.0);
    // Only a stance that was a glide held still is pressed down: one that stood by itself
    // keeps the height its motion gave it (a flat foot's toe stands higher than a tiptoe's).
    let mut press = vec![false; t];
    for (s, e) in contacts::spans(planted) {
        let held = (s..=e).map(|f| o[f][0].hypot(o[f][2])).fold(0.0, f64::max);
        press[s..=e].fill(held * unit >= SLIP_M);
    }
    // A toe standing on the floor beside a swing stays where it stands.
    let still = |a: usize, b: usize| {
        let (p, q) = (quat::add(toe[a], o[a]), quat::add(toe[b], o[b]));
        (q[0] - p[0]).hypot(q[2] - p[2]) * unit * skel.fps < STILL_MPS
    };
    let standing: Vec<bool> = (0..t)
        .map(|f| {
            (toe[f][1] + o[f][1]) * unit < CLEARANCE_M
                && (f == 0 || still(f - 1, f))
                && (f + 1 == t || still(f, f + 1))
        })
        .collect();
    for f in 0..t {
        let h = if first(f) {
            need[f]
        } else if !planted[f] && !standing[f] {
            smooth[f]
        } else if press[f] {
            (floor - toe[f][1] - o[f][1]).min(0.0)
        } else {
            0.0
        };
        o[f][1] += h * weight[f];
    }
}

/// Per frame the rise (skeleton units) that takes the toe (moved by `o`) to [`CLEARANCE_M`]
/// where its step into that frame would skate and `may(frame)`; nothing on runs of such frames
/// (joined across single-frame gaps) longer than [`MAX_SWING`].
fn needs(skel: &Skeleton, toe: &[Vec3], o: &[Vec3], may: impl Fn(usize) -> bool) -> Vec<f64> {
    let t = toe.len();
    let unit = skel.metres_per_unit;
    let at = |f: usize| quat::add(toe[f], o[f]);
    let mut need: Vec<f64> = (0..t)
        .map(|f| {
            let skating = f > 0 && may(f) && skates(skel, at(f - 1), at(f)) == Some(true);
            if skating {
                (CLEARANCE_M / unit - at(f)[1]).clamp(0.0, MAX_LIFT_M / unit)
            } else {
                0.0
            }
        })
        .collect();
    let wanted: Vec<bool> = (0..t)
        .map(|f| need[f] > 0.0 || (f > 0 && f + 1 < t && need[f - 1] > 0.0 && need[f + 1] > 0.0))
        .collect();
    for (s, e) in contacts::spans(&wanted) {
        if e + 1 - s > MAX_SWING {
            need[s..=e].fill(0.0);
        }
    }
    need
}

/// `need` spread over [`SPREAD`] frames either side (a running maximum) and smoothed by a
/// triangle kernel as wide: the spread is flat over the whole kernel around a frame that needs
/// a rise, so that frame keeps all of it.
fn spread(need: &[f64]) -> Vec<f64> {
    let t = need.len();
    let width = 2 * SPREAD + 1;
    let peak: Vec<f64> =
        (0..t).map(|f| super::window(f, width, t).map(|g| need[g]).fold(0.0, f64::max)).collect();
    let tri = |f: usize, g: usize| (SPREAD + 1 - f.abs_diff(g)) as f64;
    (0..t)
        .map(|f| {
            let w = super::window(f, width, t);
            let norm: f64 = w.clone().map(|g| tri(f, g)).sum();
            w.map(|g| peak[g] * tri(f, g)).sum::<f64>() / norm
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::postprocess::contacts::THRESHOLDS;
    use crate::T2M;

    use crate::testing::feet::feet_motion as motion;

    #[test]
    fn a_toe_gliding_slower_than_the_pelvis_stands_a_faster_or_lifted_one_does_not() {
        let glide = |v: f64| move |f: usize| [0.1, 0.0, v * f as f64 / 20.0];
        // 0.6 m/s under a pelvis at 0.9: a stance (speed alone would not find it).
        let s = stances(&T2M, &motion(0.9, glide(0.6)), &THRESHOLDS);
        assert!(s[0].iter().all(|&c| c) && s[1].iter().all(|&c| c));
        assert!(contacts::detect(&T2M, &motion(0.9, glide(0.6)), &THRESHOLDS)[0]
            .iter()
            .all(|&c| !c));
        // Faster than a still pelvis, or than a moving one: not a stance of the gait, but a
        // glide longer than a swing, into which stances are set: 3 of 7 frames in 40.
        for (pelvis, toe) in [(0.0, 0.6), (0.5, 0.9)] {
            let set = &stances(&T2M, &motion(pelvis, glide(toe)), &THRESHOLDS)[0];
            let runs = contacts::spans(set);
            assert_eq!(runs.iter().map(|(s, e)| e + 1 - s).collect::<Vec<_>>(), [7; 3]);
            assert!(runs.windows(2).all(|w| w[1].0 - w[0].1 > 5), "{runs:?}");
        }
        // A slide as short as a swing is left to the lift.
        let short =
            stances(&T2M, &motion(0.0, |f| [0.1, 0.0, 0.05 * f.min(10) as f64]), &THRESHOLDS);
        assert!((0..10).all(|f| !short[0][f]));
        // Slow but 20 cm up on frames 10..30: no stance there.
        let up = stances(
            &T2M,
            &motion(0.9, |f| [0.1, if (10..30).contains(&f) { 0.2 } else { 0.0 }, 0.03]),
            &THRESHOLDS,
        );
        assert!((0..10).chain(30..40).all(|f| up[0][f]) && (10..30).all(|f| !up[0][f]));
    }

    #[test]
    fn a_sliding_toe_is_lifted_clear_smoothly_and_only_near_the_slide() {
        // A toe on the floor, still but for a slide of 5 cm a frame (1 m/s) over frames 15..25.
        let toe: Vec<Vec3> =
            (0..40).map(|f| [0.0, 0.02, 0.05 * (f.clamp(15, 25) - 15) as f64]).collect();
        let mut o = vec![[0.0; 3]; 40];
        lift(&T2M, &toe, &mut o, &[1.0; 40], &[false; 40]);
        let at = |f: usize| quat::add(toe[f], o[f]);
        assert!((1..40).all(|f| skates(&T2M, at(f - 1), at(f)) != Some(true)));
        // Only heights change; frames beyond the spread of the slide stay as they were.
        assert!(o.iter().all(|v| v[0] == 0.0 && v[2] == 0.0 && v[1] >= 0.0));
        let near = 16 - 2 * SPREAD..=25 + 2 * SPREAD;
        assert!((0..40).filter(|f| !near.contains(f)).all(|f| o[f][1] == 0.0), "{o:?}");
        // A standing toe stays down, so the foot rises and lands within a frame, as a real
        // toe does at 20 fps (about 5 cm a frame at toe-off): here by at most the 4 cm it needs.
        assert!(o.windows(2).all(|w| (w[1][1] - w[0][1]).abs() <= 0.04 + 1e-12), "{o:?}");
        // A held frame (weight 0) is not lifted, and the lift fades beside it.
        let w: Vec<f64> = (0..40).map(|f| if f == 20 { 0.0 } else { 1.0 }).collect();
        let mut held = vec![[0.0; 3]; 40];
        lift(&T2M, &toe, &mut held, &w, &[false; 40]);
        assert_eq!(held[20], [0.0; 3]);
        // A toe sliding for longer than a swing glides: lifting it would make it hover.
        let glide: Vec<Vec3> = (0..40).map(|f| [0.0, 0.02, 0.05 * f as f64]).collect();
        let mut left = vec![[0.0; 3]; 40];
        lift(&T2M, &glide, &mut left, &[1.0; 40], &[false; 40]);
        assert!(left.iter().all(|v| *v == [0.0; 3]));
        // A toe lifting by itself or standing still needs nothing.
        let mut none = vec![[0.0; 3]; 40];
        let high: Vec<Vec3> = toe.iter().map(|p| [p[0], 0.3, p[2]]).collect();
        lift(&T2M, &high, &mut none, &[1.0; 40], &[false; 40]);
        assert!(none.iter().all(|v| *v == [0.0; 3]));
        // A stance that stood by itself keeps its heights; one that glided and is held (its
        // hold moves the toe 6 cm) is pressed to the floor (here 2 cm, the toe's lowest).
        let mut toe = toe;
        toe[30][1] = 0.05;
        let planted: Vec<bool> = (0..40).map(|f| f >= 28).collect();
        let mut stood = vec![[0.0; 3]; 40];
        lift(&T2M, &toe, &mut stood, &[1.0; 40], &planted);
        assert!((28..40).all(|f| stood[f] == [0.0; 3]));
        let mut pressed = vec![[0.0; 3]; 40];
        pressed[29][2] = 0.06;
        lift(&T2M, &toe, &mut pressed, &[1.0; 40], &planted);
        assert!((pressed[30][1] + 0.03).abs() < 1e-12 && pressed[35][1] == 0.0);
        assert!((28..40).all(|f| pressed[f][1] <= 0.0));
    }
}

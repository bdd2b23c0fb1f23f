//! Pinning planted spans found in the motion's geometry (`--feet warp|pin`): one target per
//! span, the toe's place at its middle frame (or at a held frame in or beside it), and a reach
//! fall-off instead of the all-or-nothing reach test: where holding the foot would take the leg
//! past [`REACH_FULL`] of its length the hold weakens, to nothing at [`REACH_NONE`], so the foot
//! gives way gradually rather than the whole span being dropped or the leg snapping straight.

use crate::motion::quat::{self, Vec3};
use crate::postprocess::contacts::spans;
use crate::postprocess::smoothstep;

/// What became of one planted span.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Locked,
    /// Held as far as the leg reaches (`pin`'s reach fall-off weakened the hold).
    Faded,
    Dragged,
    OutOfReach,
    /// Left as it was: holding it would move the toe faster on the ground, where the hold
    /// fades in and out, than its slide did (more foot skating, not less).
    Worse,
}

/// Up to this fraction of the leg's length a target is held fully ...
pub const REACH_FULL: f64 = 0.97;
/// ... and from this fraction not at all.
pub const REACH_NONE: f64 = 0.99;
/// Frames over which a pin fades in and out beside its span (0.25 s).
pub const BLEND: usize = 5;

/// The offsets at a span's ends (`s..=e`) faded out into up to `blend` frames on each side,
/// stopping at the first frame that is not `free` (held or planted).
pub fn fade_beside(
    o: &mut [Vec3],
    (s, e): (usize, usize),
    blend: usize,
    free: impl Fn(usize) -> bool,
) {
    let t = o.len();
    let after = (1..=blend).take_while(|&i| e + i < t && free(e + i)).count();
    for i in 1..=after {
        let w = smoothstep(1.0 - i as f64 / (after + 1) as f64);
        o[e + i] = quat::add(o[e + i], quat::scale(o[e], w));
    }
    let before = (1..=blend).take_while(|&i| i <= s && free(s - i)).count();
    for i in 1..=before {
        let w = smoothstep(1.0 - i as f64 / (before + 1) as f64);
        o[s - i] = quat::add(o[s - i], quat::scale(o[s], w));
    }
}

/// Per frame of the span `s..=e`, the toe's horizontal move to `anchor`, or to the toe's place
/// at the nearest held frame in the span or right beside it: the foot stays where a key put it
/// (a span that starts after a pose key must not snap away from the key's foot).
pub fn moves_to(toe: &[Vec3], hold: &[bool], (s, e): (usize, usize), anchor: Vec3) -> Vec<Vec3> {
    let held: Vec<usize> =
        (s.saturating_sub(1)..=(e + 1).min(hold.len() - 1)).filter(|&f| hold[f]).collect();
    (s..=e)
        .map(|f| {
            let at = held.iter().min_by_key(|&&k| k.abs_diff(f)).map_or(anchor, |&k| toe[k]);
            [at[0] - toe[f][0], 0.0, at[2] - toe[f][2]]
        })
        .collect()
}

/// How much of a hold a leg can take: 1 up to [`REACH_FULL`] of its length, 0 from
/// [`REACH_NONE`], smooth between. `reach` is the hip-to-target distance over the leg's length.
pub fn reach_weight(reach: f64) -> f64 {
    1.0 - smoothstep((reach - REACH_FULL) / (REACH_NONE - REACH_FULL))
}

/// Horizontal offset of one foot per frame: inside a planted span towards its target, weighted
/// by `weight(frame, offset)` (the reach fall-off); outside, faded over up to `blend` free
/// frames. Spans needing a move over `max_shift` are dragged feet, left alone. Returns the
/// offsets and every span with its outcome (`Faded` where the reach weakened the hold).
pub fn offsets(
    toe: &[Vec3],
    planted: &[bool],
    hold: &[bool],
    blend: usize,
    max_shift: f64,
    weight: impl Fn(usize, Vec3) -> f64,
) -> (Vec<Vec3>, Vec<(usize, usize, Outcome)>) {
    let t = toe.len();
    let mut o = vec![[0.0; 3]; t];
    let mut out = Vec::new();
    for (s, e) in spans(planted) {
        let want = moves_to(toe, hold, (s, e), toe[(s + e) / 2]);
        if want.iter().any(|v| quat::norm(*v) > max_shift) {
            out.push((s, e, Outcome::Dragged));
            continue;
        }
        let mut faded = false;
        for (i, v) in want.iter().enumerate() {
            let f = s + i;
            let w = if hold[f] { 1.0 } else { weight(f, *v) };
            faded |= w < 1.0;
            o[f] = quat::scale(*v, w);
        }
        out.push((s, e, if faded { Outcome::Faded } else { Outcome::Locked }));
        fade_beside(&mut o, (s, e), blend, |f| !planted[f] && !hold[f]);
    }
    (o, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spans_hold_their_middle_and_fall_off_with_the_reach() {
        // A toe sliding 5 cm a frame, planted on frames 5..=11.
        let toe: Vec<Vec3> = (0..20).map(|f| [0.0, 0.0, 0.05 * f as f64]).collect();
        let planted: Vec<bool> = (0..20).map(|f| (5..=11).contains(&f)).collect();
        let (o, s) = offsets(&toe, &planted, &[false; 20], BLEND, 1.0, |_, _| 1.0);
        assert_eq!(s, vec![(5, 11, Outcome::Locked)]);
        for f in 5..=11 {
            assert!((toe[f][2] + o[f][2] - toe[8][2]).abs() < 1e-12, "frame {f}");
        }
        // The fade: monotone, zero beyond the blend.
        assert!(o[12][2].abs() < o[11][2].abs() && o[16] != [0.0; 3] && o[17] == [0.0; 3]);
        // A leg short of the target at the span's ends holds less there, never jumps: the held
        // place moves smoothly as the weight falls.
        let weak = |f: usize, _: Vec3| if f >= 10 { 0.5 } else { 1.0 };
        let (o, s) = offsets(&toe, &planted, &[false; 20], BLEND, 1.0, weak);
        assert_eq!(s, vec![(5, 11, Outcome::Faded)]);
        assert!((o[11][2] - 0.5 * (toe[8][2] - toe[11][2])).abs() < 1e-12);
        // A dragged foot is left alone.
        let (o, s) = offsets(&toe, &planted, &[false; 20], BLEND, 0.1, |_, _| 1.0);
        assert_eq!((s, o), (vec![(5, 11, Outcome::Dragged)], vec![[0.0; 3]; 20]));
    }

    #[test]
    fn the_reach_weight_falls_smoothly() {
        assert_eq!(reach_weight(0.5), 1.0);
        assert_eq!(reach_weight(REACH_FULL), 1.0);
        assert_eq!(reach_weight(REACH_NONE), 0.0);
        assert_eq!(reach_weight(1.2), 0.0);
        let mid = reach_weight((REACH_FULL + REACH_NONE) / 2.0);
        assert!((mid - 0.5).abs() < 1e-12);
        let steps: Vec<f64> = (0..=20).map(|i| reach_weight(0.96 + 0.002 * i as f64)).collect();
        assert!(steps.windows(2).all(|w| w[1] <= w[0] && w[0] - w[1] < 0.2), "{steps:?}");
    }
}

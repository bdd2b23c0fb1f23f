//! Lowering the pelvis where a warped stride would over-extend a leg (as engines' stride
//! warping does): a foot placed further from its hip than the leg reaches is otherwise clamped
//! short of its place, and glides. The drop is the least that brings every leg's ankle target
//! within [`REACH`] of the leg's length, capped at [`MAX_DROP_M`], spread over the frames around
//! (a running maximum, then a running mean over [`SPREAD`] frames) so the body sinks and rises
//! smoothly, and faded to nothing towards held (keyed) frames, which never move.

use crate::motion::quat::{self, Vec3};
use crate::motion::representation::{Joints, Layout};
use crate::motion::skeleton::Skeleton;
use crate::postprocess::leg::Leg;
use crate::postprocess::{key_weights, window};

/// Share of a leg's length its ankle target is brought within (a straight knee pops).
pub const REACH: f64 = 0.97;
/// Largest drop (m): beyond it the foot is clamped instead (a crouching walk looks worse).
pub const MAX_DROP_M: f64 = 0.12;
/// Frames the drop is spread over (odd).
pub const SPREAD: usize = 9;
/// Frames over which the drop fades to nothing towards a held frame.
pub const KEY_FADE: usize = 5;

/// The pelvis drop per frame (skeleton units, >= 0) that lets each leg's ankle reach its moved
/// place `j[f][ankle] + offsets[leg][f]` with the hip lowered; zero on held frames.
pub(crate) fn drop(
    skel: &Skeleton,
    j: &Joints,
    legs: &[Leg],
    offsets: &[Vec<Vec3>],
    hold: &[bool],
) -> Vec<f64> {
    let t = j.len();
    let cap = MAX_DROP_M / skel.metres_per_unit;
    let need: Vec<f64> = (0..t)
        .map(|f| {
            legs.iter()
                .zip(offsets)
                .map(|(leg, o)| leg_need(&j[f], leg, o[f]))
                .fold(0.0, f64::max)
                .min(cap)
        })
        .collect();
    let peak: Vec<f64> =
        (0..t).map(|f| need[window(f, SPREAD, t)].iter().copied().fold(0.0, f64::max)).collect();
    key_weights(hold, KEY_FADE)
        .iter()
        .enumerate()
        .map(|(f, w)| {
            let win = &peak[window(f, SPREAD, t)];
            win.iter().sum::<f64>() / win.len() as f64 * w
        })
        .collect()
}

/// How far the hip must come down for the ankle moved by `o` to lie within [`REACH`] of the
/// leg's length, or as far as it lay unmoved where that was further (a walk's own heel strike
/// nearly straightens the knee); all of its height above the target where no drop is enough.
fn leg_need(j: &[Vec3], leg: &Leg, o: Vec3) -> f64 {
    let (dist, length) = leg.reach(j, o);
    let (unmoved, _) = leg.reach(j, [0.0; 3]);
    let r = (REACH * length).max(unmoved.min(length));
    if dist <= r {
        return 0.0;
    }
    let (h, a) = (j[leg.hip], quat::add(j[leg.ankle], o));
    let (dx, dy, dz) = (h[0] - a[0], h[1] - a[1], h[2] - a[2]);
    let flat = (dx * dx + dz * dz).sqrt();
    if flat >= r {
        dy.max(0.0)
    } else {
        (dy - (r * r - flat * flat).sqrt()).max(0.0)
    }
}

/// The joints with every joint lowered by `drop[f]`.
pub(crate) fn lowered(j: &Joints, drop: &[f64]) -> Joints {
    j.iter()
        .zip(drop)
        .map(|(frame, &h)| frame.iter().map(|p| [p[0], p[1] - h, p[2]]).collect())
        .collect()
}

/// Lower the whole body by `drop[f]` in de-normalised features [T, D]: the root height, every
/// joint's height and their vertical velocities. Held rows (whose drop is zero) stay as they
/// are, velocities included.
pub(crate) fn lower(skel: &Skeleton, feats: &mut [f32], drop: &[f64], hold: &[bool]) {
    let layout = Layout::of(skel);
    let d = layout.dim();
    let t = feats.len() / d;
    for f in (0..t).filter(|&f| !hold[f]) {
        let row = &mut feats[f * d..(f + 1) * d];
        let h = drop[f];
        let dv = if f + 1 < t { drop[f + 1] - h } else { 0.0 };
        row[3] -= h as f32;
        for jt in 0..layout.joints {
            if jt > 0 {
                row[layout.ric().start + (jt - 1) * 3 + 1] -= h as f32;
            }
            row[layout.vel().start + jt * 3 + 1] -= dv as f32;
        }
    }
}

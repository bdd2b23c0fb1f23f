//! The rigid refit's body kept on the floor it stood on. Away from its keys a network draws its
//! own body (the synthetic set's: hips 3 cm below the pelvis where HumanML3D's subjects have
//! 8-9 cm, legs a little shorter), and a leg it bends by shortening its bones for a few frames;
//! the refit gives every frame the keyed character's bones from the same pelvis with the same
//! directions, so the feet sink (5-9 cm through the floor on the fixtures' real clips, 14 cm on
//! a folded leg). Two corrections, held frames untouched:
//! * **lift**: the whole body rises by how far its lower foot sank, a running median over
//!   [`LIFT_WINDOW`] frames (a leg folded for a few frames does not lift the body), faded to
//!   nothing over [`LIFT_FADE`] frames towards held frames (a keyed pose is the keyed body's own,
//!   and the body would otherwise jump there);
//! * **knees**: a foot still below both the floor and where it stood before the refit is raised
//!   to the higher of the two by two-bone IK from the hip (the knee bends as the network bent it).

use crate::motion::quat::{Quat, Vec3};
use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;
use crate::postprocess::leg::{apply_leg, leg_deltas, legs, Leg, Posed};
use crate::postprocess::{key_weights, pelvis, window};

/// Frames over which the lower foot's sink is taken (odd; a running median).
pub const LIFT_WINDOW: usize = 21;
/// Frames over which the lift fades out towards a held frame.
pub const LIFT_FADE: usize = 10;
/// A foot this little below its floor (metres) is left where it is.
const TOLERANCE_M: f64 = 0.002;

/// What keeping the refitted body on its floor did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FloorReport {
    /// Largest lift of the whole body (metres; negative where it was lowered).
    pub lift_m: f64,
    /// Frames (per foot, summed) whose foot was raised by bending its knee.
    pub raised: usize,
    /// Largest such raise (metres).
    pub raise_m: f64,
}

/// The lowest height of a foot's ankle and toe.
fn low(j: &[Vec3], leg: &Leg) -> f64 {
    j[leg.ankle][1].min(j[leg.toe][1])
}

/// Per frame, how far to lift the whole body refitted from `before` to `after`: the running
/// median of how far its lower foot sank (negative where it rose), faded out towards held
/// frames (over [`LIFT_FADE`] frames, smoothly).
pub fn lift(skel: &Skeleton, before: &Joints, after: &Joints, hold: &[bool]) -> Vec<f64> {
    let legs = legs(skel);
    let lowest = |j: &[Vec3]| legs.iter().map(|l| low(j, l)).fold(f64::INFINITY, f64::min);
    let sink: Vec<f64> = before
        .iter()
        .zip(after)
        .zip(hold)
        .map(|((b, a), &h)| if h { 0.0 } else { lowest(b) - lowest(a) })
        .collect();
    let fade = key_weights(hold, LIFT_FADE);
    (0..sink.len())
        .map(|f| {
            let mut w = sink[window(f, LIFT_WINDOW, sink.len())].to_vec();
            w.sort_by(f64::total_cmp);
            w[w.len() / 2] * fade[f]
        })
        .collect()
}

/// What the rigid refit knew of the motion it just rewrote: the joints before and after (the
/// features now hold `after` on free rows, `before` on held ones), the root rotations and the
/// features before (their rotation channels, which neither the refit nor the lift changes).
pub struct Refit<'a> {
    pub before: &'a Joints,
    pub after: &'a Joints,
    pub root: &'a [Quat],
    pub old: &'a [f64],
}

/// Keep de-normalised features `feats` [T, D], just refitted ([`Refit`]), on the floor the motion
/// stood on before: the lift ([`lift`]), then each foot still sunk below both the floor (height
/// 0) and its own height before raised by bending its knee. Held rows stay as given.
pub fn keep_on_floor(skel: &Skeleton, feats: &mut [f32], r: &Refit, hold: &[bool]) -> FloorReport {
    let after: Joints = r
        .after
        .iter()
        .zip(r.before)
        .zip(hold)
        .map(|((a, b), &h)| if h { b.clone() } else { a.clone() })
        .collect();
    let up = lift(skel, r.before, &after, hold);
    let down: Vec<f64> = up.iter().map(|v| -v).collect();
    pelvis::lower(skel, feats, &down, hold);
    let joints = pelvis::lowered(&after, &down);
    let unit = skel.metres_per_unit;
    let mut report = FloorReport {
        lift_m: up.iter().copied().fold(0.0, |m: f64, v| if v.abs() > m.abs() { v } else { m })
            * unit,
        ..Default::default()
    };
    for leg in legs(skel) {
        let o: Vec<Vec3> = joints
            .iter()
            .zip(r.before)
            .map(|(j, b)| {
                let floor = low(b, &leg).min(0.0);
                let need = floor - low(j, &leg);
                [0.0, if need * unit > TOLERANCE_M { need } else { 0.0 }, 0.0]
            })
            .collect();
        let (delta, moved) = leg_deltas(&joints, leg, &o, hold);
        report.raised += moved.iter().filter(|&&m| m).count();
        report.raise_m = o
            .iter()
            .zip(&moved)
            .filter(|(_, &m)| m)
            .fold(report.raise_m, |r, (v, _)| r.max(v[1] * unit));
        let posed = Posed { joints: &joints, root: r.root, old: r.old };
        apply_leg(skel, feats, &posed, leg, (&delta, &moved), hold);
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    #[test]
    fn a_median_lift_ignores_a_short_fold_and_holds_keys_still() {
        // Legs' lowest joints: a body that sank 6 cm everywhere but for a 5-frame fold of 14 cm.
        let pose = |y: f64| -> Vec<Vec3> { (0..22).map(|_| [0.0, y, 0.0]).collect() };
        let before: Joints = (0..40).map(|_| pose(0.02)).collect();
        let after: Joints =
            (0..40).map(|f| pose(if (20..25).contains(&f) { -0.12 } else { -0.04 })).collect();
        let mut hold = vec![false; 40];
        hold[5] = true;
        let up = lift(&T2M, &before, &after, &hold);
        assert_eq!(up[5], 0.0);
        for (f, u) in up.iter().enumerate().skip(15) {
            assert!((u - 0.06).abs() < 1e-12, "frame {f}: {u}");
        }
        // Towards the held frame the lift fades out smoothly.
        for f in 6..15 {
            assert!(up[f] > up[f - 1] && up[f] <= 0.06, "frame {f}: {}", up[f]);
        }
    }
}

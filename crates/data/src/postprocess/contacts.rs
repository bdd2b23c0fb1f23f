//! Foot contacts read from the motion itself: a foot is planted while its toe or its ankle is
//! near that joint's lowest height in the motion and moves slowly over the ground. HumanML3D's
//! contact labels (and a network's contact channels) test speed alone, with a threshold of
//! about 0.89 m/s at 20 fps, so a foot gliding at 0.7 m/s counts as planted there; here it
//! does not. Each test has two thresholds (hysteresis: a contact starts below the first and
//! lasts until the second is passed) and spans shorter than a few frames are dropped.

use crate::motion::representation::Joints;
use crate::motion::skeleton::Skeleton;

/// The thresholds of contact detection (metres, metres per second, frames).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Thresholds {
    /// A joint this close above its lowest height may start a contact ...
    pub height_on_m: f64,
    /// ... which lasts while it stays below this.
    pub height_off_m: f64,
    /// A contact starts below this horizontal speed ...
    pub speed_on_mps: f64,
    /// ... and ends above this one.
    pub speed_off_mps: f64,
    /// Shorter spans are not contacts.
    pub min_frames: usize,
}

/// The defaults (docs/feet.md has what they were measured against).
pub const THRESHOLDS: Thresholds = Thresholds {
    height_on_m: 0.05,
    height_off_m: 0.08,
    speed_on_mps: 0.3,
    speed_off_mps: 0.5,
    min_frames: 3,
};

/// Horizontal speed (m/s) of `joint` at frame `f`: its step to the next frame (the last frame
/// repeats the previous step).
pub(crate) fn ground_speed(skel: &Skeleton, j: &Joints, joint: usize, f: usize) -> f64 {
    let t = j.len();
    let (a, b) = if f + 1 < t { (f, f + 1) } else { (f.saturating_sub(1), f) };
    let (p, q) = (j[a][joint], j[b][joint]);
    (q[0] - p[0]).hypot(q[2] - p[2]) * skel.metres_per_unit * skel.fps
}

/// Per frame of `t` whether a state with hysteresis is on: it turns on where `start(f)` holds
/// and stays on while `keep(f)` does.
pub(crate) fn hysteresis(
    t: usize,
    start: impl Fn(usize) -> bool,
    keep: impl Fn(usize) -> bool,
) -> Vec<bool> {
    let mut on = false;
    (0..t)
        .map(|f| {
            on = if on { keep(f) } else { start(f) };
            on
        })
        .collect()
}

/// Per frame whether `joint` is in contact: low and slow, with hysteresis.
fn joint_contacts(skel: &Skeleton, j: &Joints, joint: usize, th: &Thresholds) -> Vec<bool> {
    let unit = skel.metres_per_unit;
    let floor = j.iter().map(|f| f[joint][1]).fold(f64::INFINITY, f64::min);
    let h = |f: usize| (j[f][joint][1] - floor) * unit;
    let v = |f: usize| ground_speed(skel, j, joint, f);
    hysteresis(
        j.len(),
        |f| h(f) < th.height_on_m && v(f) < th.speed_on_mps,
        |f| h(f) < th.height_off_m && v(f) < th.speed_off_mps,
    )
}

/// Spans (first, last frame) of the true runs of `on`.
pub fn spans(on: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut f = 0;
    while f < on.len() {
        if !on[f] {
            f += 1;
            continue;
        }
        let s = f;
        while f + 1 < on.len() && on[f + 1] {
            f += 1;
        }
        out.push((s, f));
        f += 1;
    }
    out
}

/// `on` without its runs shorter than `min` frames.
pub(crate) fn drop_short(mut on: Vec<bool>, min: usize) -> Vec<bool> {
    for (s, e) in spans(&on) {
        if e + 1 - s < min {
            on[s..=e].iter_mut().for_each(|v| *v = false);
        }
    }
    on
}

/// Per frame whether each foot ([left, right]) is planted: its toe or its ankle in contact.
pub fn detect(skel: &Skeleton, j: &Joints, th: &Thresholds) -> [Vec<bool>; 2] {
    [skel.feet_left, skel.feet_right].map(|[ankle, toe]| {
        let (a, b) = (joint_contacts(skel, j, ankle, th), joint_contacts(skel, j, toe, th));
        drop_short(a.iter().zip(&b).map(|(x, y)| *x || *y).collect(), th.min_frames)
    })
}

/// Per frame whether each foot's toe is near the floor (height alone, with hysteresis): the
/// stance candidates of a motion whose feet glide, which speed would not find.
pub fn low(skel: &Skeleton, j: &Joints, th: &Thresholds) -> [Vec<bool>; 2] {
    let loose = Thresholds { speed_on_mps: f64::INFINITY, speed_off_mps: f64::INFINITY, ..*th };
    [skel.feet_left, skel.feet_right]
        .map(|[_, toe]| drop_short(joint_contacts(skel, j, toe, &loose), th.min_frames))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    /// A standing body whose left foot does `left(f)`.
    fn motion(left: impl Fn(usize) -> [f64; 3]) -> Joints {
        crate::testing::feet::feet_motion(0.0, left)
    }

    #[test]
    fn a_foot_at_rest_is_planted_a_lifted_or_gliding_one_is_not() {
        let rest = detect(&T2M, &motion(|_| [0.1, 0.0, 0.05]), &THRESHOLDS);
        assert!(rest[0].iter().all(|&c| c) && rest[1].iter().all(|&c| c));
        // Lifted 20 cm on frames 10..30.
        let lift = detect(
            &T2M,
            &motion(|f| [0.1, if (10..30).contains(&f) { 0.2 } else { 0.0 }, 0.05]),
            &THRESHOLDS,
        );
        assert!((0..10).chain(30..40).all(|f| lift[0][f]) && (10..30).all(|f| !lift[0][f]));
        // Gliding on the floor at 0.7 m/s: HumanML3D's speed test (0.002 m^2 per frame) would
        // label it planted; it is not.
        let glide = detect(&T2M, &motion(|f| [0.1, 0.0, 0.035 * f as f64]), &THRESHOLDS);
        assert!(glide[0].iter().all(|&c| !c), "{:?}", glide[0]);
        assert!(0.035f64.powi(2) < 0.002);
        // But it is low: a stance candidate for stride warping.
        assert!(low(&T2M, &motion(|f| [0.1, 0.0, 0.035 * f as f64]), &THRESHOLDS)[0]
            .iter()
            .all(|&c| c));
    }

    #[test]
    fn hysteresis_keeps_a_contact_through_small_rises_and_short_blips_are_dropped() {
        // 6 cm rise (between the two height thresholds) mid-contact: still planted.
        let wobble =
            detect(&T2M, &motion(|f| [0.1, if f == 20 { 0.06 } else { 0.0 }, 0.05]), &THRESHOLDS);
        assert!(wobble[0].iter().all(|&c| c));
        // Low for two frames only, high otherwise: no contact.
        let blip = detect(
            &T2M,
            &motion(|f| [0.1, if (18..20).contains(&f) { 0.0 } else { 0.3 }, 0.05]),
            &THRESHOLDS,
        );
        assert!(blip[0].iter().all(|&c| !c));
    }
}

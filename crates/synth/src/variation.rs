//! Variation beyond the actions' own parameters, so that text alone cannot say how a clip moves
//! between its keys: a smooth time warp (the pace changes across the clip and on average) and
//! slow drifts of posture (spine, head, arms, pelvis height). It acts on [`Pose`]s, before the
//! body turns them into joints, so bones stay rigid and planted feet stay where they were put.

use std::f64::consts::TAU;

use super::actions::FPS;
use super::body::{Arm, Pose};
use super::ActionSpan;
use diffkfc_data::motion::quat;
use diffkfc_data::rng::Rng;

/// Strongest variation a set may ask for (`data synth --vary`, a recipe's `vary`).
pub const MAX_STRENGTH: f64 = 2.0;

/// Fewest frames a varied clip keeps (or its own length, if shorter).
const MIN_FRAMES: usize = 60;
/// Fastest a varied clip's pelvis or ankles may move (m/s) and hardest its pelvis may
/// accelerate (m/s^2): the unvaried set's own peaks (a run's ankles, a jump's landing), so a
/// run or a jump is never sped up past what a body does.
const MAX_SPEED: f64 = 13.0;
const MAX_ACCEL: f64 = 50.0;

/// `poses` varied at `strength` (0: unchanged; 1: pace 0.75-1.33x on average, changing by up
/// to ±35% across the clip, posture drifting), at most `cap` poses long; `spans` follow the
/// warp.
pub fn apply(
    r: &mut Rng,
    strength: f64,
    poses: &[Pose],
    spans: &mut [ActionSpan],
    cap: usize,
) -> Vec<Pose> {
    if strength <= 0.0 || poses.len() < 2 {
        return poses.to_vec();
    }
    let times = warp(r, strength, poses.len(), cap, pace_limit(poses));
    for s in spans.iter_mut() {
        s.start = times.partition_point(|&t| t < s.start as f64);
        s.end = times.partition_point(|&t| t < s.end as f64).max(s.start + 1);
    }
    let drift = Drift::draw(r, strength);
    times.iter().map(|&t| drift.on(&at(poses, t), t)).collect()
}

/// Source times (in frames) of the varied clip's frames: steps of a rate that is a per-clip
/// pace times a slow wave. The pace is pulled in where the clip would pass `cap` frames or
/// fall under [`MIN_FRAMES`], so no action is cut off; it never passes `limit`.
fn warp(r: &mut Rng, strength: f64, n: usize, cap: usize, limit: f64) -> Vec<f64> {
    let mut pace = (r.range(-0.29, 0.29) * strength).exp();
    let depth = r.range(0.0, 0.35) * strength;
    let (period, phase) = (r.range(30.0, 80.0), r.range(0.0, TAU));
    let end = (n - 1) as f64;
    let min = MIN_FRAMES.min(n);
    let mut times = Vec::new();
    for _ in 0..8 {
        times.clear();
        let mut t = 0.0;
        while t <= end && times.len() < cap {
            times.push(t);
            t += (pace * (depth * (TAU * t / period + phase).sin()).exp()).min(limit);
        }
        let covered = times.last().copied().unwrap_or(0.0).max(1.0);
        if times.len() >= cap && covered < end - 1.0 {
            pace *= end / covered;
        } else if times.len() < min {
            pace *= times.len() as f64 / min as f64;
        } else {
            break;
        }
    }
    times
}

/// Fastest rate the clip may be played at: its pelvis and ankles within [`MAX_SPEED`], its
/// pelvis within [`MAX_ACCEL`] (acceleration grows with the rate's square); at least 1.
fn pace_limit(poses: &[Pose]) -> f64 {
    let d = |a: [f64; 3], b: [f64; 3]| quat::norm(quat::sub(a, b));
    let speed = poses
        .windows(2)
        .flat_map(|w| {
            [d(w[1].root, w[0].root), d(w[1].feet[0], w[0].feet[0]), d(w[1].feet[1], w[0].feet[1])]
        })
        .fold(0.0, f64::max)
        * FPS;
    let accel = poses
        .windows(3)
        .map(|w| {
            let v = std::array::from_fn(|k| w[2].root[k] - 2.0 * w[1].root[k] + w[0].root[k]);
            quat::norm(v)
        })
        .fold(0.0, f64::max)
        * FPS
        * FPS;
    (MAX_SPEED / speed).min((MAX_ACCEL / accel).sqrt()).max(1.0)
}

/// The pose at fractional frame `t`.
fn at(poses: &[Pose], t: f64) -> Pose {
    let i = (t.floor() as usize).min(poses.len() - 2);
    Pose::lerp(&poses[i], &poses[i + 1], (t - i as f64).clamp(0.0, 1.0))
}

/// One slowly varying offset: a constant plus two sines.
#[derive(Clone, Copy)]
struct Wave {
    offset: f64,
    amp: f64,
    periods: [f64; 2],
    phases: [f64; 2],
}

impl Wave {
    fn draw(r: &mut Rng, offset: (f64, f64), amp: f64) -> Wave {
        Wave {
            offset: r.range(offset.0, offset.1),
            amp: amp * r.uniform(),
            periods: [r.range(30.0, 90.0), r.range(12.0, 30.0)],
            phases: [r.range(0.0, TAU), r.range(0.0, TAU)],
        }
    }

    fn at(&self, t: f64) -> f64 {
        let w = |k: usize| (TAU * t / self.periods[k] + self.phases[k]).sin();
        self.offset + self.amp * (w(0) + 0.5 * w(1)) / 1.5
    }
}

/// Posture drift of one clip (radians, metres for the pelvis).
struct Drift {
    pitch: Wave,
    lean: Wave,
    twist: Wave,
    head: Wave,
    /// Per arm: raise forward, raise sideways, elbow.
    arms: [[Wave; 3]; 2],
    /// How far the pelvis sinks (bent knees): at most 4 cm at strength 1.
    sink: f64,
}

impl Drift {
    fn draw(r: &mut Rng, s: f64) -> Drift {
        let mut w = |lo: f64, hi: f64, amp: f64| Wave::draw(r, (lo * s, hi * s), amp * s);
        let (pitch, lean, twist) = (w(-0.05, 0.12, 0.06), w(0.0, 0.0, 0.05), w(0.0, 0.0, 0.12));
        let head = w(-0.1, 0.15, 0.1);
        let mut arm = || [w(-0.05, 0.05, 0.15), w(0.0, 0.1, 0.08), w(0.0, 0.3, 0.15)];
        let arms = [arm(), arm()];
        Drift { pitch, lean, twist, head, arms, sink: r.range(0.0, 0.04) * s }
    }

    fn on(&self, p: &Pose, t: f64) -> Pose {
        let mut q = *p;
        q.root[1] -= self.sink;
        q.pitch += self.pitch.at(t);
        q.lean += self.lean.at(t);
        q.twist += self.twist.at(t);
        q.head_pitch += self.head.at(t);
        for (arm, w) in q.arms.iter_mut().zip(&self.arms) {
            *arm = Arm {
                flex: arm.flex + w[0].at(t),
                abd: (arm.abd + w[1].at(t)).max(0.0),
                elbow: (arm.elbow + w[2].at(t)).max(0.0),
            };
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walk(n: usize) -> Vec<Pose> {
        (0..n).map(|i| Pose::standing(0.0, 0.05 * i as f64, 0.0)).collect()
    }

    #[test]
    fn strength_zero_leaves_the_clip() {
        let p = walk(80);
        assert_eq!(apply(&mut Rng::new(1), 0.0, &p, &mut [], 195), p);
    }

    #[test]
    fn warp_covers_the_clip_within_bounds() {
        for seed in 0..200 {
            let mut r = Rng::new(seed);
            let n = 40 + (seed as usize * 7) % 156;
            let t = warp(&mut r, 1.0, n, 196, 1.0 + (seed % 3) as f64);
            assert!(t.len() <= 196 && t.len() >= MIN_FRAMES.min(n) - 1, "{n}: {}", t.len());
            let limit = 1.0 + (seed % 3) as f64;
            assert!(
                t.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= limit + 1e-9),
                "monotone, limited"
            );
            assert!(*t.last().unwrap() >= (n - 1) as f64 - 2.5, "{n}: ends {}", t.last().unwrap());
        }
    }

    #[test]
    fn feet_targets_are_untouched_and_spans_follow() {
        let p = walk(120);
        let mut spans = [ActionSpan {
            action: "walk_forward",
            start: 60,
            end: 120,
            params: serde_json::Value::Null,
        }];
        let q = apply(&mut Rng::new(5), 1.0, &p, &mut spans, 195);
        // Every foot target is on the source's straight line, at the source's spacing.
        for (k, pose) in q.iter().enumerate() {
            assert_eq!(pose.feet[0][0], p[0].feet[0][0], "frame {k}");
            assert!(pose.feet[0][2] >= 0.0 && pose.feet[0][2] <= 0.05 * 119.0 + 1e-9);
        }
        assert!(spans[0].start > 0 && spans[0].end <= q.len(), "{:?}", (spans[0].start, q.len()));
        let t_mid = q[spans[0].start].root[2] / 0.05;
        assert!((0.0..2.0).contains(&(t_mid - 60.0)), "span start maps to source frame {t_mid}");
    }
}

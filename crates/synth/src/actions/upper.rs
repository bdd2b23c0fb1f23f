//! Arm actions, performed standing or over a lower-body action.

use super::*;

pub(super) fn arms_over(s: &Pose, n: usize, f: impl Fn(f64, &mut Pose)) -> Vec<Pose> {
    (0..n)
        .map(|t| {
            let mut p = *s;
            f(t as f64 / (n - 1).max(1) as f64, &mut p);
            p
        })
        .collect()
}

/// Envelope rising over the first and falling over the last `edge` of the clip.
pub(super) fn envelope(x: f64, edge: f64) -> f64 {
    smooth(x / edge) * smooth((1.0 - x) / edge)
}

pub(super) fn wave(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let hz = r.range(1.2, 2.5);
    let high = r.range(2.2, 2.9);
    let secs = n as f64 / FPS;
    let poses = arms_over(s, n, |x, p| {
        let e = envelope(x, 0.2);
        let osc = (2.0 * PI * hz * x * secs).sin();
        p.arms[side] = Arm::lerp(
            p.arms[side],
            Arm { flex: 0.4, abd: high + 0.25 * osc, elbow: 0.9 + 0.3 * osc },
            e,
        );
    });
    Performance {
        poses,
        params: json!({"hand": side_word(side), "frequency_hz": hz, "height": high}),
        side: Some(side_word(side)),
    }
}

pub(super) fn raise_arm(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let reps = 1 + r.below(2);
    let forward = r.chance(0.5);
    let b = bumps(n, reps, 0.1);
    let target = if forward {
        Arm { flex: 2.8, abd: 0.1, elbow: 0.1 }
    } else {
        Arm { flex: 0.2, abd: 2.8, elbow: 0.1 }
    };
    let poses = arms_over(s, n, |x, p| {
        let w = b[((x * (n - 1) as f64).round() as usize).min(n - 1)];
        p.arms[side] = Arm::lerp(p.arms[side], target, w);
    });
    Performance {
        poses,
        params: json!({"arm": side_word(side), "reps": reps, "path": if forward { "front" } else { "side" }}),
        side: Some(side_word(side)),
    }
}

pub(super) fn raise_both(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let reps = 1 + r.below(3);
    let height = r.range(2.0, 3.0);
    let b = bumps(n, reps, 0.1);
    let poses = arms_over(s, n, |x, p| {
        let w = b[((x * (n - 1) as f64).round() as usize).min(n - 1)];
        for a in 0..2 {
            p.arms[a] = Arm::lerp(p.arms[a], Arm { flex: height, abd: 0.15, elbow: 0.1 }, w);
        }
    });
    Performance { poses, params: json!({"reps": reps, "height": height}), side: None }
}

pub(super) fn clap(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let hz = r.range(1.5, 3.0);
    let height = r.range(1.0, 1.6);
    let secs = n as f64 / FPS;
    let poses = arms_over(s, n, |x, p| {
        let e = envelope(x, 0.2);
        let open = 0.5 + 0.5 * (2.0 * PI * hz * x * secs).cos();
        for a in 0..2 {
            p.arms[a] =
                Arm::lerp(p.arms[a], Arm { flex: height, abd: -0.45 + 0.55 * open, elbow: 0.9 }, e);
        }
    });
    Performance { poses, params: json!({"frequency_hz": hz, "height": height}), side: None }
}

pub(super) fn punch(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let reps = 1 + r.below(4);
    let alternate = r.chance(0.4);
    let guard = Arm { flex: 1.0, abd: -0.1, elbow: 2.0 };
    let hit = Arm { flex: 1.5, abd: -0.1, elbow: 0.05 };
    let poses = arms_over(s, n, |x, p| {
        let e = envelope(x, 0.15);
        let y = (x - 0.15) / 0.7 * reps as f64;
        let k = y.floor().clamp(0.0, reps as f64 - 1.0) as usize;
        let w = if (0.0..reps as f64).contains(&y) { (PI * y.fract()).sin().powi(4) } else { 0.0 };
        let arm = if alternate && k % 2 == 1 { 1 - side } else { side };
        for a in 0..2 {
            p.arms[a] = Arm::lerp(p.arms[a], guard, e);
        }
        p.arms[arm] = Arm::lerp(p.arms[arm], hit, w * e);
        p.twist = 0.25 * w * e * if arm == 0 { -1.0 } else { 1.0 };
    });
    Performance {
        poses,
        params: json!({"hand": side_word(side), "reps": reps, "alternate": alternate}),
        side: Some(side_word(side)),
    }
}

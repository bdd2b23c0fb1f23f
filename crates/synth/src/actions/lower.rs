//! Whole-body actions: locomotion, turns, dance, squats, jumps, sitting, kneeling, kicks.

use super::*;

pub(super) fn walk(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let speed = r.range(0.7, 1.6);
    let curve = r.range(-0.15, 0.15);
    Performance {
        poses: locomotion(s, n, speed, 0.0, curve, Gait::walk(speed), 0.02),
        params: json!({"speed": speed, "yaw_rate": curve}),
        side: None,
    }
}

pub(super) fn walk_backward(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let speed = r.range(0.35, 0.8);
    let mut g = Gait::walk(speed);
    g.pitch = -0.02;
    Performance {
        poses: locomotion(s, n, speed, PI, 0.0, g, 0.015),
        params: json!({"speed": speed}),
        side: None,
    }
}

pub(super) fn walk_sideways(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let speed = r.range(0.3, 0.6);
    let heading = if side == 0 { PI / 2.0 } else { -PI / 2.0 };
    let mut g = Gait::walk(speed);
    g.arm_swing = 0.05;
    Performance {
        poses: locomotion(s, n, speed, heading, 0.0, g, 0.01),
        params: json!({"speed": speed, "side": side_word(side)}),
        side: Some(side_word(side)),
    }
}

pub(super) fn walk_circle(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let radius = r.range(0.8, 2.2);
    let speed = r.range(0.7, 1.2);
    let rate = speed / radius * if side == 0 { 1.0 } else { -1.0 };
    Performance {
        poses: locomotion(s, n, speed, 0.0, rate, Gait::walk(speed), 0.02),
        params: json!({"speed": speed, "radius": radius, "direction": side_word(side)}),
        side: Some(side_word(side)),
    }
}

pub(super) fn jog(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let speed = r.range(1.8, 2.6);
    Performance {
        poses: locomotion(s, n, speed, 0.0, r.range(-0.1, 0.1), Gait::run(speed), 0.05),
        params: json!({"speed": speed}),
        side: None,
    }
}

pub(super) fn run(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let speed = r.range(3.0, 3.8);
    let mut g = Gait::run(speed);
    g.lift = 0.22;
    g.pitch = 0.22;
    Performance {
        poses: locomotion(s, n, speed, 0.0, r.range(-0.1, 0.1), g, 0.07),
        params: json!({"speed": speed}),
        side: None,
    }
}

pub(super) fn turn(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let angle = r.range(1.2, 3.3);
    let secs = n as f64 / FPS;
    // The eased trajectory covers about 80% of the nominal rate.
    let rate = angle / (secs * 0.8) * if side == 0 { 1.0 } else { -1.0 };
    Performance {
        poses: locomotion(s, n, 0.0, 0.0, rate, Gait::shuffle(), 0.0),
        params: json!({"angle": angle, "direction": side_word(side)}),
        side: Some(side_word(side)),
    }
}

pub(super) fn spin(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let angle = r.range(5.5, 7.0);
    let rate = angle / (n as f64 / FPS * 0.8) * if side == 0 { 1.0 } else { -1.0 };
    let mut g = Gait::shuffle();
    g.step_rate = 3.0;
    let mut poses = locomotion(s, n, 0.0, 0.0, rate, g, 0.0);
    for p in &mut poses {
        p.arms = [Arm { flex: 0.1, abd: 0.9, elbow: 0.4 }; 2];
    }
    Performance {
        poses,
        params: json!({"angle": angle, "direction": side_word(side)}),
        side: Some(side_word(side)),
    }
}

pub(super) fn dance(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    // Side steps to the left and right to a beat, arms swinging up and across.
    let beat = r.range(1.5, 2.3);
    let width = r.range(0.15, 0.3);
    let (_, left) = body::axes(s.yaw);
    let traj: Vec<RootState> = (0..n)
        .map(|t| {
            let ph = 2.0 * PI * beat * t as f64 / FPS / 2.0;
            let off =
                width * ph.sin() * smooth(t as f64 / 10.0) * smooth((n - 1 - t) as f64 / 10.0);
            let st = state(s);
            RootState {
                x: st.x + left[0] * off,
                z: st.z + left[2] * off,
                height: st.height - 0.04 * (2.0 * ph).sin().abs(),
                ..st
            }
        })
        .collect();
    let g = Gait {
        step_rate: beat,
        swing: 0.6,
        lift: 0.06,
        lead: 0.3,
        arm_swing: 0.0,
        elbow: 0.5,
        pitch: 0.0,
    };
    let mut poses = gait::locomote(&traj, &g, s.feet, FPS);
    let amp = r.range(0.6, 1.4);
    for (t, p) in poses.iter_mut().enumerate() {
        let ph = 2.0 * PI * beat * t as f64 / FPS / 2.0;
        p.arms = [
            Arm { flex: 0.6 + 0.5 * ph.sin(), abd: 0.3 + amp * (0.5 + 0.5 * ph.cos()), elbow: 1.0 },
            Arm { flex: 0.6 - 0.5 * ph.sin(), abd: 0.3 + amp * (0.5 - 0.5 * ph.cos()), elbow: 1.0 },
        ];
        p.lean = 0.1 * ph.sin();
    }
    Performance {
        poses,
        params: json!({"beat_hz": beat, "width": width, "arm_amplitude": amp}),
        side: None,
    }
}

pub(super) fn squat(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let reps = 1 + r.below(3);
    let depth = r.range(0.25, 0.45);
    let b = bumps(n, reps, 0.1);
    let poses = b
        .iter()
        .map(|&w| {
            let mut p = *s;
            p.root[1] = body::standing_height() - depth * w;
            p.pitch = 0.5 * w * depth / 0.45;
            p.knee_out = 0.35 * w;
            p.arms = [Arm::lerp(Arm::REST, Arm { flex: 1.4, abd: 0.1, elbow: 0.2 }, w); 2];
            p
        })
        .collect();
    Performance { poses, params: json!({"reps": reps, "depth": depth}), side: None }
}

/// Vertical pelvis offset over one jump cycle (f in [0, 1)): crouch, push, flight of peak
/// `h`, land, rise. Feet leave the ground only while it is above zero.
pub(super) fn jump_height(f: f64, h: f64) -> f64 {
    // Crouch depth grows with the jump: small hops barely bend.
    let c = (0.6 * h + 0.02).min(0.18);
    if f < 0.25 {
        -c * smooth(f / 0.25)
    } else if f < 0.4 {
        -c * (1.0 - smooth((f - 0.25) / 0.15))
    } else if f < 0.7 {
        let u = (f - 0.4) / 0.3;
        4.0 * h * u * (1.0 - u)
    } else if f < 0.85 {
        -c * smooth((f - 0.7) / 0.15)
    } else {
        -c * (1.0 - smooth((f - 0.85) / 0.15))
    }
}

/// `reps` jumps of peak `height`, advancing `dist` each; with `one_leg`, hops on the other
/// leg with that foot tucked up behind.
pub(super) fn jumps(
    s: &Pose,
    n: usize,
    reps: usize,
    height: f64,
    dist: f64,
    one_leg: Option<usize>,
) -> Vec<Pose> {
    let (fwd, left) = body::axes(s.yaw);
    // At least 16 frames (0.8 s) per jump: fewer repetitions if the clip is short.
    let reps = reps.min(((n as f64 * 0.85) / 16.0).floor().max(1.0) as usize);
    let cycle = n as f64 * 0.85 / reps as f64;
    let lead = ((n as f64 - cycle * reps as f64) / 2.0).max(0.0);
    let shift = |p: [f64; 3], d: f64, y: f64| [p[0] + fwd[0] * d, p[1] + y, p[2] + fwd[2] * d];
    (0..n)
        .map(|t| {
            let x = ((t as f64 - lead) / cycle).clamp(0.0, reps as f64 - 1e-9);
            let (k, f) = (x.floor(), x.fract());
            let y = if t as f64 >= lead && t as f64 <= lead + cycle * reps as f64 {
                jump_height(f, height)
            } else {
                0.0
            };
            let adv = dist
                * (k + if f < 0.4 {
                    0.0
                } else if f < 0.7 {
                    (f - 0.4) / 0.3
                } else {
                    1.0
                });
            let adv = if (t as f64) < lead { 0.0 } else { adv };
            let mut p = *s;
            p.root = shift(s.root, adv, y);
            let lift = y.max(0.0);
            for side in 0..2 {
                p.feet[side] = shift(s.feet[side], adv, lift);
                p.toe[side] = if lift > 0.0 { 0.4 } else { 0.0 };
            }
            let crouch = (-y / 0.18).clamp(0.0, 1.0);
            p.pitch = 0.35 * crouch;
            // Arms swing back in the crouch and up through the flight, smoothly over the cycle.
            let active = t as f64 >= lead && t as f64 <= lead + cycle * reps as f64;
            let swing = if active { (PI * f).sin().powi(2) } else { 0.0 };
            let amp = if one_leg.is_some() { 0.5 } else { 1.6 * (height / 0.3).min(1.0) };
            p.arms = [Arm { flex: 0.05 - 0.4 * crouch + amp * swing, abd: 0.15, elbow: 0.3 }; 2];
            if let Some(free) = one_leg {
                // The free foot tucks up behind, easing in and out at the ends of the clip.
                let w = smooth(t as f64 / 8.0) * smooth((n - 1 - t) as f64 / 8.0);
                tuck(&mut p, free, w, (fwd, left));
            }
            p
        })
        .collect()
}

/// The `free` foot of a hop tucked up behind the body, by `w` (0: where it was), with the
/// body leaning over the standing leg; `axes` the facing's forward and left.
fn tuck(p: &mut Pose, free: usize, w: f64, (fwd, left): ([f64; 3], [f64; 3])) {
    let sgn = if free == 0 { 1.0 } else { -1.0 };
    let base_y = p.root[1] - body::standing_height() + body::ANKLE_HEIGHT + 0.3;
    let tucked = [
        p.root[0] - fwd[0] * 0.22 + left[0] * sgn * 0.1,
        base_y.max(p.feet[1 - free][1] + 0.25),
        p.root[2] - fwd[2] * 0.22 + left[2] * sgn * 0.1,
    ];
    p.feet[free] = body::lerp3(p.feet[free], tucked, w);
    p.toe[free] = 0.6 * w;
    p.lean = -sgn * 0.08 * w;
}

pub(super) fn jump_in_place(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let reps = 1 + r.below(3);
    let h = r.range(0.12, 0.32);
    Performance {
        poses: jumps(s, n, reps, h, 0.0, None),
        params: json!({"reps": reps, "height": h}),
        side: None,
    }
}

pub(super) fn jump_forward(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let reps = 1 + r.below(2);
    let h = r.range(0.15, 0.3);
    let d = r.range(0.4, 0.9);
    Performance {
        poses: jumps(s, n, reps, h, d, None),
        params: json!({"reps": reps, "height": h, "distance": d}),
        side: None,
    }
}

pub(super) fn hop(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let free = r.below(2);
    let reps = 2 + r.below(4);
    let h = r.range(0.06, 0.14);
    let d = r.range(0.0, 0.25);
    // Hops on the other leg: "hops on the {side} leg" names the stance leg.
    Performance {
        poses: jumps(s, n, reps, h, d, Some(free)),
        params: json!({"reps": reps, "height": h, "distance": d, "leg": side_word(1 - free)}),
        side: Some(side_word(1 - free)),
    }
}

pub(super) fn sit(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let depth = r.range(0.38, 0.5);
    let hold = r.range(0.15, 0.45);
    let (fwd, _) = body::axes(s.yaw);
    let mut down = *s;
    down.root = [s.root[0] - fwd[0] * 0.22, s.root[1] - depth, s.root[2] - fwd[2] * 0.22];
    down.pitch = 0.25;
    down.knee_out = 0.2;
    down.arms = [Arm { flex: 0.5, abd: 0.15, elbow: 1.0 }; 2];
    let mut lean = down;
    lean.root = [s.root[0] - fwd[0] * 0.12, s.root[1] - depth * 0.55, s.root[2] - fwd[2] * 0.12];
    lean.pitch = 0.75;
    lean.arms = [Arm { flex: 0.9, abd: 0.1, elbow: 0.3 }; 2];
    let a = (1.0 - hold) / 2.0;
    let keys = [
        (0.0, *s),
        (a * 0.5, lean),
        (a, down),
        (a + hold, down),
        (a + hold + a * 0.5, lean),
        (1.0, *s),
    ];
    Performance {
        poses: keyed(n, &keys),
        params: json!({"depth": depth, "hold_fraction": hold}),
        side: None,
    }
}

pub(super) fn kneel(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let hold = r.range(0.2, 0.5);
    let (fwd, _) = body::axes(s.yaw);
    let mut k = *s;
    k.root[1] = 0.52;
    k.root = [s.root[0] + fwd[0] * 0.05, 0.52, s.root[2] + fwd[2] * 0.05];
    k.feet[1 - side] = [
        s.feet[1 - side][0] + fwd[0] * 0.4,
        s.feet[1 - side][1],
        s.feet[1 - side][2] + fwd[2] * 0.4,
    ];
    k.feet[side] = [s.feet[side][0] - fwd[0] * 0.45, 0.1, s.feet[side][2] - fwd[2] * 0.45];
    k.toe[side] = 0.9;
    k.pitch = 0.1;
    k.arms = [Arm { flex: 0.4, abd: 0.1, elbow: 0.8 }; 2];
    // The back foot steps back through the air, not along the floor.
    let mut mid = Pose::lerp(s, &k, 0.5);
    mid.feet[side][1] = 0.3;
    let a = (1.0 - hold) / 2.0;
    let keys =
        [(0.0, *s), (a * 0.5, mid), (a, k), (a + hold, k), (a + hold + a * 0.5, mid), (1.0, *s)];
    Performance {
        poses: keyed(n, &keys),
        params: json!({"knee": side_word(side), "hold_fraction": hold}),
        side: Some(side_word(side)),
    }
}

pub(super) fn kick(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let reps = 1 + r.below(2);
    let height = r.range(0.35, 0.85);
    let (fwd, _) = body::axes(s.yaw);
    let b = bumps(n, reps, 0.15);
    let poses = b
        .iter()
        .map(|&w| {
            let mut p = *s;
            let f = s.feet[side];
            p.feet[side] = [f[0] + fwd[0] * 0.6 * w, f[1] + height * w, f[2] + fwd[2] * 0.6 * w];
            p.toe[side] = -0.3 * w;
            p.pitch = -0.2 * w;
            p.root[1] -= 0.05 * w;
            p.arms = [Arm { flex: 0.3 * w, abd: 0.5 * w + 0.12, elbow: 0.6 }; 2];
            p
        })
        .collect();
    Performance {
        poses,
        params: json!({"leg": side_word(side), "reps": reps, "height": height}),
        side: Some(side_word(side)),
    }
}

pub(super) fn pick_up(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let side = r.below(2);
    let bend = r.range(1.0, 1.4);
    let hold = r.range(0.1, 0.3);
    let (fwd, _) = body::axes(s.yaw);
    let mut down = *s;
    down.pitch = bend;
    down.root = [s.root[0] - fwd[0] * 0.12, s.root[1] - 0.12, s.root[2] - fwd[2] * 0.12];
    down.knee_out = 0.1;
    down.head_pitch = -0.4;
    down.arms[side] = Arm { flex: 0.2, abd: 0.05, elbow: 0.1 };
    down.arms[1 - side] = Arm { flex: 0.1, abd: 0.2, elbow: 0.4 };
    let mut up = *s;
    up.arms[side] = Arm { flex: 0.7, abd: 0.1, elbow: 1.4 };
    let a = (1.0 - hold) / 2.0;
    let keys = [(0.0, *s), (a, down), (a + hold, down), (1.0, up)];
    Performance {
        poses: keyed(n, &keys),
        params: json!({"hand": side_word(side), "bend": bend, "hold_fraction": hold}),
        side: Some(side_word(side)),
    }
}

pub(super) fn stretch(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let sideways = r.chance(0.5);
    let lean = r.range(0.15, 0.35) * if r.chance(0.5) { 1.0 } else { -1.0 };
    let mut up = *s;
    up.arms = [Arm { flex: 0.3, abd: 2.9, elbow: 0.1 }; 2];
    up.pitch = -0.15;
    up.head_pitch = -0.3;
    let mut side = up;
    if sideways {
        side.lean = lean;
    } else {
        side.arms = [Arm { flex: 0.0, abd: 1.5, elbow: 0.0 }; 2];
        side.pitch = -0.05;
    }
    let keys = [(0.0, *s), (0.3, up), (0.55, side), (0.75, up), (1.0, *s)];
    Performance {
        poses: keyed(n, &keys),
        params: json!({"variant": if sideways { "side_lean" } else { "arms_out" }, "lean": lean}),
        side: None,
    }
}

/// Standing still with a slight sway (the base under standing upper-body actions).
pub fn idle(r: &mut Rng, s: &Pose, n: usize) -> Performance {
    let amp = r.range(0.003, 0.012);
    let (_, left) = body::axes(s.yaw);
    let poses = (0..n)
        .map(|t| {
            let mut p = *s;
            let o = amp * (t as f64 / FPS * 1.3).sin();
            p.root[0] += left[0] * o;
            p.root[2] += left[2] * o;
            p
        })
        .collect();
    Performance { poses, params: json!({"sway": amp}), side: None }
}

// ---- upper-body actions: they only set arms (the base supplies everything else) ----

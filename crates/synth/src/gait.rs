//! Locomotion: a root trajectory plus a footstep planner. Feet are planted (fixed in the world)
//! in stance and swing on an arc to the next plant, so foot contacts are real and skating is
//! low. Turning, walking, running and side-stepping are all this one mechanism with different
//! root paths and gait parameters.

use super::body::{self, lerp3, Pose};
use diffkfc_data::motion::quat::{self, Vec3};

/// Per-frame root state.
#[derive(Clone, Copy, Debug)]
pub struct RootState {
    pub x: f64,
    pub z: f64,
    pub yaw: f64,
    pub height: f64,
}

#[derive(Clone, Copy, Debug)]
pub struct Gait {
    /// Steps per second (one step = one foot's swing).
    pub step_rate: f64,
    /// Fraction of a step's time the swing foot is in the air (< 1: double support).
    pub swing: f64,
    /// Peak foot lift (metres).
    pub lift: f64,
    /// How far ahead of the root a new plant lands, as a fraction of the step length.
    pub lead: f64,
    /// Arm swing amplitude (radians) and elbow bend.
    pub arm_swing: f64,
    pub elbow: f64,
    /// Forward lean of the spine.
    pub pitch: f64,
}

impl Gait {
    pub fn walk(speed: f64) -> Gait {
        Gait {
            step_rate: 1.6 + 0.6 * speed,
            swing: 0.75,
            lift: 0.07,
            lead: 0.5,
            arm_swing: 0.25 + 0.2 * speed,
            elbow: 0.25,
            pitch: 0.05,
        }
    }
    pub fn run(speed: f64) -> Gait {
        Gait {
            step_rate: 2.3 + 0.35 * speed,
            swing: 1.3,
            lift: 0.16,
            lead: 0.45,
            arm_swing: 0.5,
            elbow: 1.3,
            pitch: 0.15,
        }
    }
    /// Small steps in place while turning.
    pub fn shuffle() -> Gait {
        Gait {
            step_rate: 2.2,
            swing: 0.7,
            lift: 0.05,
            lead: 0.0,
            arm_swing: 0.05,
            elbow: 0.2,
            pitch: 0.0,
        }
    }
}

/// Feet and arms for a root trajectory. `start_feet` are the plants at frame 0; returns poses
/// and the final plants. Velocity for foot leading is taken from the trajectory itself.
pub fn locomote(traj: &[RootState], gait: &Gait, start_feet: [Vec3; 2], fps: f64) -> Vec<Pose> {
    let n = traj.len();
    let step_frames = (fps / gait.step_rate).max(2.0);
    let swings = swing_schedule(traj, gait, start_feet, step_frames);
    // Arms swing in proportion to the current speed.
    let speed = |t: usize| {
        let a = traj[t.saturating_sub(1)];
        let b = traj[t];
        ((b.x - a.x).powi(2) + (b.z - a.z).powi(2)).sqrt()
    };
    let vmax = (1..n).map(speed).fold(0.0, f64::max);
    let mut last_plant = start_feet;
    let mut poses = Vec::with_capacity(n);
    let mut si = [0usize; 2];
    let side_swings: [Vec<_>; 2] = [
        swings.iter().filter(|s| s.0 == 0).copied().collect(),
        swings.iter().filter(|s| s.0 == 1).copied().collect(),
    ];
    for (t, r) in traj.iter().enumerate() {
        let tf = t as f64;
        let mut pose = Pose::standing(r.x, r.z, r.yaw);
        pose.root[1] = r.height;
        pose.pitch = gait.pitch;
        for side in 0..2 {
            let list = &side_swings[side];
            while si[side] < list.len() && list[si[side]].2 <= tf {
                last_plant[side] = list[si[side]].4;
                si[side] += 1;
            }
            pose.feet[side] = last_plant[side];
            if let Some(&(_, a, b, from, to)) = list.get(si[side]).filter(|s| s.1 <= tf) {
                let w = (tf - a) / (b - a);
                // Lift first, travel in the middle, set down last: toes clear the ground
                // before they move, so a stepping foot does not skate.
                let mut p = lerp3(from, to, body::smooth((w - 0.15) / 0.7));
                p[1] += gait.lift * (std::f64::consts::PI * w).sin().powf(0.6);
                pose.feet[side] = p;
                pose.toe[side] = -0.25 * (std::f64::consts::PI * w).sin();
            }
        }
        // Arms swing opposite to the legs: left arm forward when the right foot swings.
        let moving = if vmax > 1e-4 { speed(t) / vmax } else { 0.0 };
        let a = gait.arm_swing * moving * ((tf / step_frames) * std::f64::consts::PI).sin();
        pose.arms[0] = body::Arm { flex: 0.05 + a, abd: 0.12, elbow: gait.elbow };
        pose.arms[1] = body::Arm { flex: 0.05 - a, abd: 0.12, elbow: gait.elbow };
        poses.push(pose);
    }
    poses
}

/// One foot's swing: (side, start frame, end frame, from, to).
type Swing = (usize, f64, f64, Vec3, Vec3);

/// The feet's swings along `traj`: a step every `step_frames` frames, alternating sides, each
/// foot landing at its neutral place led along the motion; a step whose feet are already
/// within 2.5 cm of their places is skipped (standing still).
fn swing_schedule(
    traj: &[RootState],
    gait: &Gait,
    start_feet: [Vec3; 2],
    step_frames: f64,
) -> Vec<Swing> {
    let n = traj.len();
    let ideal = |t: usize, side: usize| -> Vec3 {
        let r = traj[t.min(n - 1)];
        let base = body::neutral_foot(r.x, r.z, r.yaw, side);
        // Lead the plant along the motion by a share of the step length.
        let t1 = (t + 1).min(n - 1);
        let t0 = t1.saturating_sub(1);
        let v =
            [(traj[t1].x - traj[t0].x) * step_frames, 0.0, (traj[t1].z - traj[t0].z) * step_frames];
        quat::add(base, quat::scale(v, gait.lead))
    };
    let mut plants = start_feet;
    let mut swings = Vec::new();
    let mut k = 0usize;
    loop {
        let t0 = k as f64 * step_frames;
        if t0 >= n as f64 {
            break;
        }
        let side = k % 2;
        let t1 = t0 + gait.swing * step_frames;
        let land = (t1.round() as usize).min(n - 1);
        let target = ideal(land, side);
        let other = ideal(land, 1 - side);
        let needs = quat::norm(quat::sub(target, plants[side])) > 0.025
            || quat::norm(quat::sub(other, plants[1 - side])) > 0.025;
        if needs {
            swings.push((side, t0, t1, plants[side], target));
            plants[side] = target;
        }
        k += 1;
    }
    swings
}

/// How a root travels: `speed` (m/s) in direction `heading` relative to the facing (0 forward,
/// pi/2 to the left), turning at `yaw_rate` (rad/s), bouncing `bounce` metres `step_rate` times
/// a second.
#[derive(Clone, Copy, Debug)]
pub struct Travel {
    pub speed: f64,
    pub heading: f64,
    pub yaw_rate: f64,
    pub bounce: f64,
    pub step_rate: f64,
}

/// A root trajectory of `n` frames from `start`, travelling as `tr` says, with eased start and
/// stop.
pub fn trajectory(start: RootState, n: usize, fps: f64, tr: Travel) -> Vec<RootState> {
    let Travel { speed, heading, yaw_rate, bounce, step_rate } = tr;
    let mut out = Vec::with_capacity(n);
    let mut s = start;
    let ease_frames = (0.6 * fps).min(n as f64 / 3.0);
    for t in 0..n {
        let tf = t as f64;
        let ease =
            body::smooth(tf / ease_frames) * body::smooth((n as f64 - 1.0 - tf) / ease_frames);
        let h = start.height
            - bounce
                * (0.5 - 0.5 * (2.0 * std::f64::consts::PI * step_rate * tf / fps).cos())
                * ease;
        out.push(RootState { height: h, ..s });
        let dir = s.yaw + heading;
        s.x += dir.sin() * speed * ease / fps;
        s.z += dir.cos() * speed * ease / fps;
        s.yaw += yaw_rate * ease / fps;
    }
    out
}

//! A parametric body on the HumanML3D target skeleton: a [`Pose`] (root, facing, spine, feet
//! targets, arm angles) becomes 22 joint positions, legs by two-bone IK so planted feet stay
//! exactly where they were put. Bone lengths are the target skeleton's, so `process_file`'s
//! retargeting leaves the motion unchanged.

use diffkfc_data::motion::quat::{self, Vec3};
use diffkfc_data::motion::skeleton::T2M;

/// Angles of one arm in the upper-body frame (radians): raise forward, raise sideways
/// (outwards), elbow flexion.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Arm {
    pub flex: f64,
    pub abd: f64,
    pub elbow: f64,
}

impl Arm {
    pub const REST: Arm = Arm { flex: 0.05, abd: 0.12, elbow: 0.15 };

    pub fn lerp(a: Arm, b: Arm, w: f64) -> Arm {
        Arm {
            flex: lerp(a.flex, b.flex, w),
            abd: lerp(a.abd, b.abd, w),
            elbow: lerp(a.elbow, b.elbow, w),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Pelvis position (world, metres, Y up).
    pub root: Vec3,
    /// Facing angle about +Y; 0 faces +Z.
    pub yaw: f64,
    /// Forward bend of the spine (radians, total over the spine).
    pub pitch: f64,
    /// Sideways lean (positive: towards the body's left).
    pub lean: f64,
    /// Upper-body rotation about the spine relative to the pelvis.
    pub twist: f64,
    pub head_pitch: f64,
    /// Ankle targets (world): left, right.
    pub feet: [Vec3; 2],
    /// Extra downward pitch of each foot (heel raised / pointed toes).
    pub toe: [f64; 2],
    /// Knee direction spread outwards (radians), for squats and kneeling.
    pub knee_out: f64,
    pub arms: [Arm; 2],
}

pub fn lerp(a: f64, b: f64, w: f64) -> f64 {
    a + (b - a) * w
}

pub fn lerp3(a: Vec3, b: Vec3, w: f64) -> Vec3 {
    [lerp(a[0], b[0], w), lerp(a[1], b[1], w), lerp(a[2], b[2], w)]
}

/// Smooth 0 -> 1 ramp over [0, 1] (cubic smoothstep), clamped.
pub fn smooth(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Ankle height above the ground with the foot flat.
pub const ANKLE_HEIGHT: f64 = 0.09;
/// Downward angle of an ankle -> foot bone (joint `foot`) with the foot flat on the ground.
fn foot_base_angle(foot: usize) -> f64 {
    ((ANKLE_HEIGHT - 0.02) / len(foot)).asin()
}

/// Target bone length of joint `j` (to its parent).
pub fn len(j: usize) -> f64 {
    T2M.target_lengths.unwrap()[j]
}

/// Lateral offset of each foot from the pelvis in a neutral stance (left +, right -).
pub const STANCE_HALF_WIDTH: f64 = 0.11;

/// Pelvis height when standing with nearly straight legs.
pub fn standing_height() -> f64 {
    ANKLE_HEIGHT + 0.97 * (len(4) + len(7)) + hip_drop()
}

/// How far the hips hang below the pelvis in the legacy body: poses are drawn for it (see
/// [`Body`]).
fn hip_drop() -> f64 {
    Body::Legacy.hip_drop()
}

/// The skeleton's bone directions above the legs: left side, in the pelvis frame (left, up,
/// forward) for the hip and in the chest frame for the collar and shoulder; the right side
/// mirrors them. Poses are drawn for the hip line and the legs (pelvis heights are the legacy
/// body's), and a body whose hips hang lower under the pelvis has its pelvis raised by the
/// difference, so feet and legs are the same whichever body draws them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Body {
    /// The hand-set body of the sets `models/tiny-synth` and the reference model's first thirteen
    /// stages were trained on: hips 3 cm below the pelvis and 20 cm apart, collars nearly
    /// sideways.
    Legacy,
    /// HumanML3D's: every clip is retargeted to one skeleton but keeps SMPL's bone directions,
    /// measured as the mean over real clips 000021 and 012314 (hips 8.8 cm below the pelvis and
    /// 12 cm apart, collars up and out). The default: what real keys have.
    #[default]
    HumanMl3d,
}

impl Body {
    pub const ALL: [Body; 2] = [Body::Legacy, Body::HumanMl3d];

    /// Its name in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Body::Legacy => "legacy",
            Body::HumanMl3d => "humanml3d",
        }
    }

    /// Pelvis -> left hip.
    fn hip(self) -> Vec3 {
        match self {
            Body::Legacy => [0.958, -0.287, 0.0],
            Body::HumanMl3d => [0.553, -0.830, -0.072],
        }
    }

    /// Chest (spine3) -> left collar.
    fn collar(self) -> Vec3 {
        match self {
            Body::Legacy => [1.0, 0.3, -0.15],
            Body::HumanMl3d => [0.55, 0.83, -0.03],
        }
    }

    /// Left collar -> left shoulder.
    fn shoulder(self) -> Vec3 {
        match self {
            Body::Legacy => [1.0, -0.3, -0.05],
            Body::HumanMl3d => [1.0, -0.08, -0.03],
        }
    }

    fn hip_drop(self) -> f64 {
        len(1) * -self.hip()[1]
    }

    /// How much higher than the drawn pose's pelvis this body's pelvis sits (0 for the legacy
    /// body, whose sets keep their bytes).
    fn pelvis_lift(self) -> f64 {
        self.hip_drop() - Body::Legacy.hip_drop()
    }
}

impl std::str::FromStr for Body {
    type Err = String;
    fn from_str(s: &str) -> Result<Body, String> {
        Body::ALL.into_iter().find(|b| b.name() == s).ok_or_else(|| {
            format!("unknown body '{s}' (known: {})", Body::ALL.map(Body::name).join(", "))
        })
    }
}

fn mirror(v: Vec3) -> Vec3 {
    [-v[0], v[1], v[2]]
}

impl Pose {
    /// Standing still at `root_xz` facing `yaw`, feet under the hips.
    pub fn standing(x: f64, z: f64, yaw: f64) -> Pose {
        let mut p = Pose {
            root: [x, standing_height(), z],
            yaw,
            pitch: 0.0,
            lean: 0.0,
            twist: 0.0,
            head_pitch: 0.0,
            feet: [[0.0; 3]; 2],
            toe: [0.0; 2],
            knee_out: 0.0,
            arms: [Arm::REST; 2],
        };
        p.feet = [neutral_foot(x, z, yaw, 0), neutral_foot(x, z, yaw, 1)];
        p
    }

    pub fn lerp(a: &Pose, b: &Pose, w: f64) -> Pose {
        Pose {
            root: lerp3(a.root, b.root, w),
            yaw: lerp(a.yaw, b.yaw, w),
            pitch: lerp(a.pitch, b.pitch, w),
            lean: lerp(a.lean, b.lean, w),
            twist: lerp(a.twist, b.twist, w),
            head_pitch: lerp(a.head_pitch, b.head_pitch, w),
            feet: [lerp3(a.feet[0], b.feet[0], w), lerp3(a.feet[1], b.feet[1], w)],
            toe: [lerp(a.toe[0], b.toe[0], w), lerp(a.toe[1], b.toe[1], w)],
            knee_out: lerp(a.knee_out, b.knee_out, w),
            arms: [Arm::lerp(a.arms[0], b.arms[0], w), Arm::lerp(a.arms[1], b.arms[1], w)],
        }
    }
}

/// Facing (forward) and left unit vectors for a yaw.
pub fn axes(yaw: f64) -> (Vec3, Vec3) {
    ([yaw.sin(), 0.0, yaw.cos()], [yaw.cos(), 0.0, -yaw.sin()])
}

/// Ankle position of a foot (0 left, 1 right) in a neutral stance.
pub fn neutral_foot(x: f64, z: f64, yaw: f64, side: usize) -> Vec3 {
    let (_, left) = axes(yaw);
    let s = if side == 0 { STANCE_HALF_WIDTH } else { -STANCE_HALF_WIDTH };
    [x + left[0] * s, ANKLE_HEIGHT, z + left[2] * s]
}

/// Knee position of a two-bone chain from `root` reaching for `target`, bending towards `pole`.
fn two_bone(root: Vec3, target: Vec3, l1: f64, l2: f64, pole: Vec3) -> Vec3 {
    let d_vec = quat::sub(target, root);
    let d = quat::norm(d_vec).clamp((l1 - l2).abs() + 1e-4, (l1 + l2) * 0.9995);
    let u = quat::normalize(d_vec);
    let cos_a = ((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d)).clamp(-1.0, 1.0);
    let bend = quat::sub(pole, quat::scale(u, quat::dot(pole, u)));
    let bend = if quat::norm(bend) < 1e-6 { [0.0, 0.0, 1.0] } else { quat::normalize(bend) };
    quat::add(
        root,
        quat::add(quat::scale(u, l1 * cos_a), quat::scale(bend, l1 * (1.0 - cos_a * cos_a).sqrt())),
    )
}

/// Rotate `v` by yaw about +Y.
fn yaw_rot(yaw: f64, v: Vec3) -> Vec3 {
    quat::qrot(quat::from_axis_angle([0.0, 1.0, 0.0], yaw), v)
}

/// The 22 joint positions of a pose drawn by `body`.
pub fn joints(body: Body, p: &Pose) -> Vec<Vec3> {
    joints_with(body, p, &mut [None, None])
}

/// Joint positions of a pose sequence. Each elbow's bend direction is carried from frame to
/// frame (and eased towards "forearm to the front"), so it never flips where the front is
/// parallel to the upper arm.
pub fn joints_seq(body: Body, poses: &[Pose]) -> Vec<Vec<Vec3>> {
    let mut bend = [None, None];
    poses.iter().map(|p| joints_with(body, p, &mut bend)).collect()
}

fn joints_with(body: Body, p: &Pose, bend: &mut [Option<Vec3>; 2]) -> Vec<Vec3> {
    let mut j = vec![[0.0; 3]; 22];
    let yq = quat::from_axis_angle([0.0, 1.0, 0.0], p.yaw);
    // Spine segments carry growing shares of twist, bend and lean.
    let seg = |share: f64, extra_pitch: f64| {
        let q = quat::qmul(yq, quat::from_axis_angle([0.0, 1.0, 0.0], p.twist * share));
        let q =
            quat::qmul(q, quat::from_axis_angle([1.0, 0.0, 0.0], p.pitch * share + extra_pitch));
        quat::qmul(q, quat::from_axis_angle([0.0, 0.0, 1.0], -p.lean * share))
    };
    let (q1, q2, q3) = (seg(0.35, 0.0), seg(0.7, 0.0), seg(1.0, 0.0));
    let place = |j: &mut Vec<Vec3>, child: usize, parent: usize, q: quat::Quat, dir: Vec3| {
        j[child] =
            quat::add(j[parent], quat::scale(quat::qrot(q, quat::normalize(dir)), len(child)));
    };
    j[0] = p.root;
    j[0][1] += body.pelvis_lift();
    place(&mut j, 1, 0, yq, body.hip());
    place(&mut j, 2, 0, yq, mirror(body.hip()));
    place(&mut j, 3, 0, q1, [0.0, 1.0, -0.08]);
    place(&mut j, 6, 3, q2, [0.0, 1.0, 0.0]);
    place(&mut j, 9, 6, q3, [0.0, 1.0, 0.05]);
    place(&mut j, 12, 9, q3, [0.0, 1.0, 0.1]);
    let qh = quat::qmul(q3, quat::from_axis_angle([1.0, 0.0, 0.0], p.head_pitch));
    place(&mut j, 15, 12, qh, [0.0, 0.85, 0.5]);
    place(&mut j, 13, 9, q3, body.collar());
    place(&mut j, 14, 9, q3, mirror(body.collar()));
    place(&mut j, 16, 13, q3, body.shoulder());
    place(&mut j, 17, 14, q3, mirror(body.shoulder()));
    arms(p, q3, &mut j, bend);
    legs(p, &mut j);
    j
}

/// The arms' joints (elbows, wrists) from the shoulders in `j`, in the chest frame `q3`.
fn arms(p: &Pose, q3: quat::Quat, j: &mut [Vec3], bend: &mut [Option<Vec3>; 2]) {
    // Forward f, up u, outward o.
    let f = quat::qrot(q3, [0.0, 0.0, 1.0]);
    let u = quat::qrot(q3, [0.0, 1.0, 0.0]);
    for (side, (sho, elb, wri)) in [(0usize, (16usize, 18usize, 20usize)), (1, (17, 19, 21))] {
        let out = quat::qrot(q3, [if side == 0 { 1.0 } else { -1.0 }, 0.0, 0.0]);
        let a = p.arms[side];
        let d = quat::normalize(quat::add(
            quat::add(
                quat::scale(u, -a.flex.cos() * a.abd.cos()),
                quat::scale(f, a.flex.sin() * a.abd.cos()),
            ),
            quat::scale(out, a.abd.sin()),
        ));
        j[elb] = quat::add(j[sho], quat::scale(d, len(elb)));
        // The forearm bends towards the front, as elbows do; where the front is along the upper
        // arm, the previous frame's bend direction carries on.
        let front = quat::sub(f, quat::scale(d, quat::dot(f, d)));
        let w = ((quat::norm(front) - 0.2) / 0.5).clamp(0.0, 1.0);
        let prev = bend[side].map(|b: Vec3| quat::sub(b, quat::scale(d, quat::dot(b, d))));
        let b = match prev {
            Some(pb) if quat::norm(pb) > 1e-6 => {
                let pb = quat::normalize(pb);
                let target = if w > 0.0 { quat::normalize(front) } else { pb };
                quat::add(quat::scale(pb, 1.0 - 0.5 * w), quat::scale(target, 0.5 * w))
            }
            _ if quat::norm(front) > 1e-6 => front,
            _ => quat::sub(u, quat::scale(d, quat::dot(u, d))),
        };
        let b = quat::normalize(b);
        bend[side] = Some(b);
        let fore = quat::add(quat::scale(d, a.elbow.cos()), quat::scale(b, a.elbow.sin()));
        j[wri] = quat::add(j[elb], quat::scale(fore, len(wri)));
    }
}

/// The legs' joints (knees, ankles, feet) from the hips in `j`: IK to the ankle targets.
fn legs(p: &Pose, j: &mut [Vec3]) {
    // Knees towards the front (spread by knee_out).
    for (side, (hip, knee, ankle, foot)) in
        [(0usize, (1usize, 4usize, 7usize, 10usize)), (1, (2, 5, 8, 11))]
    {
        let s = if side == 0 { 1.0 } else { -1.0 };
        // Knees bend to the front and up: a leg raised forward (a kick) then bends upwards
        // instead of flipping where "front" runs along the thigh.
        let pole = yaw_rot(p.yaw, [s * p.knee_out.sin(), 1.0, p.knee_out.cos()]);
        let target = p.feet[side];
        j[knee] = two_bone(j[hip], target, len(knee), len(ankle), pole);
        let dir = quat::normalize(quat::sub(target, j[knee]));
        j[ankle] = quat::add(j[knee], quat::scale(dir, len(ankle)));
        let a = foot_base_angle(foot) + p.toe[side];
        let fwd = yaw_rot(p.yaw, [0.0, 0.0, 1.0]);
        let fd = [fwd[0] * a.cos(), -a.sin(), fwd[2] * a.cos()];
        j[foot] = quat::add(j[ankle], quat::scale(fd, len(foot)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standing_pose_has_target_bones_and_feet_on_the_ground() {
        let p = Pose::standing(0.3, -1.0, 0.7);
        let j = joints(Body::Legacy, &p);
        let parents = T2M.parents();
        for (i, &par) in parents.iter().enumerate().skip(1) {
            let l = quat::norm(quat::sub(j[i], j[par as usize]));
            assert!((l - len(i)).abs() < 1e-9, "joint {i}: {l} vs {}", len(i));
        }
        // Ankles reach their targets; toes touch the floor; head above the pelvis.
        for (a, t) in [(7, p.feet[0]), (8, p.feet[1])] {
            assert!(quat::norm(quat::sub(j[a], t)) < 1e-6);
        }
        assert!(
            (j[10][1] - 0.02).abs() < 1e-6 && (j[11][1] - 0.02).abs() < 1e-6,
            "{:?} {:?}",
            j[10],
            j[11]
        );
        assert!(j[15][1] > 1.5 && j[15][1] < 1.8, "head at {}", j[15][1]);
        // It faces its yaw: left hip on the body's left.
        let (fwd, left) = axes(0.7);
        assert!(quat::dot(quat::sub(j[1], j[2]), left) > 0.15);
        assert!(quat::dot(quat::sub(j[10], j[7]), fwd) > 0.1);
    }
}

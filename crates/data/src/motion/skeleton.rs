//! Skeleton definitions: HumanML3D's 22-joint "t2m" skeleton and KIT-ML's 21-joint one.
//! Everything downstream (features, keyframe groups, BVH) is generic over [`Skeleton`], so
//! KIT-ML is a second instance of the same code, not a copy.

use crate::motion::quat::Vec3;

/// A named set of joints (a body part), used for partial keyframes and body-part editing.
#[derive(Clone, Debug)]
pub struct BodyPart {
    pub name: &'static str,
    pub joints: &'static [usize],
}

/// A joint or body-part name the skeleton does not have, with the names it has.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown joint or body part '{item}' (body parts: {parts}; joints: {joints})")]
pub struct UnknownJoint {
    pub item: String,
    pub parts: String,
    pub joints: String,
}

#[derive(Clone, Debug)]
pub struct Skeleton {
    pub name: &'static str,
    pub joint_names: &'static [&'static str],
    /// Chains from a parent joint outwards; the first joint of each chain is already placed.
    pub kinematic_chain: &'static [&'static [usize]],
    /// Unit directions of each bone in the rest pose (HumanML3D's `raw_offsets`).
    pub raw_offsets: &'static [Vec3],
    /// Target bone lengths (metres for t2m) that `uniform_skeleton` retargets to, if known.
    pub target_lengths: Option<&'static [f64]>,
    /// (r_hip, l_hip, r_shoulder, l_shoulder) slots of HumanML3D's `face_joint_indx`.
    pub face_joints: [usize; 4],
    pub feet_left: [usize; 2],
    pub feet_right: [usize; 2],
    /// Lower-leg bones whose lengths set the retargeting scale (`l_idx1`, `l_idx2`).
    pub leg_bones: [usize; 2],
    pub fps: f64,
    /// Multiply positions by this to get metres (KIT-ML stores millimetres).
    pub metres_per_unit: f64,
    pub parts: &'static [BodyPart],
}

impl Skeleton {
    pub fn num_joints(&self) -> usize {
        self.joint_names.len()
    }

    /// Width of the motion feature vector: 4 + (J-1)*3 + (J-1)*6 + J*3 + 4.
    pub fn feature_dim(&self) -> usize {
        let j = self.num_joints();
        4 + (j - 1) * 9 + j * 3 + 4
    }

    /// Parent of every joint (-1 for the root), derived from the kinematic chain.
    pub fn parents(&self) -> Vec<i64> {
        let mut parents = vec![-1i64; self.num_joints()];
        for chain in self.kinematic_chain {
            for w in chain.windows(2) {
                parents[w[1]] = w[0] as i64;
            }
        }
        parents
    }

    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joint_names.iter().position(|n| n.eq_ignore_ascii_case(name))
    }

    pub fn part(&self, name: &str) -> Option<&BodyPart> {
        self.parts.iter().find(|p| p.name.eq_ignore_ascii_case(name))
    }

    /// Resolve a comma-separated list of body-part names and joint names to sorted joint
    /// indices; the error names the first unknown entry.
    pub fn resolve_joints(&self, spec: &str) -> Result<Vec<usize>, UnknownJoint> {
        let mut out = Vec::new();
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            if let Some(p) = self.part(item) {
                out.extend_from_slice(p.joints);
            } else if let Some(j) = self.joint_index(item) {
                out.push(j);
            } else {
                let parts: Vec<_> = self.parts.iter().map(|p| p.name).collect();
                return Err(UnknownJoint {
                    item: item.to_string(),
                    parts: parts.join(", "),
                    joints: self.joint_names.join(", "),
                });
            }
        }
        out.sort_unstable();
        out.dedup();
        Ok(out)
    }

    /// Target bone vectors: raw offset direction times target length.
    pub fn target_offsets(&self) -> Option<Vec<Vec3>> {
        let lengths = self.target_lengths?;
        Some(
            self.raw_offsets
                .iter()
                .zip(lengths)
                .map(|(d, &l)| crate::motion::quat::scale(*d, l))
                .collect(),
        )
    }

    /// Look a skeleton up by name (`t2m`/`humanml3d` or `kit`).
    pub fn by_name(name: &str) -> Option<&'static Skeleton> {
        match name.to_ascii_lowercase().as_str() {
            "t2m" | "humanml3d" | "humanml" => Some(&T2M),
            "kit" | "kit-ml" | "kitml" => Some(&KIT),
            _ => None,
        }
    }
}

/// Target bone lengths of HumanML3D: frame 0 of `000021.npy`, first 22 joints, measured along
/// the raw offset directions (the README of the fixtures lists the same numbers rounded).
/// The golden test `target_lengths_match_000021` recomputes them from the fixture.
const T2M_LENGTHS: [f64; 22] = [
    0.0,
    0.103100177,
    0.109867721,
    0.131602724,
    0.393589222,
    0.390126114,
    0.143163828,
    0.432214947,
    0.425707550,
    0.057362134,
    0.143381093,
    0.149540883,
    0.219349397,
    0.137450143,
    0.143360774,
    0.103108706,
    0.131557726,
    0.123003279,
    0.256924639,
    0.263132272,
    0.266010486,
    0.269717635,
];

pub static T2M: Skeleton = Skeleton {
    name: "t2m",
    joint_names: &[
        "pelvis",
        "l_hip",
        "r_hip",
        "spine1",
        "l_knee",
        "r_knee",
        "spine2",
        "l_ankle",
        "r_ankle",
        "spine3",
        "l_foot",
        "r_foot",
        "neck",
        "l_collar",
        "r_collar",
        "head",
        "l_shoulder",
        "r_shoulder",
        "l_elbow",
        "r_elbow",
        "l_wrist",
        "r_wrist",
    ],
    kinematic_chain: &[
        &[0, 2, 5, 8, 11],
        &[0, 1, 4, 7, 10],
        &[0, 3, 6, 9, 12, 15],
        &[9, 14, 17, 19, 21],
        &[9, 13, 16, 18, 20],
    ],
    raw_offsets: &[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
    ],
    target_lengths: Some(&T2M_LENGTHS),
    face_joints: [2, 1, 17, 16],
    feet_left: [7, 10],
    feet_right: [8, 11],
    leg_bones: [5, 8],
    fps: 20.0,
    metres_per_unit: 1.0,
    parts: &[
        BodyPart { name: "lower_body", joints: &[0, 1, 2, 4, 5, 7, 8, 10, 11] },
        BodyPart { name: "upper_body", joints: &[3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21] },
        BodyPart { name: "arms", joints: &[13, 14, 16, 17, 18, 19, 20, 21] },
        BodyPart { name: "left_arm", joints: &[13, 16, 18, 20] },
        BodyPart { name: "right_arm", joints: &[14, 17, 19, 21] },
        BodyPart { name: "legs", joints: &[1, 2, 4, 5, 7, 8, 10, 11] },
        BodyPart { name: "left_leg", joints: &[1, 4, 7, 10] },
        BodyPart { name: "right_leg", joints: &[2, 5, 8, 11] },
        BodyPart { name: "spine_head", joints: &[0, 3, 6, 9, 12, 15] },
        BodyPart { name: "root", joints: &[0] },
    ],
};

/// KIT-ML (21 joints, millimetres, 12.5 fps). Its target skeleton comes from a KIT clip that is
/// not among our fixtures, so `uniform_skeleton` needs the user's KIT data to supply lengths.
pub static KIT: Skeleton = Skeleton {
    name: "kit",
    joint_names: &[
        "root",
        "torso",
        "chest",
        "neck",
        "head",
        "l_shoulder",
        "l_elbow",
        "l_wrist",
        "r_shoulder",
        "r_elbow",
        "r_wrist",
        "l_hip",
        "l_knee",
        "l_ankle",
        "l_toe_base",
        "l_toe",
        "r_hip",
        "r_knee",
        "r_ankle",
        "r_toe_base",
        "r_toe",
    ],
    kinematic_chain: &[
        &[0, 11, 12, 13, 14, 15],
        &[0, 16, 17, 18, 19, 20],
        &[0, 1, 2, 3, 4],
        &[3, 5, 6, 7],
        &[3, 8, 9, 10],
    ],
    raw_offsets: &[
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
    ],
    target_lengths: None,
    face_joints: [11, 16, 5, 8],
    feet_left: [14, 15],
    feet_right: [19, 20],
    leg_bones: [17, 18],
    fps: 12.5,
    metres_per_unit: 0.001,
    parts: &[
        BodyPart { name: "lower_body", joints: &[0, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20] },
        BodyPart { name: "upper_body", joints: &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10] },
        BodyPart { name: "arms", joints: &[5, 6, 7, 8, 9, 10] },
        BodyPart { name: "left_arm", joints: &[5, 6, 7] },
        BodyPart { name: "right_arm", joints: &[8, 9, 10] },
        BodyPart { name: "legs", joints: &[11, 12, 13, 14, 15, 16, 17, 18, 19, 20] },
        BodyPart { name: "left_leg", joints: &[11, 12, 13, 14, 15] },
        BodyPart { name: "right_leg", joints: &[16, 17, 18, 19, 20] },
        BodyPart { name: "spine_head", joints: &[0, 1, 2, 3, 4] },
        BodyPart { name: "root", joints: &[0] },
    ],
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feature_widths() {
        assert_eq!(T2M.feature_dim(), 263);
        assert_eq!(KIT.feature_dim(), 251);
        assert_eq!(T2M.num_joints(), 22);
        assert_eq!(KIT.num_joints(), 21);
    }

    #[test]
    fn chains_cover_every_joint_once() {
        for s in [&T2M, &KIT] {
            let p = s.parents();
            assert_eq!(p[0], -1);
            assert!(p[1..].iter().all(|&x| x >= 0), "{}: {p:?}", s.name);
            // Parents precede children, so one pass in index order places the skeleton.
            assert!(p.iter().enumerate().skip(1).all(|(i, &x)| (x as usize) < i), "{}", s.name);
            assert_eq!(s.raw_offsets.len(), s.num_joints());
            for part in s.parts {
                assert!(part.joints.iter().all(|&j| j < s.num_joints()));
            }
        }
    }

    #[test]
    fn resolve_names_and_groups() {
        assert_eq!(T2M.resolve_joints("left_arm, head").unwrap(), vec![13, 15, 16, 18, 20]);
        let e = T2M.resolve_joints("lower_body,tail").unwrap_err().to_string();
        assert!(e.contains("'tail'"), "{e}");
    }
}

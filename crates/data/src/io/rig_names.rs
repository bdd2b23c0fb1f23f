//! Which joint of a BVH file is which of the skeleton's: the naming conventions files follow
//! (ours and LaFAN1's, Mixamo's with or without `mixamorig:`, CMU's, our earlier snake_case
//! names) and the user's `--rig-map`.

use crate::io::bvh::Bvh;
use crate::motion::skeleton::Skeleton;
use crate::DataError;

/// The common names of HumanML3D's 22 joints, in the skeleton's order (LaFAN1's names; Mixamo's
/// differ only in the toes).
pub const T2M_NAMES: [&str; 22] = [
    "Hips",
    "LeftUpLeg",
    "RightUpLeg",
    "Spine",
    "LeftLeg",
    "RightLeg",
    "Spine1",
    "LeftFoot",
    "RightFoot",
    "Spine2",
    "LeftToe",
    "RightToe",
    "Neck",
    "LeftShoulder",
    "RightShoulder",
    "Head",
    "LeftArm",
    "RightArm",
    "LeftForeArm",
    "RightForeArm",
    "LeftHand",
    "RightHand",
];

/// Known naming conventions for the 22 joints, as the joints where they differ from
/// [`T2M_NAMES`] (a file matches one when it has all 22).
pub(super) const T2M_CONVENTIONS: [(&str, &[(usize, &str)]); 3] = [
    ("diffkfc / LaFAN1", &[]),
    ("Mixamo", &[(10, "LeftToeBase"), (11, "RightToeBase")]),
    (
        "CMU",
        &[
            (3, "LowerBack"),
            (6, "Spine"),
            (9, "Spine1"),
            (10, "LeftToeBase"),
            (11, "RightToeBase"),
            (12, "Neck1"),
        ],
    ),
];

/// The 22 names of a convention.
pub(super) fn convention_names(changes: &[(usize, &'static str)]) -> Vec<&'static str> {
    let mut names = T2M_NAMES.to_vec();
    for &(j, n) in changes {
        names[j] = n;
    }
    names
}

fn bare(name: &str) -> String {
    name.rsplit(':').next().unwrap_or(name).to_ascii_lowercase()
}

/// The file's joint for each skeleton joint that `--rig-map` names (ours by the skeleton's or
/// the rig's name, theirs by the file's).
fn mapped_by_user(
    skel: &Skeleton,
    rig_names: &[&str],
    map: &[(String, String)],
    find: &dyn Fn(&str) -> Option<usize>,
) -> Result<Vec<Option<usize>>, DataError> {
    let mut fixed = vec![None; skel.num_joints()];
    for (ours, theirs) in map {
        let j = skel
            .joint_index(ours)
            .or_else(|| rig_names.iter().position(|n| n.eq_ignore_ascii_case(ours)))
            .ok_or_else(|| {
                DataError::Invalid(format!(
                    "rig map: '{ours}' is not a joint of the {} skeleton (joints: {})",
                    skel.name,
                    rig_names.join(", ")
                ))
            })?;
        fixed[j] = Some(find(theirs).ok_or_else(|| {
            DataError::Invalid(format!(
                "rig map: '{ours}' maps to '{theirs}', which the BVH does not have"
            ))
        })?);
    }
    Ok(fixed)
}

/// Index in the file of each skeleton joint (`rig_names`: the names our rig gives them).
pub(super) fn map_joints(
    skel: &Skeleton,
    b: &Bvh,
    map: &[(String, String)],
    rig_names: &[&'static str],
) -> Result<Vec<usize>, DataError> {
    let find = |name: &str| {
        b.joints
            .iter()
            .position(|j| j.name == name)
            .or_else(|| b.joints.iter().position(|j| bare(&j.name) == bare(name)))
    };
    let fixed = mapped_by_user(skel, rig_names, map, &find)?;
    let mut conventions: Vec<(&str, Vec<&str>)> =
        vec![("diffkfc", rig_names.to_vec()), ("snake_case", skel.joint_names.to_vec())];
    if skel.name == "t2m" {
        conventions
            .extend(T2M_CONVENTIONS.iter().map(|(n, changes)| (*n, convention_names(changes))));
    }
    let resolved: Vec<(&str, Vec<Option<usize>>)> = conventions
        .iter()
        .map(|(n, names)| {
            (*n, names.iter().zip(&fixed).map(|(name, f)| f.or_else(|| find(name))).collect())
        })
        .collect();
    let best = resolved
        .iter()
        .max_by_key(|(_, r)| r.iter().filter(|x| x.is_some()).count())
        .expect("conventions");
    if best.1.iter().all(Option::is_some) {
        return Ok(best.1.iter().map(|x| x.unwrap_or(0)).collect());
    }
    let names = &conventions.iter().find(|(n, _)| *n == best.0).expect("convention").1;
    let missing: Vec<String> = best
        .1
        .iter()
        .enumerate()
        .filter(|(_, x)| x.is_none())
        .map(|(j, _)| format!("{} ({})", skel.joint_names[j], names[j]))
        .collect();
    Err(DataError::Invalid(format!(
        "BVH: no joint for {} of the {} skeleton (closest naming: {}); map them with --rig-map (JSON {{\"{}\": \"<joint in the file>\", ...}})",
        missing.join(", "),
        skel.name,
        best.0,
        skel.joint_names[best.1.iter().position(Option::is_none).unwrap_or(0)]
    )))
}

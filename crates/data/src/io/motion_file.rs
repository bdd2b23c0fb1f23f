//! Loading motion files a user hands us (features or joint positions), with the checks that
//! turn bad input into a one-line error naming the file and the problem.

use std::path::Path;

use crate::io::npy::{self, Array};
use crate::io::rig::{self, ImportOptions};
use crate::motion::representation::{self as rep, Joints};
use crate::motion::skeleton::Skeleton;
use crate::{motion::magnitude, DataError};

fn invalid(path: &Path, msg: String) -> DataError {
    DataError::Npy { path: path.to_path_buf(), msg }
}

/// First (row, column) holding NaN or infinity in a row-major array of `width` columns.
pub fn first_non_finite<T: Into<f64> + Copy>(data: &[T], width: usize) -> Option<(usize, usize)> {
    data.iter().position(|&v| !v.into().is_finite()).map(|i| (i / width, i % width))
}

/// A features file (T, D) for `skel`, with at least `min_frames` rows and only finite values.
pub fn load_features(
    path: &Path,
    skel: &Skeleton,
    min_frames: usize,
) -> Result<Array<f32>, DataError> {
    check_features(path, npy::read_f32(path)?, skel, min_frames)
}

/// `arr` (read from `path`) checked as features (T, D) for `skel`.
fn check_features(
    path: &Path,
    arr: Array<f32>,
    skel: &Skeleton,
    min_frames: usize,
) -> Result<Array<f32>, DataError> {
    let dim = skel.feature_dim();
    if arr.ndim() != 2 || arr.shape[1] != dim {
        return Err(invalid(
            path,
            format!(
                "expected features of shape (T, {dim}) for the {} skeleton, got {:?}",
                skel.name, arr.shape
            ),
        ));
    }
    if arr.shape[0] < min_frames {
        return Err(invalid(
            path,
            format!("has {} frame(s); at least {min_frames} needed", arr.shape[0]),
        ));
    }
    if let Some((r, c)) = first_non_finite(&arr.data, dim) {
        return Err(invalid(path, format!("NaN or infinite value at frame {r}, feature {c}")));
    }
    magnitude::check_features(skel, &arr.data).map_err(|m| invalid(path, m.to_string()))?;
    Ok(arr)
}

/// Joint positions (T, J, 3): J equal to the skeleton's joint count, or for t2m the 52 joints of
/// SMPL-H (body first), of which the first 22 are used.
pub fn load_joints(path: &Path, skel: &Skeleton, min_frames: usize) -> Result<Joints, DataError> {
    check_joints(path, npy::read_f64(path)?, skel, min_frames)
}

/// `arr` (read from `path`) checked as joint positions (T, J, 3) for `skel`.
fn check_joints(
    path: &Path,
    arr: Array<f64>,
    skel: &Skeleton,
    min_frames: usize,
) -> Result<Joints, DataError> {
    let jn = skel.num_joints();
    let ok_joints = |j: usize| j == jn || (skel.name == "t2m" && (j == 52 || j == 24));
    if arr.ndim() != 3 || arr.shape[2] != 3 || !ok_joints(arr.shape[1]) {
        let extra = if skel.name == "t2m" { ", (T, 24, 3) SMPL or (T, 52, 3) SMPL-H" } else { "" };
        return Err(invalid(
            path,
            format!("expected joint positions of shape (T, {jn}, 3){extra}, got {:?}", arr.shape),
        ));
    }
    if arr.shape[0] < min_frames {
        return Err(invalid(
            path,
            format!("has {} frame(s); at least {min_frames} needed", arr.shape[0]),
        ));
    }
    let per_frame = arr.shape[1] * 3;
    // Only the joints we use must be finite (SMPL-H hands may be padded).
    for f in 0..arr.shape[0] {
        if let Some((_, c)) =
            first_non_finite(&arr.data[f * per_frame..f * per_frame + jn * 3], jn * 3)
        {
            return Err(invalid(
                path,
                format!("NaN or infinite value at frame {f}, joint {}", c / 3),
            ));
        }
    }
    let j = rep::joints_from_array(&arr.data, arr.shape[0], arr.shape[1], jn);
    magnitude::check_joints(skel, &j).map_err(|m| invalid(path, m.to_string()))?;
    Ok(j)
}

/// A motion has at least two frames (one pose has no velocity, no path, nothing to animate).
pub const MIN_MOTION_FRAMES: usize = 2;

pub fn is_bvh(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("bvh"))
}

/// The joints of a BVH file of any common rig ([`crate::io::rig::import`]).
pub fn load_bvh(path: &Path, skel: &Skeleton, opts: &ImportOptions) -> Result<Joints, DataError> {
    let text = std::fs::read_to_string(path)
        .map_err(|err| DataError::Io { path: path.to_path_buf(), err })?;
    bvh_joints(path, &text, skel, opts)
}

/// The joints of BVH `text` (read from `path`), checked.
fn bvh_joints(
    path: &Path,
    text: &str,
    skel: &Skeleton,
    opts: &ImportOptions,
) -> Result<Joints, DataError> {
    let j = rig::read(skel, text, opts).map_err(|e| e.in_file(path))?;
    magnitude::check_joints(skel, &j).map_err(|m| invalid(path, m.to_string()))?;
    if j.len() < MIN_MOTION_FRAMES {
        return Err(invalid(
            path,
            format!("has {} frame(s); at least {MIN_MOTION_FRAMES} needed", j.len()),
        ));
    }
    Ok(j)
}

/// Joint positions from a motion file: features (T, D) are recovered, joints (T, J, 3) taken
/// as they are, a BVH read through the rig import.
pub fn load_motion(path: &Path, skel: &Skeleton, bvh: &ImportOptions) -> Result<Joints, DataError> {
    if is_bvh(path) {
        return load_bvh(path, skel, bvh);
    }
    if npy::read_f64(path)?.ndim() == 2 {
        load_feature_joints(path, skel)
    } else {
        load_joints(path, skel, MIN_MOTION_FRAMES)
    }
}

/// The joint positions a features file (T, D) recovers to (HumanML3D's `recover_from_ric`).
pub fn load_feature_joints(path: &Path, skel: &Skeleton) -> Result<Joints, DataError> {
    let f = load_features(path, skel, MIN_MOTION_FRAMES)?;
    let j = rep::recover_from_ric(skel, &f.data.iter().map(|&v| v as f64).collect::<Vec<_>>());
    // Small steps add up: a path past 1 km is refused here rather than drawn.
    magnitude::check_positions(skel, &j).map_err(|m| invalid(path, m.to_string()))?;
    Ok(j)
}

/// Features (T, D) of a motion file: features as they are, joints or BVH through
/// `process_file` (one frame fewer).
pub fn load_motion_features(
    path: &Path,
    skel: &Skeleton,
    bvh: &ImportOptions,
) -> Result<Vec<f32>, DataError> {
    let bytes =
        std::fs::read(path).map_err(|err| DataError::Io { path: path.to_path_buf(), err })?;
    motion_features_from_bytes(path, &bytes, skel, bvh)
}

/// Features (T, D) of a motion file's bytes (an upload held in memory): a BVH (by `name`'s
/// extension or its `HIERARCHY` line) or a features or joints `.npy`; `name` names it in errors.
pub fn motion_features_from_bytes(
    name: &Path,
    bytes: &[u8],
    skel: &Skeleton,
    bvh: &ImportOptions,
) -> Result<Vec<f32>, DataError> {
    let joints = if is_bvh(name) || bytes.starts_with(b"HIERARCHY") {
        let text = std::str::from_utf8(bytes)
            .map_err(|_| invalid(name, "is not text (a BVH file is)".into()))?;
        bvh_joints(name, text, skel, bvh)?
    } else {
        let arr = npy::decode_f64(name, bytes)?.0;
        if arr.ndim() == 2 {
            let f = check_features(name, arr.map(|x| x as f32), skel, MIN_MOTION_FRAMES)?.data;
            let joints = rep::recover_from_ric_f32(skel, &f);
            magnitude::check_joints(skel, &joints).map_err(|m| invalid(name, m.to_string()))?;
            // A motion used as keys or a source is refused on a collapsed body rather than
            // carried into the fit (the check joints files get in `features_from_joints`).
            rep::validate_joints(skel, &joints).map_err(|e| e.in_file(name))?;
            return Ok(f);
        }
        check_joints(name, arr, skel, MIN_MOTION_FRAMES)?
    };
    rep::features_from_joints(skel, &joints, rep::FOOT_CONTACT_THRESHOLD)
        .map_err(|e| e.in_file(name))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    #[test]
    fn finds_first_nan() {
        let d = [1.0f32, 2.0, 3.0, f32::NAN, 5.0, f32::INFINITY];
        assert_eq!(first_non_finite(&d, 2), Some((1, 1)));
        assert_eq!(first_non_finite(&[1.0f32; 4], 2), None);
    }

    #[test]
    fn rejects_bad_shapes() {
        let dir = std::env::temp_dir().join(format!("diffkfc-mf-{}", std::process::id()));
        let p = dir.join("x.npy");
        npy::write(&p, &[4, 10], &[0f32; 40]).unwrap();
        let e = load_features(&p, &T2M, 1).unwrap_err().to_string();
        assert!(e.contains("x.npy") && e.contains("(T, 263)") && e.contains("[4, 10]"), "{e}");
        let e = load_joints(&p, &T2M, 2).unwrap_err().to_string();
        assert!(e.contains("(T, 22, 3)"), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}

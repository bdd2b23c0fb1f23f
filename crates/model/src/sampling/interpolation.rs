//! The keys' linear interpolation as a motion: between keys, the place on the ground and the
//! root-relative pose linearly, the heading the short way round, composed into joints and
//! processed into features as HumanML3D processes joints. The in-betweening baseline of the field (LaFAN1's
//! "Interp"), and what `sampling::balance` falls back on where the network misses the keys.

use diffkfc_data::dataset::normalise;
use diffkfc_data::motion::representation::{
    features_from_joints, Joints, Layout, FOOT_CONTACT_THRESHOLD,
};
use diffkfc_data::motion::root_key::RootKey;
use diffkfc_data::Skeleton;

/// A keyed frame in the keys' local terms: place on the ground, heading, and the pose relative
/// to them (RIC: root-relative, facing +Z; the pelvis at (0, height, 0)).
#[derive(Clone)]
struct Key {
    frame: usize,
    place: [f64; 2],
    heading: f64,
    pose: Vec<[f64; 3]>,
}

fn local_pose(skel: &Skeleton, row: &[f32]) -> Vec<[f64; 3]> {
    let ric = Layout::of(skel).ric().start;
    let mut pose = vec![[0.0, row[3] as f64, 0.0]];
    pose.extend((1..skel.num_joints()).map(|j| {
        let o = ric + 3 * (j - 1);
        [row[o] as f64, row[o + 1] as f64, row[o + 2] as f64]
    }));
    pose
}

/// The keys, when every key observes a whole pose with its place and heading (otherwise
/// `None`: partial keys have no interpolation). A motion whose frame 0 is not keyed starts from
/// the first key's pose at the origin, facing +Z (the output's frame).
fn keys_of(
    skel: &Skeleton,
    values: &[f32],
    mask: &[f32],
    root: &[RootKey],
    length: usize,
) -> Option<Vec<Key>> {
    let d = skel.feature_dim();
    let pose_dims = Layout::of(skel).ric();
    let mut keys = Vec::new();
    for f in 0..length {
        let m = &mask[f * d..(f + 1) * d];
        if !(m[3] > 0.0 && m[pose_dims.clone()].iter().all(|&v| v > 0.0)) {
            continue;
        }
        let (Some(place), Some(heading)) = (root[f].place, root[f].heading) else { return None };
        keys.push(Key {
            frame: f,
            place,
            heading,
            pose: local_pose(skel, &values[f * d..(f + 1) * d]),
        });
    }
    let first = keys.first()?.clone();
    if first.frame > 0 {
        keys.insert(0, Key { frame: 0, place: [0.0, 0.0], heading: 0.0, ..first });
    }
    Some(keys)
}

/// Global joints of every frame: place and local pose linearly interpolated between the keys,
/// the heading the short way round (in the keys' local frame, as the delta-interpolator's
/// baseline: a turning body keeps its shape), held after the last key.
fn interpolate(keys: &[Key], length: usize) -> Joints {
    let lerp = |a: f64, b: f64, w: f64| a + w * (b - a);
    (0..length)
        .map(|f| {
            let i = keys.partition_point(|k| k.frame <= f).saturating_sub(1);
            let a = &keys[i];
            let (place, heading, pose) = match keys.get(i + 1) {
                Some(b) if f > a.frame => {
                    let w = (f - a.frame) as f64 / (b.frame - a.frame) as f64;
                    let turn = (b.heading - a.heading + std::f64::consts::PI)
                        .rem_euclid(std::f64::consts::TAU)
                        - std::f64::consts::PI;
                    let pose = a
                        .pose
                        .iter()
                        .zip(&b.pose)
                        .map(|(p, q)| [0, 1, 2].map(|k| lerp(p[k], q[k], w)))
                        .collect();
                    (
                        [lerp(a.place[0], b.place[0], w), lerp(a.place[1], b.place[1], w)],
                        a.heading + w * turn,
                        pose,
                    )
                }
                _ => (a.place, a.heading, a.pose.clone()),
            };
            // Heading h turns +Z towards +X: (x, z) -> (x cos h + z sin h, -x sin h + z cos h).
            let (s, c) = heading.sin_cos();
            pose.iter()
                .map(|p| [place[0] + p[0] * c + p[2] * s, p[1], place[1] - p[0] * s + p[2] * c])
                .collect()
        })
        .collect()
}

/// Normalised features `[length, D]` of the keys' interpolation (HumanML3D's processing of the
/// interpolated joints, the last frame repeated), or `None` when the keys do not allow one.
pub fn interpolated_keys(
    skel: &Skeleton,
    values: &[f32],
    mask: &[f32],
    root: &[RootKey],
    length: usize,
    mean: &[f32],
    std: &[f32],
) -> Option<Vec<f32>> {
    if length < 2 {
        return None;
    }
    let keys = keys_of(skel, values, mask, root, length)?;
    let mut feats =
        features_from_joints(skel, &interpolate(&keys, length), FOOT_CONTACT_THRESHOLD).ok()?;
    let d = skel.feature_dim();
    let last = feats[feats.len() - d..].to_vec();
    feats.extend_from_slice(&last);
    if feats.iter().any(|v| !v.is_finite()) {
        return None;
    }
    normalise(&mut feats, mean, std);
    Some(feats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::motion::representation::recover_from_ric_f32;
    use diffkfc_data::motion::root_key::root_trajectory;
    use diffkfc_data::testing::fixtures;

    /// The fixture clip 012314's features (None: fixtures absent, the test skips).
    fn clip() -> Option<Vec<f32>> {
        let path = fixtures::require("humanml3d/new_joint_vecs/012314.npy")?;
        Some(diffkfc_data::io::npy::read_f32(path).unwrap().data)
    }

    /// Keyed on every frame of a real clip, the interpolation is the clip itself (HumanML3D's
    /// processing of its own joints).
    #[test]
    fn keyed_on_every_frame_the_interpolation_is_the_clip() {
        let Some(feats) = clip() else { return };
        let skel = &diffkfc_data::T2M;
        let d = skel.feature_dim();
        let len = 60;
        let x = &feats[..len * d];
        let (mean, std) = (vec![0.0; d], vec![1.0; d]);
        let root = root_trajectory(x, d);
        let a = interpolated_keys(skel, x, &vec![1.0; len * d], &root, len, &mean, &std).unwrap();
        let (ja, jx) = (recover_from_ric_f32(skel, &a), recover_from_ric_f32(skel, x));
        let worst = (0..len - 1)
            .flat_map(|f| (0..22).map(move |j| (f, j)))
            .map(|(f, j)| (0..3).map(|k| (ja[f][j][k] - jx[f][j][k]).powi(2)).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        assert!(worst < 0.02, "{worst}");
    }

    /// Keyed every second, the interpolation passes through the keyed places.
    #[test]
    fn sparse_keys_the_interpolation_meets_the_keyed_places() {
        let Some(x) = clip() else { return };
        let skel = &diffkfc_data::T2M;
        let d = skel.feature_dim();
        let len = x.len() / d;
        let keys: Vec<usize> = (0..len).step_by(20).chain([len - 1]).collect();
        let mask = diffkfc_data::keyframes::frame_mask(len, &keys, &vec![true; d]);
        let traj = root_trajectory(&x, d);
        let mut root = vec![RootKey::default(); len];
        keys.iter().for_each(|&f| root[f] = traj[f]);
        let (mean, std) = (vec![0.0; d], vec![1.0; d]);
        let a = interpolated_keys(skel, &x, &mask, &root, len, &mean, &std).unwrap();
        let (ja, jx) = (recover_from_ric_f32(skel, &a), recover_from_ric_f32(skel, &x));
        for &f in &keys[..keys.len() - 1] {
            let e = (ja[f][0][0] - jx[f][0][0]).hypot(ja[f][0][2] - jx[f][0][2]);
            assert!(e < 0.03, "frame {f}: {e}");
        }
    }

    #[test]
    fn partial_keys_have_no_interpolation() {
        let skel = &diffkfc_data::T2M;
        let d = skel.feature_dim();
        let (len, vals) = (10, vec![0.1; 10 * d]);
        let mut mask = vec![0.0; len * d];
        mask[3..7].iter_mut().for_each(|m| *m = 1.0);
        let root = vec![RootKey { place: Some([0.0, 0.0]), heading: Some(0.0) }; len];
        let (mean, std) = (vec![0.0; d], vec![1.0; d]);
        assert!(interpolated_keys(skel, &vals, &mask, &root, len, &mean, &std).is_none());
    }
}

//! Body-part prompts (MotionDiffuse's idea on DiffKFC's keyframes): the lower body carries the
//! path, so a whole motion is generated from the lower body's text first; the upper body's pass
//! then keys that motion's lower body (and its place and heading) on every frame, so it is kept
//! exactly while the arms, spine and head are generated anew from their own text.

use diffkfc_data::keyframes;
use diffkfc_data::motion::root_key::{root_trajectory, RootKey};
use diffkfc_data::Skeleton;

/// The upper body's keyframes for one motion of `n` frames: `first`'s lower body ([n, D]
/// features) on every frame, the user's keys (`values`, `mask`) elsewhere, and `first`'s place
/// and heading on every frame.
pub fn upper_body_keys(
    skel: &Skeleton,
    first: &[f32],
    values: &[f32],
    mask: &[f32],
    n: usize,
) -> (Vec<f32>, Vec<f32>, Vec<RootKey>) {
    let d = skel.feature_dim();
    let lower_joints = skel.part("lower_body").map(|p| p.joints.to_vec()).unwrap_or_default();
    let dims = keyframes::dim_mask(skel, Some(&lower_joints));
    let every: Vec<usize> = (0..n).collect();
    let lower_mask = keyframes::frame_mask(n, &every, &dims);
    let keyed: Vec<f32> = lower_mask.iter().zip(mask).map(|(l, u)| l.max(*u)).collect();
    let v: Vec<f32> =
        (0..n * d).map(|k| if lower_mask[k] > 0.0 { first[k] } else { values[k] }).collect();
    (v, keyed, root_trajectory(first, d))
}

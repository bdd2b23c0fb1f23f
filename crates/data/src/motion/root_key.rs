//! Where a keyframe stands: its place on the ground and its heading, and the four channels
//! [x, z, sin h, cos h] the network reads them through; the root trajectory of a whole motion
//! in the same terms.

use crate::motion::representation::recover_root_rot_pos;

/// Root channels a keyframe may observe, in the order of `RootKey::channels`.
pub const ROOT_CHANNELS: usize = 4;
/// Metres per unit of the position channels the network sees.
pub const ROOT_POS_SCALE: f64 = 2.0;

/// Where a keyframe stands: ground-plane place (x, z in metres) and heading (radians, 0 facing
/// +Z, positive turning towards +X), in the output motion's frame; each may be unobserved.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RootKey {
    pub place: Option<[f64; 2]>,
    pub heading: Option<f64>,
}

impl RootKey {
    /// The network's channels [x, z, sin h, cos h] (place scaled by 1/ROOT_POS_SCALE) and their
    /// mask.
    pub fn channels(&self) -> ([f32; ROOT_CHANNELS], [f32; ROOT_CHANNELS]) {
        let (mut v, mut m) = ([0f32; ROOT_CHANNELS], [0f32; ROOT_CHANNELS]);
        if let Some([x, z]) = self.place {
            v[0] = (x / ROOT_POS_SCALE) as f32;
            v[1] = (z / ROOT_POS_SCALE) as f32;
            m[0] = 1.0;
            m[1] = 1.0;
        }
        if let Some(h) = self.heading {
            v[2] = h.sin() as f32;
            v[3] = h.cos() as f32;
            m[2] = 1.0;
            m[3] = 1.0;
        }
        (v, m)
    }

    /// Inverse of `channels` (a channel pair counts as observed when its mask is set).
    pub fn from_channels(v: &[f32], m: &[f32]) -> RootKey {
        RootKey {
            place: (m[0] > 0.0)
                .then(|| [v[0] as f64 * ROOT_POS_SCALE, v[1] as f64 * ROOT_POS_SCALE]),
            heading: (m[2] > 0.0).then(|| (v[2] as f64).atan2(v[3] as f64)),
        }
    }
}

/// Heading (radians, 0 facing +Z) of HumanML3D's root yaw angle `a`: the root quaternion
/// (cos a, 0, sin a, 0) turns by 2a, and positions use its inverse.
pub fn heading_of_angle(a: f64) -> f64 {
    -2.0 * a
}

/// Place and heading of every frame of de-normalised features [T, D].
pub fn root_trajectory(feats: &[f32], dim: usize) -> Vec<RootKey> {
    let f64s: Vec<f64> = feats.iter().map(|&v| v as f64).collect();
    let (_, pos) = recover_root_rot_pos(&f64s, dim);
    let mut angle = 0.0;
    (0..pos.len())
        .map(|i| {
            if i > 0 {
                angle += f64s[(i - 1) * dim];
            }
            RootKey { place: Some([pos[i][0], pos[i][2]]), heading: Some(heading_of_angle(angle)) }
        })
        .collect()
}

/// Root channels [T, 4] of a whole motion (every frame observed), as training keyframes see them.
pub fn root_channels(feats: &[f32], dim: usize) -> Vec<f32> {
    root_trajectory(feats, dim).iter().flat_map(|k| k.channels().0).collect()
}

//! An absolute root for the network (our extension, `model.absolute_root`). HumanML3D features
//! carry the root as per-frame velocities (yaw rate, and the ground-plane step in the facing
//! frame), so a keyed place is the sum of every earlier frame's velocity: a small bias per
//! frame becomes metres at a key, and the tiny networks never learned to reach keyed places
//! (root keys on or off gave the same K-Err, docs/reference-model.md). As CondMDI does, a
//! model with an absolute root sees instead, in the same three channels, the root's yaw angle
//! and ground-plane place in the motion's frame (frame 0 at the origin facing +Z); keyed
//! places and headings are then observed values like any pose feature. The conversion is exact
//! both ways (the last frame's velocities, which no position depends on, repeat the previous
//! frame's), so data, outputs and the evaluator stay HumanML3D.

use crate::motion::quat;
use crate::motion::representation::recover_root_rot_pos;
use crate::motion::root_key::{RootKey, ROOT_CHANNELS};

/// The channels that change meaning: 0 yaw (velocity -> angle), 1 and 2 x and z (velocity in
/// the facing frame -> place).
pub const CHANNELS: usize = 3;
/// Scale of the absolute channels in the network's normalised space (radians of HumanML3D's
/// yaw angle, which is half the heading; metres): values are divided by it, mean 0.
pub const ANGLE_SCALE: f32 = 1.0;
pub const PLACE_SCALE: f32 = 1.0;

/// Normalisation (mean, std) of the velocity channels 0..3 in the dataset's statistics, needed
/// to move between the two normalised spaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityStats {
    pub mean: [f32; CHANNELS],
    pub std: [f32; CHANNELS],
}

impl VelocityStats {
    /// From a dataset's full Mean/Std vectors.
    pub fn of(mean: &[f32], std: &[f32]) -> VelocityStats {
        let take = |v: &[f32]| [v[0], v[1], v[2]];
        VelocityStats { mean: take(mean), std: take(std) }
    }

    /// As stored in a model's config: the three means then the three stds.
    pub fn from_flat(v: &[f32]) -> Option<VelocityStats> {
        (v.len() == 2 * CHANNELS).then(|| VelocityStats::of(&v[..CHANNELS], &v[CHANNELS..]))
    }

    pub fn flat(&self) -> Vec<f32> {
        self.mean.iter().chain(&self.std).copied().collect()
    }

    /// The de-normalised velocity root channels of a normalised motion's first `len` frames
    /// as rows of four (the fourth, height, zero), the layout `recover_root_rot_pos` reads
    /// with `dim` 4.
    pub fn raw_rows(&self, x: &[f32], len: usize, dim: usize) -> Vec<f64> {
        let mut raw = vec![0f64; len * 4];
        for f in 0..len {
            for c in 0..CHANNELS {
                raw[f * 4 + c] = (x[f * dim + c] * self.std[c] + self.mean[c]) as f64;
            }
        }
        raw
    }
}

/// Mask of the absolute channels (yaw angle, place x, place z) from one frame's root-key mask
/// (`RootKey::channels`: place x, place z, heading sin, cos).
pub fn observed(root_mask: &[f32]) -> [f32; CHANNELS] {
    [root_mask[2], root_mask[0], root_mask[1]]
}

/// One normalised motion [frames, dim] (its first `len` frames real): velocity root channels
/// to absolute ones, in place. Padding stays as it is.
pub fn to_absolute(x: &mut [f32], len: usize, dim: usize, s: &VelocityStats) {
    if len == 0 {
        return;
    }
    let raw = s.raw_rows(x, len, dim);
    let (_, pos) = recover_root_rot_pos(&raw, 4);
    let mut angle = 0.0;
    for f in 0..len {
        if f > 0 {
            angle += raw[(f - 1) * 4];
        }
        let row = &mut x[f * dim..f * dim + CHANNELS];
        row[0] = angle as f32 / ANGLE_SCALE;
        row[1] = pos[f][0] as f32 / PLACE_SCALE;
        row[2] = pos[f][2] as f32 / PLACE_SCALE;
    }
}

/// The inverse of [`to_absolute`], in place.
pub fn to_relative(x: &mut [f32], len: usize, dim: usize, s: &VelocityStats) {
    let abs: Vec<[f64; 3]> = (0..len)
        .map(|f| {
            let r = &x[f * dim..f * dim + CHANNELS];
            [(r[0] * ANGLE_SCALE) as f64, (r[1] * PLACE_SCALE) as f64, (r[2] * PLACE_SCALE) as f64]
        })
        .collect();
    for f in 0..len {
        // Frame f's velocities lead to frame f + 1; the last frame repeats the one before.
        let g = if f + 1 < len { f + 1 } else { f };
        let vel = if g == 0 {
            [0.0; 3]
        } else {
            let (a, b) = (abs[g - 1], abs[g]);
            let step = [b[1] - a[1], 0.0, b[2] - a[2]];
            let v = quat::qrot(quat::root_yaw_quat(b[0]), step);
            [b[0] - a[0], v[0], v[2]]
        };
        for c in 0..CHANNELS {
            x[f * dim + c] = ((vel[c] - s.mean[c] as f64) / s.std[c] as f64) as f32;
        }
    }
}

/// Keyframe values and mask of the absolute channels for one motion from its root keys
/// ([frames, ROOT_CHANNELS] values and mask, `RootKey::channels`), written into `kf` and
/// `mask` ([frames, dim], normalised): a keyed place observes channels 1 and 2, a keyed heading
/// channel 0; every other frame leaves them unobserved. Headings are unwrapped from frame 0's
/// (0) through the keys in order, each turned by whole turns to the nearest of the one before,
/// as the network's angle is continuous.
pub fn keyframes(
    root: &[f32],
    root_mask: &[f32],
    frames: usize,
    kf: &mut [f32],
    mask: &mut [f32],
    dim: usize,
) {
    let r = ROOT_CHANNELS;
    let mut last_heading = 0.0f64;
    for f in 0..frames {
        let rm = &root_mask[f * r..(f + 1) * r];
        let key = RootKey::from_channels(&root[f * r..(f + 1) * r], rm);
        mask[f * dim..f * dim + CHANNELS].copy_from_slice(&observed(rm));
        let row = &mut kf[f * dim..f * dim + CHANNELS];
        row.fill(0.0);
        if let Some(h) = key.heading {
            let turns = ((last_heading - h) / std::f64::consts::TAU).round();
            let h = h + turns * std::f64::consts::TAU;
            last_heading = h;
            // HumanML3D's yaw angle is minus half the heading (`root_key::heading_of_angle`).
            row[0] = (-h / 2.0) as f32 / ANGLE_SCALE;
        }
        if let Some([x, z]) = key.place {
            row[1] = x as f32 / PLACE_SCALE;
            row[2] = z as f32 / PLACE_SCALE;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::root_key;
    use crate::rng::Rng;

    /// A turning walk's normalised features (only channels 0..4 matter here).
    fn walk(len: usize, dim: usize, s: &VelocityStats) -> Vec<f32> {
        let mut rng = Rng::new(3);
        let mut x = vec![0f32; len * dim];
        for f in 0..len {
            let raw =
                [0.03 + 0.01 * rng.normal(), 0.005 * rng.normal(), 0.04 + 0.01 * rng.normal()];
            for c in 0..CHANNELS {
                x[f * dim + c] = ((raw[c] - s.mean[c] as f64) / s.std[c] as f64) as f32;
            }
            x[f * dim + 3] = 0.9;
        }
        x
    }

    fn stats() -> VelocityStats {
        VelocityStats { mean: [0.001, 0.0, 0.017], std: [0.007, 0.025, 0.025] }
    }

    #[test]
    fn absolute_channels_are_the_recovered_path_and_convert_back() {
        let (len, dim, s) = (60, 7, stats());
        let x = walk(len, dim, &s);
        let mut abs = x.clone();
        to_absolute(&mut abs, len, dim, &s);
        // The places are those HumanML3D's recovery gives (an independent path to them).
        let mut raw = x.clone();
        for f in 0..len {
            for c in 0..CHANNELS {
                raw[f * dim + c] = raw[f * dim + c] * s.std[c] + s.mean[c];
            }
        }
        for (f, k) in root_key::root_trajectory(&raw, dim).iter().enumerate() {
            let [px, pz] = k.place.unwrap();
            assert!((abs[f * dim + 1] as f64 * PLACE_SCALE as f64 - px).abs() < 1e-4);
            assert!((abs[f * dim + 2] as f64 * PLACE_SCALE as f64 - pz).abs() < 1e-4);
            let h = root_key::heading_of_angle((abs[f * dim] * ANGLE_SCALE) as f64);
            let kh = k.heading.unwrap();
            assert!((h.sin() - kh.sin()).abs() < 1e-4 && (h.cos() - kh.cos()).abs() < 1e-4);
        }
        let mut back = abs.clone();
        to_relative(&mut back, len, dim, &s);
        // Every frame but the last (whose velocities nothing depends on) comes back.
        for f in 0..len - 1 {
            for c in 0..dim {
                let (a, b) = (back[f * dim + c], x[f * dim + c]);
                assert!((a - b).abs() < 2e-3, "frame {f} channel {c}: {a} vs {b}");
            }
        }
        let last = (len - 1) * dim;
        assert_eq!(back[last..last + CHANNELS], back[last - dim..last - dim + CHANNELS]);
        // And so the path recovered from the converted motion is the same.
        let mut twice = back.clone();
        to_absolute(&mut twice, len, dim, &s);
        for (a, b) in twice.iter().zip(&abs) {
            assert!((a - b).abs() < 1e-4);
        }
    }

    #[test]
    fn keyed_places_and_unwrapped_headings_become_observed_channels() {
        let (frames, dim) = (10, 5);
        let r = ROOT_CHANNELS;
        let (mut root, mut root_mask) = (vec![0f32; frames * r], vec![0f32; frames * r]);
        let mut put = |f: usize, key: RootKey| {
            let (v, m) = key.channels();
            root[f * r..(f + 1) * r].copy_from_slice(&v);
            root_mask[f * r..(f + 1) * r].copy_from_slice(&m);
        };
        let deg = |d: f64| d.to_radians();
        put(2, RootKey { place: Some([1.0, 2.0]), heading: Some(deg(170.0)) });
        put(5, RootKey { place: None, heading: Some(deg(-170.0)) });
        put(7, RootKey { place: Some([-0.5, 3.0]), heading: None });
        let (mut kf, mut mask) = (vec![9f32; frames * dim], vec![9f32; frames * dim]);
        keyframes(&root, &root_mask, frames, &mut kf, &mut mask, dim);
        assert_eq!(&mask[2 * dim..2 * dim + 3], &[1.0, 1.0, 1.0]);
        assert_eq!(&mask[5 * dim..5 * dim + 3], &[1.0, 0.0, 0.0]);
        assert_eq!(&mask[7 * dim..7 * dim + 3], &[0.0, 1.0, 1.0]);
        assert!(mask[..3].iter().chain(&kf[..3]).all(|&v| v == 0.0));
        assert_eq!(&kf[7 * dim + 1..7 * dim + 3], &[-0.5, 3.0]);
        // -170 degrees after 170 is 190: a 20-degree turn, not 340 back.
        let h5 = root_key::heading_of_angle((kf[5 * dim] * ANGLE_SCALE) as f64);
        assert!((h5 - deg(190.0)).abs() < 1e-5, "{}", h5.to_degrees());
        // Channels past the root's are left alone.
        assert!(kf[2 * dim + 3..3 * dim].iter().all(|&v| v == 9.0));
    }
}

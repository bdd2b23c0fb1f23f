//! Dense root tracks: the root observed on every frame (or a dense subset) rather than at a few
//! keyframes. A sparse keyed place is easily ignored by a denoiser; a dense track is not (GMD,
//! CondMDI), so training shows the network tracks and sampling's second stage observes one.
//!
//! A track frame observes the root's local velocities (HumanML3D features 0..3: yaw rate and
//! the facing-frame ground step) and its place and heading channels (`root_key::RootKey`); the
//! root height and the pose stay free.

use std::ops::Range;

use crate::motion::root_key::ROOT_CHANNELS;
use crate::rng::Rng;

/// Feature dims a track observes: root yaw rate, ground velocity x and z.
pub const TRACK_DIMS: Range<usize> = 0..3;

/// How often and how densely training samples observe a root track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackSchedule {
    /// Probability that a (not dropped) training sample observes a root track.
    pub prob: f64,
    /// Smallest fraction of frames a track observes; half the tracks observe every frame, the
    /// others a uniform fraction in [min_density, 1).
    pub min_density: f64,
}

impl TrackSchedule {
    /// The frames of a `len`-frame sample that observe the track (sorted; empty when the
    /// sample draws none). Draws nothing from `rng` when `prob` is 0, so schedules without
    /// tracks keep every other draw of the loader unchanged.
    pub fn draw(&self, len: usize, rng: &mut Rng) -> Vec<usize> {
        if self.prob <= 0.0 || len == 0 || !rng.chance(self.prob) {
            return vec![];
        }
        if rng.chance(0.5) {
            return (0..len).collect();
        }
        let density = rng.range(self.min_density.clamp(0.0, 1.0), 1.0);
        let k = ((density * len as f64).round() as usize).clamp(1, len);
        rng.sample_sorted(len, k)
    }
}

/// Whether a keyframe mask row `[D]` observes anything besides the track dims: a pose key, as
/// opposed to a frame that only carries the root track.
pub fn is_pose_key(mask_row: &[f32]) -> bool {
    mask_row.iter().enumerate().any(|(k, &m)| m > 0.0 && !TRACK_DIMS.contains(&k))
}

/// Observe the track of a motion on `frames`: its normalised features `x` [T, D] give the track
/// dims of `kf`/`mask` [T, D], its root channels `channels` [T, ROOT_CHANNELS] (`root_key::root_channels`)
/// give `root`/`root_mask` [T, ROOT_CHANNELS]. Dims already observed (a pose key's own root
/// velocities) keep their values.
#[allow(clippy::too_many_arguments)]
pub fn observe(
    x: &[f32],
    channels: &[f32],
    dim: usize,
    frames: &[usize],
    kf: &mut [f32],
    mask: &mut [f32],
    root: &mut [f32],
    root_mask: &mut [f32],
) {
    let r = ROOT_CHANNELS;
    for &f in frames {
        for k in TRACK_DIMS.map(|k| f * dim + k) {
            if mask[k] <= 0.0 {
                kf[k] = x[k];
                mask[k] = 1.0;
            }
        }
        root[f * r..(f + 1) * r].copy_from_slice(&channels[f * r..(f + 1) * r]);
        root_mask[f * r..(f + 1) * r].iter_mut().for_each(|m| *m = 1.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_track_draws_nothing() {
        let s = TrackSchedule { prob: 0.0, min_density: 0.25 };
        let mut a = Rng::new(3);
        let b = a.clone();
        assert!(s.draw(100, &mut a).is_empty());
        assert_eq!(a.state(), b.state(), "a zero probability must not consume draws");
    }

    #[test]
    fn tracks_are_dense_and_reproducible() {
        let s = TrackSchedule { prob: 0.4, min_density: 0.25 };
        let (mut with, mut full) = (0, 0);
        for i in 0..2000 {
            let t = s.draw(120, &mut Rng::derive(9, 1, i));
            assert_eq!(t, s.draw(120, &mut Rng::derive(9, 1, i)), "same seed, same track");
            if t.is_empty() {
                continue;
            }
            with += 1;
            assert!(t.len() >= 30, "density at least 0.25: {}", t.len());
            assert!(t.windows(2).all(|w| w[0] < w[1]) && *t.last().unwrap() < 120);
            full += usize::from(t.len() == 120);
        }
        let frac = with as f64 / 2000.0;
        assert!((frac - 0.4).abs() < 0.04, "fraction of samples with a track: {frac}");
        let half = full as f64 / with as f64;
        assert!((half - 0.5).abs() < 0.06, "fraction of full tracks: {half}");
    }

    #[test]
    fn observe_sets_track_dims_and_channels_only() {
        let (t, d, r) = (4, 6, ROOT_CHANNELS);
        let x: Vec<f32> = (0..t * d).map(|v| v as f32).collect();
        let ch: Vec<f32> = (0..t * r).map(|v| -(v as f32)).collect();
        let (mut kf, mut mask) = (vec![0.0; t * d], vec![0.0; t * d]);
        let (mut root, mut rm) = (vec![0.0; t * r], vec![0.0; t * r]);
        observe(&x, &ch, d, &[1, 3], &mut kf, &mut mask, &mut root, &mut rm);
        for f in 0..t {
            let on = f == 1 || f == 3;
            for k in 0..d {
                let want = on && k < 3;
                assert_eq!(mask[f * d + k] > 0.0, want, "frame {f} dim {k}");
                assert_eq!(kf[f * d + k], if want { x[f * d + k] } else { 0.0 });
            }
            assert_eq!(rm[f * r] > 0.0, on);
            assert!(!is_pose_key(&mask[f * d..(f + 1) * d]), "a track frame is no pose key");
        }
        mask[2 * d + 4] = 1.0;
        assert!(is_pose_key(&mask[2 * d..3 * d]));
    }
}

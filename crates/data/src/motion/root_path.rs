//! The keyed root path as a per-frame hint for the denoiser's decoder. A keyed place says
//! where the root stands at one frame; the features carry root *velocities*, so reaching it
//! means spreading the right speed over every frame before it. Keyframe tokens hold the
//! places themselves, and the reference model learned to ignore them (root keys on or off gave
//! the same K-Err, 0.534 m, README "Keyframes that pin pose and place"). This hands each frame
//! the average velocity the keys imply for it: between consecutive keyed places (frame 0 is
//! the origin, HumanML3D's canonical frame), the straight-line step per second; no hint after
//! the last keyed place or when no place is keyed.

use crate::motion::root_key::{RootKey, ROOT_CHANNELS};

/// Channels per frame: velocity x and z (metres per second, canonical frame), speed, mask.
pub const PATH_CHANNELS: usize = 4;

/// Path hints [len, PATH_CHANNELS] of one motion from its root key channels and mask
/// ([len, ROOT_CHANNELS] each, `RootKey::channels`); `fps` frames per second.
pub fn path_channels(root: &[f32], root_mask: &[f32], len: usize, fps: f64) -> Vec<f32> {
    let r = ROOT_CHANNELS;
    let mut out = vec![0f32; len * PATH_CHANNELS];
    let mut anchors: Vec<(usize, [f64; 2])> = (1..len)
        .filter_map(|f| {
            RootKey::from_channels(&root[f * r..(f + 1) * r], &root_mask[f * r..(f + 1) * r])
                .place
                .map(|p| (f, p))
        })
        .collect();
    if anchors.is_empty() {
        return out;
    }
    anchors.insert(0, (0, [0.0, 0.0]));
    for w in anchors.windows(2) {
        let ((a, pa), (b, pb)) = (w[0], w[1]);
        let per_s = fps / (b - a) as f64;
        let v = [(pb[0] - pa[0]) * per_s, (pb[1] - pa[1]) * per_s];
        let speed = (v[0] * v[0] + v[1] * v[1]).sqrt();
        for f in a..b {
            let row = &mut out[f * PATH_CHANNELS..(f + 1) * PATH_CHANNELS];
            row.copy_from_slice(&[v[0] as f32, v[1] as f32, speed as f32, 1.0]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(len: usize, places: &[(usize, [f64; 2])]) -> (Vec<f32>, Vec<f32>) {
        let (mut v, mut m) = (vec![0f32; len * ROOT_CHANNELS], vec![0f32; len * ROOT_CHANNELS]);
        for &(f, p) in places {
            let (cv, cm) = RootKey { place: Some(p), heading: Some(0.3) }.channels();
            v[f * ROOT_CHANNELS..(f + 1) * ROOT_CHANNELS].copy_from_slice(&cv);
            m[f * ROOT_CHANNELS..(f + 1) * ROOT_CHANNELS].copy_from_slice(&cm);
        }
        (v, m)
    }

    #[test]
    fn frames_get_the_speed_that_reaches_the_next_place() {
        let len = 50;
        let (v, m) = keys(len, &[(20, [0.0, 2.0]), (40, [1.0, 2.0])]);
        let p = path_channels(&v, &m, len, 20.0);
        let row = |f: usize| &p[f * PATH_CHANNELS..(f + 1) * PATH_CHANNELS];
        // 2 m in 20 frames at 20 fps: 2 m/s forward; then 1 m sideways in 1 s.
        for f in 0..20 {
            assert!((row(f)[1] - 2.0).abs() < 1e-5 && row(f)[0].abs() < 1e-6, "{:?}", row(f));
            assert_eq!(row(f)[3], 1.0);
        }
        for f in 20..40 {
            assert!((row(f)[0] - 1.0).abs() < 1e-5 && (row(f)[2] - 1.0).abs() < 1e-5);
        }
        // Integrating the hint from the origin lands on every keyed place.
        let z: f32 = (0..20).map(|f| row(f)[1] / 20.0).sum();
        assert!((z - 2.0).abs() < 1e-4);
        assert!((40..len).all(|f| row(f).iter().all(|&c| c == 0.0)));
    }

    #[test]
    fn no_places_no_hint_and_headings_alone_give_none() {
        let len = 30;
        let (v, m) = keys(len, &[]);
        assert!(path_channels(&v, &m, len, 20.0).iter().all(|&c| c == 0.0));
        let (mut v, mut m) = keys(len, &[(10, [1.0, 1.0])]);
        // Drop the place pair, keep the heading.
        m[10 * ROOT_CHANNELS] = 0.0;
        m[10 * ROOT_CHANNELS + 1] = 0.0;
        v[10 * ROOT_CHANNELS] = 0.0;
        assert!(path_channels(&v, &m, len, 20.0).iter().all(|&c| c == 0.0));
    }
}

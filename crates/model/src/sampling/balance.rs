//! How far the pipeline trusts the network between keys: per frame, the motion is pulled
//! towards the keys' linear interpolation (`sampling::interpolation`) as far as the network failed to
//! reproduce the keys it was given. Where the network's own pose at the keys is close to them
//! (motion like its training set), its in-betweens are kept; where it is far (a cartwheel, a
//! crawl: motion it never saw), the keys' interpolation wins, so in-betweens are never much
//! further from the truth than interpolating the keys (after AIS's per-frame balance of learned
//! interpolation and synthesis). With the track fit, the network's first, unaided sample is
//! judged too: a network that only meets the keys once given the keyed path is not trusted
//! between them. Reads only the request and the samples, never the truth.

use diffkfc_data::motion::representation::Layout;
use diffkfc_data::postprocess::smoothstep;

/// The network's pose error at a key (metres) at which its in-betweens keep e^-1 of their
/// weight: a limb about a hand's width off.
pub const TRUST_M: f64 = 0.15;

/// Mean distance (metres) of the network's root-relative joints (RIC) and root height from the
/// key's, in one frame of de-normalised features.
fn pose_error(layout: &Layout, raw: &[f32], key: &[f32]) -> f64 {
    let ric = layout.ric();
    let joints = ric.len() / 3;
    let mut sum = (raw[3] - key[3]).abs() as f64;
    for j in 0..joints {
        let o = ric.start + 3 * j;
        sum += (0..3).map(|k| ((raw[o + k] - key[o + k]) as f64).powi(2)).sum::<f64>().sqrt();
    }
    sum / (joints + 1) as f64
}

/// Frames over which the weight returns to the network's past the first and last keys.
pub const EDGE: usize = 10;

/// Per frame, the weight of the network's motion against the interpolation: at each key
/// exp(-(error / TRUST_M)^2), blended smoothly between keys. Before the first key and after the
/// last the interpolation only holds a key (no in-between to lean on), so the weight returns
/// to 1 over [`EDGE`] frames there: a timeline window keyed on its first frames keeps the
/// network's motion after them.
pub fn weights(
    layout: &Layout,
    raw: &[f32],
    target: &[f32],
    keys: &[usize],
    len: usize,
) -> Vec<f64> {
    let d = layout.dim();
    let at: Vec<(usize, f64)> = keys
        .iter()
        .filter(|&&f| f < len)
        .map(|&f| {
            let e = pose_error(layout, &raw[f * d..(f + 1) * d], &target[f * d..(f + 1) * d]);
            (f, (-(e / TRUST_M).powi(2)).exp())
        })
        .collect();
    let (Some(&(first, c0)), Some(&(last, cn))) = (at.first(), at.last()) else {
        return vec![1.0; len];
    };
    let edge = |c: f64, dist: usize| c + (1.0 - c) * smoothstep(dist as f64 / EDGE as f64);
    (0..len)
        .map(|f| {
            if f < first {
                return edge(c0, first - f);
            }
            if f > last {
                return edge(cn, f - last);
            }
            let i = at.partition_point(|&(k, _)| k <= f) - 1;
            match at.get(i + 1) {
                Some(&(k2, c2)) => {
                    let (k1, c1) = at[i];
                    c1 + (c2 - c1) * smoothstep((f - k1) as f64 / (k2 - k1) as f64)
                }
                None => at[i].1,
            }
        })
        .collect()
}

/// `out` = interpolation + w (out - interpolation) per frame, on every channel but the foot
/// contacts (labels of the motion's own feet); de-normalised features [len, D].
pub fn pull_towards(layout: &Layout, out: &mut [f32], interpolation: &[f32], w: &[f64]) {
    let d = layout.dim();
    let contacts = layout.contacts().start;
    for (f, &wf) in w.iter().enumerate() {
        for c in 0..contacts {
            let (o, a) = (out[f * d + c] as f64, interpolation[f * d + c] as f64);
            out[f * d + c] = (a + wf * (o - a)) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::T2M;

    #[test]
    fn exact_keys_keep_the_network_and_far_keys_give_the_interpolation() {
        let layout = Layout::of(&T2M);
        let d = layout.dim();
        let len = 21;
        let target = vec![0.0f32; len * d];
        let mut raw = target.clone();
        // The network is 0.3 m off (every RIC coordinate 0.3/sqrt(3)) at key 20, exact at 0.
        let ric = layout.ric();
        raw[20 * d + ric.start..20 * d + ric.end].iter_mut().for_each(|v| *v = 0.3 / 3f32.sqrt());
        let w = weights(&layout, &raw, &target, &[0, 20], len);
        assert!((w[0] - 1.0).abs() < 1e-12);
        let expect = (-(0.3 * 21.0 / 22.0 / TRUST_M).powi(2)).exp();
        assert!((w[20] - expect).abs() < 1e-6, "{} {expect}", w[20]);
        assert!(w[10] < w[5] && w[5] < w[0], "{w:?}");
        // Past the last key the weight returns to the network's: keys 0 and 20 read at 0 and 10.
        let mut early = target.clone();
        early[10 * d..11 * d].copy_from_slice(&raw[20 * d..21 * d]);
        let w_past = weights(&layout, &early, &target, &[0, 10], len);
        assert!(w_past[10] < 0.5 && w_past[20] == 1.0 && w_past[15] > w_past[10], "{w_past:?}");
        let mut out = vec![1.0f32; len * d];
        pull_towards(&layout, &mut out, &vec![0.0; len * d], &w);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[20 * d] as f64 - expect).abs() < 1e-6);
        // Contacts are the motion's own.
        assert_eq!(out[20 * d + layout.contacts().start], 1.0);
    }
}

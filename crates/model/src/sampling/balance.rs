//! How far the pipeline trusts the network between keys: per frame and body part, the motion
//! is pulled towards the keys' linear interpolation (`sampling::interpolation`) as far as the
//! network failed to reproduce that part of the keys it was given. Where the network's own pose
//! at the keys is close to them (motion like its training set), its in-betweens are kept; where
//! it is far (a cartwheel, a crawl: motion it never saw), the keys' interpolation wins, so
//! in-betweens are never much further from the truth than interpolating the keys (after AIS's
//! per-frame balance of learned interpolation and synthesis). The lower body (pelvis, path and
//! legs) and the rest are judged apart: a walk whose arms the network misses keeps its own
//! stepping legs. With the track fit, the network's first, unaided sample is judged too: a
//! network that only meets the keys once given the keyed path is not trusted between them.
//! Reads only the request and the samples, never the truth.

use diffkfc_data::keyframes::dim_mask;
use diffkfc_data::motion::representation::Layout;
use diffkfc_data::postprocess::smoothstep;
use diffkfc_data::Skeleton;

/// The network's pose error at a key (metres) at which its in-betweens keep e^-1 of their
/// weight: a limb about a hand's width off.
pub const TRUST_M: f64 = 0.15;

/// A body part the balance weighs on its own: its joints (0, the root, stands for its height)
/// and the feature channels it pulls.
pub struct Part {
    pub joints: Vec<usize>,
    pub channels: Vec<bool>,
}

/// The skeleton's lower body (pelvis with the root's channels, legs) and upper body; the whole
/// body as one part where the skeleton names no such halves.
pub fn parts(skel: &Skeleton) -> Vec<Part> {
    let part =
        |joints: &[usize]| Part { joints: joints.to_vec(), channels: dim_mask(skel, Some(joints)) };
    match (skel.part("lower_body"), skel.part("upper_body")) {
        (Some(lower), Some(upper)) => vec![part(lower.joints), part(upper.joints)],
        _ => {
            vec![Part { joints: (0..skel.num_joints()).collect(), channels: dim_mask(skel, None) }]
        }
    }
}

/// Mean distance (metres) of the network's root-relative joints (RIC; the root: its height)
/// from the key's over `joints`, in one frame of de-normalised features.
fn pose_error(layout: &Layout, raw: &[f32], key: &[f32], joints: &[usize]) -> f64 {
    let ric = layout.ric().start;
    let error = |j: usize| {
        if j == 0 {
            return (raw[3] - key[3]).abs() as f64;
        }
        let o = ric + 3 * (j - 1);
        (0..3).map(|k| ((raw[o + k] - key[o + k]) as f64).powi(2)).sum::<f64>().sqrt()
    };
    joints.iter().map(|&j| error(j)).sum::<f64>() / joints.len().max(1) as f64
}

/// Frames over which the weight returns to the network's past the first and last keys.
pub const EDGE: usize = 10;

/// Per frame, the weight of the network's motion of the part `joints` against the
/// interpolation: at each key exp(-(error / TRUST_M)^2), blended smoothly between keys. Before
/// the first key and after the last the interpolation only holds a key (no in-between to lean
/// on), so the weight returns to 1 over [`EDGE`] frames there: a timeline window keyed on its
/// first frames keeps the network's motion after them.
pub fn weights(
    layout: &Layout,
    (raw, target): (&[f32], &[f32]),
    joints: &[usize],
    keys: &[usize],
    len: usize,
) -> Vec<f64> {
    let d = layout.dim();
    let at: Vec<(usize, f64)> = keys
        .iter()
        .filter(|&&f| f < len)
        .map(|&f| {
            let e =
                pose_error(layout, &raw[f * d..(f + 1) * d], &target[f * d..(f + 1) * d], joints);
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

/// `out` = interpolation + w (out - interpolation) per frame, on the `channels` marked but
/// never the foot contacts (labels of the motion's own feet); de-normalised features [len, D].
pub fn pull_towards(
    layout: &Layout,
    out: &mut [f32],
    interpolation: &[f32],
    w: &[f64],
    channels: &[bool],
) {
    let d = layout.dim();
    let pulled: Vec<usize> = (0..layout.contacts().start).filter(|&c| channels[c]).collect();
    for (f, &wf) in w.iter().enumerate() {
        for &c in &pulled {
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
        let all: Vec<usize> = (0..22).collect();
        let target = vec![0.0f32; len * d];
        let mut raw = target.clone();
        // The network is 0.3 m off (every RIC coordinate 0.3/sqrt(3)) at key 20, exact at 0.
        let ric = layout.ric();
        raw[20 * d + ric.start..20 * d + ric.end].iter_mut().for_each(|v| *v = 0.3 / 3f32.sqrt());
        let w = weights(&layout, (&raw, &target), &all, &[0, 20], len);
        assert!((w[0] - 1.0).abs() < 1e-12);
        let expect = (-(0.3 * 21.0 / 22.0 / TRUST_M).powi(2)).exp();
        assert!((w[20] - expect).abs() < 1e-6, "{} {expect}", w[20]);
        assert!(w[10] < w[5] && w[5] < w[0], "{w:?}");
        // Past the last key the weight returns to the network's: keys 0 and 20 read at 0 and 10.
        let mut early = target.clone();
        early[10 * d..11 * d].copy_from_slice(&raw[20 * d..21 * d]);
        let w_past = weights(&layout, (&early, &target), &all, &[0, 10], len);
        assert!(w_past[10] < 0.5 && w_past[20] == 1.0 && w_past[15] > w_past[10], "{w_past:?}");
        let mut out = vec![1.0f32; len * d];
        pull_towards(&layout, &mut out, &vec![0.0; len * d], &w, &vec![true; d]);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[20 * d] as f64 - expect).abs() < 1e-6);
        // Contacts are the motion's own.
        assert_eq!(out[20 * d + layout.contacts().start], 1.0);
    }

    /// Arms missed, legs met: the arms lean on the interpolation, the legs and the path keep
    /// the network's motion; the two halves cover every channel once.
    #[test]
    fn each_part_is_trusted_as_far_as_it_met_its_keys() {
        let layout = Layout::of(&T2M);
        let d = layout.dim();
        let len = 21;
        let parts = parts(&T2M);
        assert_eq!(parts.len(), 2);
        for c in 0..d {
            assert_eq!(parts.iter().filter(|p| p.channels[c]).count(), 1, "channel {c}");
        }
        let (lower, rest) = (&parts[0], &parts[1]);
        assert!(lower.channels[..4].iter().all(|&on| on), "the root's channels go with the legs");
        let target = vec![0.0f32; len * d];
        let mut raw = target.clone();
        for &j in &rest.joints {
            let o = layout.ric().start + 3 * (j - 1);
            raw[20 * d + o..20 * d + o + 3].iter_mut().for_each(|v| *v = 0.3 / 3f32.sqrt());
        }
        let w_lower = weights(&layout, (&raw, &target), &lower.joints, &[0, 20], len);
        let w_rest = weights(&layout, (&raw, &target), &rest.joints, &[0, 20], len);
        assert!(w_lower.iter().all(|&w| w == 1.0), "{w_lower:?}");
        assert!(w_rest[20] < 0.1, "{w_rest:?}");
        let mut out = vec![1.0f32; len * d];
        for (p, w) in [(lower, &w_lower), (rest, &w_rest)] {
            pull_towards(&layout, &mut out, &vec![0.0; len * d], w, &p.channels);
        }
        let wrist = layout.ric().start + 3 * (20 - 1);
        let ankle = layout.ric().start + 3 * (7 - 1);
        assert!(out[20 * d + wrist] < 0.1 && out[20 * d + ankle] == 1.0 && out[20 * d + 1] == 1.0);
    }
}

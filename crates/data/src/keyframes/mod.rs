//! Keyframe selection (which frames are observed) and partial keyframes (which feature dims of
//! an observed frame belong to a body part).

use serde::{Deserialize, Serialize};

use crate::motion::representation::Layout;
use crate::motion::skeleton::Skeleton;
use crate::rng::Rng;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Uniformly random positions (the paper's training default).
    #[default]
    Random,
    /// Evenly spaced, first and last frame included.
    Uniform,
    /// KeyMotion's maximum-distance-optimal selection.
    Mdo,
}

impl std::str::FromStr for Strategy {
    type Err = crate::UnknownChoice;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "random" => Ok(Strategy::Random),
            "uniform" => Ok(Strategy::Uniform),
            "mdo" => Ok(Strategy::Mdo),
            _ => Err(crate::UnknownChoice {
                what: "keyframe strategy",
                given: s.into(),
                choices: "random, uniform, mdo",
            }),
        }
    }
}

/// Number of keyframes for a clip of `len` frames at `rate`: none at rate 0, else at least one.
pub fn count(len: usize, rate: f64) -> usize {
    if rate <= 0.0 || len == 0 {
        0
    } else {
        ((rate * len as f64).round() as usize).clamp(1, len)
    }
}

/// Evenly spaced frames including both ends (the middle frame when k = 1).
pub fn uniform(len: usize, k: usize) -> Vec<usize> {
    match k {
        0 => vec![],
        1 => vec![len / 2],
        _ => {
            let mut v: Vec<usize> = (0..k)
                .map(|i| ((i * (len - 1)) as f64 / (k - 1) as f64).round() as usize)
                .collect();
            v.dedup();
            v
        }
    }
}

/// Maximum-distance-optimal selection: the `k` frames (sorted) maximising the summed L2
/// distance between consecutive chosen frames, by dynamic programming in O(k N^2).
/// `frames` is row-major (N, D).
pub fn mdo(frames: &[f32], dim: usize, k: usize) -> Vec<usize> {
    let n = frames.len() / dim;
    let k = k.min(n);
    if k <= 1 {
        return if k == 1 { vec![0] } else { vec![] };
    }
    let dist = |i: usize, j: usize| -> f64 {
        frames[i * dim..(i + 1) * dim]
            .iter()
            .zip(&frames[j * dim..(j + 1) * dim])
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    // best[c][j]: best score of a chain of c+1 frames ending at j.
    let mut best = vec![vec![f64::NEG_INFINITY; n]; k];
    let mut from = vec![vec![usize::MAX; n]; k];
    best[0].iter_mut().for_each(|b| *b = 0.0);
    for c in 1..k {
        for j in c..n {
            for i in (c - 1)..j {
                let s = best[c - 1][i] + dist(i, j);
                if s > best[c][j] {
                    best[c][j] = s;
                    from[c][j] = i;
                }
            }
        }
    }
    let mut j = (k - 1..n).max_by(|&a, &b| best[k - 1][a].total_cmp(&best[k - 1][b])).unwrap();
    let mut out = vec![j];
    for c in (1..k).rev() {
        j = from[c][j];
        out.push(j);
    }
    out.reverse();
    out
}

/// Choose keyframes of a clip by strategy; `frames` (N, D) is used by MDO only.
pub fn select(
    strategy: Strategy,
    len: usize,
    rate: f64,
    frames: &[f32],
    dim: usize,
    rng: &mut Rng,
) -> Vec<usize> {
    let k = count(len, rate);
    match strategy {
        Strategy::Random => rng.sample_sorted(len, k),
        Strategy::Uniform => uniform(len, k),
        Strategy::Mdo => mdo(&frames[..len * dim], dim, k),
    }
}

/// The frames of `frames` whose mask `[T, D]` observes a pose (any root-relative joint
/// position): a key with only a place or a heading has none to compare.
pub fn posed_frames(skel: &Skeleton, mask: &[f32], frames: &[usize]) -> Vec<usize> {
    let (d, ric) = (skel.feature_dim(), Layout::of(skel).ric());
    frames
        .iter()
        .copied()
        .filter(|&f| {
            mask.get(f * d + ric.start..f * d + ric.end).is_some_and(|m| m.iter().any(|&v| v > 0.0))
        })
        .collect()
}

/// Feature dims owned by each joint: its RIC, 6D rotation and velocity, plus the foot
/// contacts of foot joints; the root joint also owns the four root dims.
pub fn joint_dims(skel: &Skeleton, joint: usize) -> Vec<usize> {
    let l = Layout::of(skel);
    let mut d = Vec::new();
    if joint == 0 {
        d.extend(0..4);
    } else {
        d.extend(l.ric().start + 3 * (joint - 1)..l.ric().start + 3 * joint);
        d.extend(l.rot().start + 6 * (joint - 1)..l.rot().start + 6 * joint);
    }
    d.extend(l.vel().start + 3 * joint..l.vel().start + 3 * joint + 3);
    let feet = [skel.feet_left[0], skel.feet_left[1], skel.feet_right[0], skel.feet_right[1]];
    if let Some(k) = feet.iter().position(|&f| f == joint) {
        d.push(l.contacts().start + k);
    }
    d
}

/// Per-dim mask (length D) observing the dims of `joints` (all dims when `joints` is None).
pub fn dim_mask(skel: &Skeleton, joints: Option<&[usize]>) -> Vec<bool> {
    let dim = skel.feature_dim();
    match joints {
        None => vec![true; dim],
        Some(js) => {
            let mut m = vec![false; dim];
            for &j in js {
                for d in joint_dims(skel, j) {
                    m[d] = true;
                }
            }
            m
        }
    }
}

/// A keyframe mask (N, D) row-major: 1 where frame `f` in `frames` and dim observed.
pub fn frame_mask(n: usize, frames: &[usize], dims: &[bool]) -> Vec<f32> {
    let d = dims.len();
    let mut m = vec![0f32; n * d];
    for &f in frames.iter().filter(|&&f| f < n) {
        for (k, &on) in dims.iter().enumerate() {
            if on {
                m[f * d + k] = 1.0;
            }
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::T2M;

    /// A pose key (any body part) counts; a key observing only the root height (a place) does not.
    #[test]
    fn posed_frames_skip_place_only_keys() {
        let d = T2M.feature_dim();
        let mut mask = frame_mask(10, &[2], &dim_mask(&T2M, Some(&[7, 10])));
        mask[5 * d + 3] = 1.0; // frame 5: root height only
        assert_eq!(posed_frames(&T2M, &mask, &[2, 5, 9]), vec![2]);
    }

    #[test]
    fn counts_and_uniform() {
        assert_eq!(count(196, 0.05), 10);
        assert_eq!(count(40, 0.02), 1);
        assert_eq!(count(40, 0.0), 0);
        assert_eq!(uniform(100, 3), vec![0, 50, 99]);
        assert_eq!(uniform(9, 1), vec![4]);
    }

    /// MDO against exhaustive search over all k-subsets.
    #[test]
    fn mdo_matches_brute_force() {
        let mut rng = Rng::new(11);
        for trial in 0..20 {
            let (n, dim, k) = (6 + trial % 5, 3, 2 + trial % 3);
            let f: Vec<f32> = (0..n * dim).map(|_| rng.normal() as f32).collect();
            let score = |s: &[usize]| -> f64 {
                s.windows(2)
                    .map(|w| {
                        (0..dim)
                            .map(|c| ((f[w[0] * dim + c] - f[w[1] * dim + c]) as f64).powi(2))
                            .sum::<f64>()
                            .sqrt()
                    })
                    .sum()
            };
            let mut best = f64::NEG_INFINITY;
            for bits in 0u32..(1 << n) {
                if bits.count_ones() as usize == k {
                    let s: Vec<usize> = (0..n).filter(|i| bits >> i & 1 == 1).collect();
                    best = best.max(score(&s));
                }
            }
            let got = mdo(&f, dim, k);
            assert_eq!(got.len(), k);
            assert!(got.windows(2).all(|w| w[0] < w[1]));
            assert!((score(&got) - best).abs() < 1e-9, "trial {trial}: {} vs {best}", score(&got));
        }
    }

    #[test]
    fn left_arm_dims_are_exactly_its_joints() {
        let js = T2M.resolve_joints("left_arm").unwrap();
        assert_eq!(js, vec![13, 16, 18, 20]);
        let m = dim_mask(&T2M, Some(&js));
        let on: Vec<usize> = (0..263).filter(|&d| m[d]).collect();
        let mut want = Vec::new();
        for j in [13usize, 16, 18, 20] {
            want.extend(4 + 3 * (j - 1)..4 + 3 * j);
            want.extend(67 + 6 * (j - 1)..67 + 6 * j);
            want.extend(193 + 3 * j..196 + 3 * j);
        }
        want.sort_unstable();
        assert_eq!(on, want);
        // The lower body holds the root dims and all four contacts.
        let lb = dim_mask(&T2M, Some(T2M.part("lower_body").unwrap().joints));
        assert!((0..4).chain(259..263).all(|d| lb[d]));
        // Every dim belongs to exactly one joint.
        let mut owners = vec![0; 263];
        for j in 0..22 {
            for d in joint_dims(&T2M, j) {
                owners[d] += 1;
            }
        }
        assert!(owners.iter().all(|&o| o == 1), "{owners:?}");
    }
}

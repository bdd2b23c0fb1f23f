//! K-Err and K-TranS (see the crate documentation for the definitions).

use diffkfc_data::motion::quat;
use diffkfc_data::motion::representation::{Joints, Layout};
use diffkfc_data::motion::skeleton::Skeleton;

/// Mean L2 distance between `gen` and `reference` over the given frames and joints (global).
pub fn k_err_global(
    gen: &Joints,
    reference: &Joints,
    frames: &[usize],
    joints: &[usize],
) -> Option<f64> {
    let mut sum = 0.0;
    let mut n = 0usize;
    for &f in frames.iter().filter(|&&f| f < gen.len() && f < reference.len()) {
        for &j in joints {
            sum += quat::norm(quat::sub(gen[f][j], reference[f][j]));
            n += 1;
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// Root-relative, facing-normalised K-Err from de-normalised features [T, D] of the generated
/// motion and of the keyframes: joint 0 by its height, the others by their RIC positions.
pub fn k_err_local(
    skel: &Skeleton,
    gen: &[f32],
    kf: &[f32],
    frames: &[usize],
    joints: &[usize],
) -> Option<f64> {
    let d = skel.feature_dim();
    let ric = Layout::of(skel).ric().start;
    let mut sum = 0.0;
    let mut n = 0usize;
    for &f in frames.iter().filter(|&&f| (f + 1) * d <= gen.len() && (f + 1) * d <= kf.len()) {
        for &j in joints {
            let e = if j == 0 {
                (gen[f * d + 3] - kf[f * d + 3]).abs() as f64
            } else {
                let o = f * d + ric + 3 * (j - 1);
                (0..3).map(|k| ((gen[o + k] - kf[o + k]) as f64).powi(2)).sum::<f64>().sqrt()
            };
            sum += e;
            n += 1;
        }
    }
    (n > 0).then(|| sum / n as f64)
}

/// Displacement error of one sample (ADE takes its minimum over samples): mean L2 joint error
/// against the ground truth over all joints of every frame that is not a keyframe.
pub fn displacement_error(gen: &Joints, reference: &Joints, keys: &[usize]) -> Option<f64> {
    let frames: Vec<usize> =
        (0..gen.len().min(reference.len())).filter(|f| !keys.contains(f)).collect();
    let joints: Vec<usize> = (0..gen.first().map_or(0, |p| p.len())).collect();
    k_err_global(gen, reference, &frames, &joints)
}

/// K-TranS with window `l` (2 in the paper's setting).
pub fn k_trans(j: &Joints, frames: &[usize], l: usize) -> Option<f64> {
    let t = j.len();
    let mut per_key = Vec::new();
    for &k in frames {
        let (lo, hi) = (k.saturating_sub(l).max(1), (k + l).min(t.saturating_sub(2)));
        let mut sum = 0.0;
        let mut n = 0usize;
        for f in lo..=hi {
            if f == 0 || f + 1 >= t {
                continue;
            }
            for ((next, here), prev) in j[f + 1].iter().zip(&j[f]).zip(&j[f - 1]) {
                let a = quat::add(quat::sub(*next, quat::scale(*here, 2.0)), *prev);
                sum += quat::norm(a);
                n += 1;
            }
        }
        if n > 0 {
            per_key.push(sum / n as f64);
        }
    }
    (!per_key.is_empty()).then(|| per_key.iter().sum::<f64>() / per_key.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(t: usize, accel: f64) -> Joints {
        (0..t).map(|f| vec![[0.5 * accel * (f * f) as f64, 1.0, 0.0]; 3]).collect()
    }

    #[test]
    fn hand_made_answers() {
        // Constant acceleration a per frame^2: |x[f+1] - 2x[f] + x[f-1]| = a everywhere.
        assert!((k_trans(&line(20, 0.01), &[5, 10], 2).unwrap() - 0.01).abs() < 1e-12);
        // Uniform motion has no acceleration.
        let uniform: Joints = (0..10).map(|f| vec![[f as f64 * 0.1, 0.0, 0.0]; 2]).collect();
        assert!(k_trans(&uniform, &[4], 2).unwrap() < 1e-12);
        // A 3-4-5 offset at one keyframe, exact elsewhere.
        let a = line(10, 0.0);
        let mut b = a.clone();
        b[4][1] = [3.0, 5.0, 0.0];
        assert!((k_err_global(&b, &a, &[4], &[1]).unwrap() - 5.0).abs() < 1e-12);
        assert!((k_err_global(&b, &a, &[4], &[0, 1]).unwrap() - 2.5).abs() < 1e-12);
        assert!(k_err_global(&a, &a, &[], &[0]).is_none());
        // Displacement skips keyframes: a 1 m shift on frames 0..5 of 10, keyframes 0 and 1.
        let mut c = a.clone();
        c.iter_mut().take(5).for_each(|p| p.iter_mut().for_each(|j| j[0] += 1.0));
        assert!((displacement_error(&c, &a, &[0, 1]).unwrap() - 3.0 / 8.0).abs() < 1e-12);
        assert!(displacement_error(&c, &a, &(0..10).collect::<Vec<_>>()).is_none());
    }
}

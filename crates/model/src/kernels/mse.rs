//! The training loss's masked squared errors on host slices, forward and backward, parallel over
//! blocks of frames: L_simple (elements no keyframe observes) and the keyframe term (the observed
//! ones) in one pass over the batch, where the composed Burn ops make a dozen single-threaded
//! passes over [B, N, D] tensors and as many again backward.

use rayon::prelude::*;

use super::host::par_built;

/// Frames per parallel work item (fixed, so that sums are added in the same order for any
/// thread count).
const FRAMES: usize = 64;

/// Sums of one block: [simple error, simple count, key error, key count].
fn block_sums(pred: &[f32], x0: &[f32], m: &[f32], valid: &[f32], d: usize) -> [f64; 4] {
    let mut s = [0f64; 4];
    for (f, &v) in valid.iter().enumerate() {
        if v == 0.0 {
            continue;
        }
        let row = f * d..(f + 1) * d;
        let (mut es, mut cs, mut ek, mut ck) = (0f32, 0f32, 0f32, 0f32);
        for ((&p, &x), &o) in pred[row.clone()].iter().zip(&x0[row.clone()]).zip(&m[row]) {
            let e = (p - x) * (p - x);
            es += e * (1.0 - o);
            cs += 1.0 - o;
            ek += e * o;
            ck += o;
        }
        for (acc, part) in s.iter_mut().zip([es, cs, ek, ck]) {
            *acc += (part * v) as f64;
        }
    }
    s
}

/// The two means and their counts: ([simple, key], [simple count, key count]) of pred against
/// x0 ([rows, d] each) under the keyframe mask `m` ([rows, d], 1 = observed) and `valid`
/// ([rows], 1 = real frame); a mean over no element is 0 (its count is taken as at least 1).
pub fn masked_mse(
    pred: &[f32],
    x0: &[f32],
    m: &[f32],
    valid: &[f32],
    d: usize,
) -> ([f32; 2], [f32; 2]) {
    let parts: Vec<[f64; 4]> = valid
        .par_chunks(FRAMES)
        .enumerate()
        .map(|(i, v)| {
            let at = i * FRAMES * d..(i * FRAMES + v.len()) * d;
            block_sums(&pred[at.clone()], &x0[at.clone()], &m[at], v, d)
        })
        .collect();
    let mut s = [0f64; 4];
    for p in &parts {
        s.iter_mut().zip(p).for_each(|(a, b)| *a += b);
    }
    let counts = [s[1].max(1.0) as f32, s[3].max(1.0) as f32];
    ([(s[0] / counts[0] as f64) as f32, (s[2] / counts[1] as f64) as f32], counts)
}

/// d pred of g[0] * simple + g[1] * key (from [`masked_mse`] with its `counts`); d x0 is its
/// negative.
pub fn masked_mse_backward(
    pred: &[f32],
    x0: &[f32],
    m: &[f32],
    valid: &[f32],
    d: usize,
    g: [f32; 2],
    counts: [f32; 2],
) -> Vec<f32> {
    let (ws, wk) = (2.0 * g[0] / counts[0], 2.0 * g[1] / counts[1]);
    let (dp, _) = par_built(pred.len(), d * FRAMES, |i, out| {
        for (f, row) in out.chunks_exact_mut(d).enumerate() {
            let r = i * FRAMES + f;
            let v = valid[r];
            if v == 0.0 {
                continue;
            }
            let at = r * d..(r + 1) * d;
            for (((o, &p), &x), &mo) in
                row.iter_mut().zip(&pred[at.clone()]).zip(&x0[at.clone()]).zip(&m[at])
            {
                *o = (p - x) * v * (ws * (1.0 - mo) + wk * mo);
            }
        }
    });
    dp
}

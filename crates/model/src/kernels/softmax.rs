//! Masked row softmax for the attention kernel, written to vectorise: masks as additive scores,
//! reductions over 16 lanes, and a polynomial exp (relative error < 1e-7) in place of libm's
//! scalar expf (together they were a sixth of the sampling call's kernel-thread time).
//! Compiled twice, for the baseline target and for AVX2 + FMA, chosen at run time.

use rayon::prelude::*;

use super::attention_call::{AttnShape, Mask};
use super::simd::{self, exp_neg};

/// The mask as scores to add: 0 where the key may be seen, -inf where it may not, one row per
/// query (Full) or per sample (Keys), or none. An addition vectorises into plain stores (a
/// select that keeps the open scores compiles to masked stores, slow on AMD cores), and as
/// `exp_neg` gives exactly 0 at -inf the blocked probabilities need no second pass.
pub struct Open {
    bias: Vec<f32>,
    per_query: bool,
}

impl Open {
    pub fn new(mask: &Mask) -> Open {
        let f = |m: &[bool]| {
            m.par_iter()
                .with_min_len(1 << 14)
                .map(|&b| if b { f32::NEG_INFINITY } else { 0.0 })
                .collect()
        };
        match mask {
            Mask::None => Open { bias: Vec::new(), per_query: false },
            Mask::Keys(m) => Open { bias: f(m), per_query: false },
            Mask::Full(m) => Open { bias: f(m), per_query: true },
        }
    }

    /// The bias row of query i of sample b (empty: no mask).
    pub fn row(&self, s: &AttnShape, b: usize, i: usize) -> &[f32] {
        if self.bias.is_empty() {
            return &[];
        }
        let r = if self.per_query { b * s.lq + i } else { b };
        &self.bias[r * s.lk..(r + 1) * s.lk]
    }
}

const LANES: usize = 16;

/// softmax over the open entries of `row` in place (blocked ones 0; all blocked: all 0) under
/// the mask's `bias` row (empty: none); returns the row's log-sum-exp over its open entries (all
/// blocked: -inf). Whole 16-wide chunks go lane by lane (the compiler keeps them in vector
/// registers), the tail one by one.
#[inline(always)]
pub(super) fn row_softmax(row: &mut [f32], bias: &[f32]) -> f32 {
    let n = row.len();
    let whole = n / LANES * LANES;
    if !bias.is_empty() {
        for (x, &o) in row.iter_mut().zip(&bias[..n]) {
            *x += o;
        }
    }
    let mut lanes = [f32::NEG_INFINITY; LANES];
    for c in row[..whole].chunks_exact(LANES) {
        for l in 0..LANES {
            lanes[l] = if c[l] > lanes[l] { c[l] } else { lanes[l] };
        }
    }
    let mut max = lanes.iter().fold(f32::NEG_INFINITY, |a, &b| if b > a { b } else { a });
    for &x in &row[whole..] {
        max = if x > max { x } else { max };
    }
    if max == f32::NEG_INFINITY {
        row.fill(0.0);
        return f32::NEG_INFINITY;
    }
    let mut sums = [0f32; LANES];
    for c in row[..whole].chunks_exact_mut(LANES) {
        for l in 0..LANES {
            c[l] = exp_neg(c[l] - max);
            sums[l] += c[l];
        }
    }
    let mut sum: f32 = 0.0;
    for x in &mut row[whole..] {
        *x = exp_neg(*x - max);
        sum += *x;
    }
    let total = sums.iter().sum::<f32>() + sum;
    let inv = 1.0 / total;
    row.iter_mut().for_each(|x| *x *= inv);
    max + total.ln()
}

/// The softmax of `row` from its log-sum-exp `lse` (what `row_softmax` returned for these
/// scores and this `bias`): exp(score - lse) on open entries, 0 on blocked ones and on fully
/// blocked rows.
#[inline(always)]
pub(super) fn row_exp(row: &mut [f32], bias: &[f32], lse: f32) {
    if lse == f32::NEG_INFINITY {
        row.fill(0.0);
        return;
    }
    // Scores never exceed lse; the min keeps rounding from pushing an argument above 0.
    if bias.is_empty() {
        row.iter_mut().for_each(|x| *x = exp_neg((*x - lse).min(0.0)));
    } else {
        row.iter_mut().zip(bias).for_each(|(x, &o)| *x = exp_neg((*x + o - lse).min(0.0)));
    }
}

#[inline(always)]
fn rows_generic(p: &mut [f32], s: &AttnShape, open: &Open, b: usize) {
    for (i, row) in p.chunks_mut(s.lk).enumerate() {
        let _ = row_softmax(row, open.row(s, b, i));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn rows_avx2(p: &mut [f32], s: &AttnShape, open: &Open, b: usize) {
    rows_generic(p, s, open, b)
}

/// Softmax of every row of p [Lq, Lk] (sample b's scores of one head) under `open`.
pub fn rows(p: &mut [f32], s: &AttnShape, open: &Open, b: usize) {
    #[cfg(target_arch = "x86_64")]
    if simd::avx2() {
        // SAFETY: the CPU has the features the function was compiled for.
        return unsafe { rows_avx2(p, s, open, b) };
    }
    rows_generic(p, s, open, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn softmax_rows_match_the_definition() {
        let s = AttnShape { batch: 1, lq: 3, lk: 37, heads: 1, d: 8 };
        let scores: Vec<f32> = (0..3 * 37).map(|i| ((i * 7919) % 101) as f32 / 9.0 - 5.0).collect();
        let blocked: Vec<bool> = (0..3 * 37)
            .map(|i| i % 37 > 30 || (i % 5 == 2 && i % 37 != 0) || i / 37 == 2)
            .collect();
        let open = Open::new(&Mask::Full(std::sync::Arc::new(blocked.clone())));
        let mut p = scores.clone();
        rows(&mut p, &s, &open, 0);
        for i in 0..3 {
            let r = &scores[i * 37..(i + 1) * 37];
            let m = r
                .iter()
                .enumerate()
                .filter(|(j, _)| !blocked[i * 37 + j])
                .map(|(_, &x)| x)
                .fold(f32::NEG_INFINITY, f32::max);
            let z: f64 = r
                .iter()
                .enumerate()
                .filter(|(j, _)| !blocked[i * 37 + j])
                .map(|(_, &x)| ((x - m) as f64).exp())
                .sum();
            for j in 0..37 {
                let want = if blocked[i * 37 + j] || m == f32::NEG_INFINITY {
                    0.0
                } else {
                    ((r[j] - m) as f64).exp() / z
                };
                assert!(
                    (p[i * 37 + j] as f64 - want).abs() < 1e-7,
                    "row {i} key {j}: {} vs {want}",
                    p[i * 37 + j]
                );
            }
        }
    }
}

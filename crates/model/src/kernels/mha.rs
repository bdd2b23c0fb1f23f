//! The fused multi-head attention kernel on host slices, forward and backward, parallel over
//! (sample, head) with rayon: the [B, H, Lq, Lk] scores never become tensors (the backward
//! recomputes them). Where a mask leaves most of a sample's keys unseen by every query (the
//! early, small-window DMA blocks see only the few keyframe tokens valid so far), the kernel
//! gathers the keys that some query may see and runs on those alone: the same softmax over the
//! same open entries, on a fraction of the products.

use std::sync::Arc;

use rayon::prelude::*;

use super::attention_call::{AttnShape, Mask};
use super::host::{matmul, matmul_scaled, transposed, Out, View};
use super::softmax::{self, Open};

/// The keys of one sample that some query may see, and the mask restricted to them.
pub(super) struct Compact {
    pub(super) cols: Vec<usize>,
    /// [Lq, cols] per query (Full masks) or nothing blocked (Keys masks).
    open: Open,
}

/// Per sample: its seen keys where gathering them is worth it (`worth_gathering`), else None
/// (the kernel runs on every key). Samples in parallel, each mask scanned row by row.
pub(super) fn compact(mask: &Mask, s: &AttnShape) -> Vec<Option<Compact>> {
    let (lq, lk) = (s.lq, s.lk);
    let worth = |cols: &[usize]| super::worth_gathering(cols.len(), lk);
    (0..s.batch)
        .into_par_iter()
        .map(|b| match mask {
            Mask::None => None,
            Mask::Keys(m) => {
                let cols: Vec<usize> = (0..lk).filter(|&j| !m[b * lk + j]).collect();
                worth(&cols).then(|| Compact { cols, open: Open::new(&Mask::None) })
            }
            Mask::Full(m) => {
                let m = &m[b * lq * lk..(b + 1) * lq * lk];
                let mut seen = vec![false; lk];
                for row in m.chunks_exact(lk) {
                    seen.iter_mut().zip(row).for_each(|(s, &blocked)| *s |= !blocked);
                }
                let cols: Vec<usize> = (0..lk).filter(|&j| seen[j]).collect();
                worth(&cols).then(|| {
                    let sub = m.chunks_exact(lk).flat_map(|row| cols.iter().map(|&j| row[j]));
                    let open = Open::new(&Mask::Full(Arc::new(sub.collect())));
                    Compact { cols, open }
                })
            }
        })
        .collect()
}

/// Keys and values of head (b, h) as the core sees them: the sample's own rows, or the
/// compacted ones gathered into `buf` ([Lc, dh] each, row-major).
pub(super) struct HeadKeys<'a> {
    pub(super) k: View,
    pub(super) v: View,
    pub(super) lk: usize,
    pub(super) open: &'a Open,
    /// The row of `open` that belongs to this sample.
    pub(super) sample: usize,
}

impl<'a> HeadKeys<'a> {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        k: &[f32],
        v: &[f32],
        s: &AttnShape,
        open: &'a Open,
        compact: &'a Option<Compact>,
        b: usize,
        h: usize,
        buf: &'a mut (Vec<f32>, Vec<f32>),
    ) -> HeadKeys<'a> {
        let Some(c) = compact else {
            let (k, v) = (s.head(k, s.lk, b, h), s.head(v, s.lk, b, h));
            return HeadKeys { k, v, lk: s.lk, open, sample: b };
        };
        let dh = s.dh();
        buf.0.clear();
        buf.1.clear();
        for &j in &c.cols {
            let at = (b * s.lk + j) * s.d + h * dh;
            buf.0.extend_from_slice(&k[at..at + dh]);
            buf.1.extend_from_slice(&v[at..at + dh]);
        }
        let view = |x: &Vec<f32>| View { ptr: x.as_ptr(), rs: dh as isize, cs: 1 };
        HeadKeys { k: view(&buf.0), v: view(&buf.1), lk: c.cols.len(), open: &c.open, sample: 0 }
    }

    /// softmax(Q K^T * scale, masked) of the head's queries `q` into `p` [Lq, lk]; fully blocked
    /// rows are 0.
    fn probabilities(&self, q: View, s: &AttnShape, p: &mut [f32]) {
        let (lq, lk, dh) = (s.lq, self.lk, s.dh());
        let kt = View { ptr: self.k.ptr, rs: self.k.cs, cs: self.k.rs };
        // SAFETY: q is [lq, dh], k [lk, dh]; p holds lq * lk.
        unsafe { matmul_scaled(lq, lk, dh, p.as_mut_ptr(), lk, q, kt, s.scale()) };
        softmax::rows(&mut p[..lq * lk], &AttnShape { lk, ..*s }, self.open, self.sample);
    }
}

/// softmax(Q K^T / sqrt(dh) + mask) V per head -> [B, Lq, d].
pub fn attention_forward(q: &[f32], k: &[f32], v: &[f32], s: &AttnShape, mask: &Mask) -> Vec<f32> {
    let (lq, lk, dh) = (s.lq, s.lk, s.dh());
    let open = Open::new(mask);
    let compact = compact(mask, s);
    // Not zeroed: the heads together write every element (set_len below).
    let mut out: Vec<f32> = Vec::with_capacity(s.batch * lq * s.d);
    let dst = Out(out.as_mut_ptr());
    (0..s.batch * s.heads).into_par_iter().for_each_init(
        || (vec![0f32; lq * lk], (Vec::new(), Vec::new())),
        |(p, buf), bh| {
            let (b, h) = (bh / s.heads, bh % s.heads);
            let keys = HeadKeys::new(k, v, s, &open, &compact[b], b, h, buf);
            let d = dst;
            // SAFETY: head (b, h) writes only its own dh columns of sample b's rows.
            let at = unsafe { d.0.add(b * lq * s.d + h * dh) };
            if keys.lk == 0 {
                // No query sees any key: every row is blocked, so 0 (as the softmax gives).
                (0..lq).for_each(|i| unsafe { std::ptr::write_bytes(at.add(i * s.d), 0, dh) });
                return;
            }
            keys.probabilities(s.head(q, lq, b, h), s, p);
            let pv = View { ptr: p.as_ptr(), rs: keys.lk as isize, cs: 1 };
            // SAFETY: p is [lq, lk'], the values [lk', dh]; the destination as above.
            unsafe { matmul(lq, dh, keys.lk, at, s.d, pv, keys.v) };
        },
    );
    // SAFETY: every (b, h) wrote its [lq, dh] block; the blocks tile [B, Lq, d].
    unsafe { out.set_len(s.batch * lq * s.d) };
    out
}

/// dS = P o (dP - rowsum(P o dP)) times the score scale, in place of dP (rows of `n` keys).
fn softmax_backward(p: &[f32], dp: &mut [f32], n: usize, scale: f32) {
    for (pr, gr) in p.chunks(n).zip(dp.chunks_mut(n)) {
        let dot: f32 = pr.iter().zip(gr.iter()).map(|(a, b)| a * b).sum();
        gr.iter_mut().zip(pr).for_each(|(g, &pv)| *g = pv * (*g - dot) * scale);
    }
}

/// A compacted head's dK and dV (`grads`: [2, n, dh]) written to the rows of its keys `cols`
/// in [B, Lk, d] buffers, from element `base` (sample b's first row, head h's first column).
///
/// # Safety
/// `base + cols[r] * d + dh` must lie inside both buffers, and no other thread may write those
/// elements meanwhile.
unsafe fn scatter_keys(
    grads: &[f32],
    cols: &[usize],
    (dk, dv): (Out, Out),
    base: usize,
    d: usize,
    dh: usize,
) {
    let n = cols.len();
    for (r, &j) in cols.iter().enumerate() {
        let at = base + j * d;
        std::ptr::copy_nonoverlapping(grads[r * dh..].as_ptr(), dk.0.add(at), dh);
        std::ptr::copy_nonoverlapping(grads[(n + r) * dh..].as_ptr(), dv.0.add(at), dh);
    }
}

/// Where one head's dK and dV rows go, and their row stride: straight into the [B, Lk, d]
/// buffers at offset `at`, or, for a compacted head, into the scratch `grads` [2, n, dh]
/// (scattered to their rows afterwards).
///
/// # Safety
/// `at` is the head's first key row and column in buffers of [B, Lk, d].
unsafe fn key_grad_rows(
    compacted: bool,
    grads: &mut Vec<f32>,
    (dkp, dvp): (Out, Out),
    at: usize,
    n: usize,
    s: &AttnShape,
) -> (*mut f32, *mut f32, usize) {
    let dh = s.dh();
    if !compacted {
        return (dkp.0.add(at), dvp.0.add(at), s.d);
    }
    grads.resize(2 * n * dh, 0.0);
    let g = grads.as_mut_ptr();
    (g, g.add(n * dh), dh)
}

/// Gradients (dQ, dK, dV) of [`attention_forward`] for the output gradient `dout` [B, Lq, d];
/// the probabilities are recomputed (cheaper than keeping [B, H, Lq, Lk] per layer).
pub fn attention_backward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    dout: &[f32],
    s: &AttnShape,
    mask: &Mask,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (lq, lk, dh) = (s.lq, s.lk, s.dh());
    // dQ is written whole by the heads; dK and dV start at 0, as keys that no query sees get
    // no gradient and compacted heads write only the keys they saw.
    let mut dq: Vec<f32> = Vec::with_capacity(s.batch * lq * s.d);
    let (mut dk, mut dv) = (vec![0f32; s.batch * lk * s.d], vec![0f32; s.batch * lk * s.d]);
    let (dqp, dkp, dvp) = (Out(dq.as_mut_ptr()), Out(dk.as_mut_ptr()), Out(dv.as_mut_ptr()));
    let open = Open::new(mask);
    let compact = compact(mask, s);
    let scale = s.scale();
    (0..s.batch * s.heads).into_par_iter().for_each_init(
        || (vec![0f32; lq * lk], vec![0f32; lq * lk], (Vec::new(), Vec::new()), vec![0f32; 0]),
        |(p, dp, buf, grads), bh| {
            let (b, h) = (bh / s.heads, bh % s.heads);
            let (dqp, dkp, dvp) = (dqp, dkp, dvp);
            let col = h * dh;
            let keys = HeadKeys::new(k, v, s, &open, &compact[b], b, h, buf);
            let n = keys.lk;
            // SAFETY (all blocks below): the buffers hold [B, L, d] or [Lq, Lk]; head (b, h)
            // writes only its own dh columns of sample b's rows in dq, dk and dv.
            let dq_at = unsafe { dqp.0.add(b * lq * s.d + col) };
            if n == 0 {
                return (0..lq).for_each(|i| unsafe { dq_at.add(i * s.d).write_bytes(0, dh) });
            }
            let (qh, go) = (s.head(q, lq, b, h), s.head(dout, lq, b, h));
            keys.probabilities(qh, s, p);
            let (p, dp) = (&mut p[..lq * n], &mut dp[..lq * n]);
            // dK and dV of the compacted keys go to a scratch [2, n, dh] first, then to their rows.
            let compacted = compact[b].as_ref();
            let at = b * lk * s.d + col;
            let (dk_at, dv_at, rs) =
                unsafe { key_grad_rows(compacted.is_some(), grads, (dkp, dvp), at, n, s) };
            let (pt, vt) =
                (transposed(p, n), View { ptr: keys.v.ptr, rs: keys.v.cs, cs: keys.v.rs });
            // dV = P^T dO; dP = dO V^T; dS from dP; dQ = dS K; dK = dS^T Q.
            unsafe { matmul(n, dh, lq, dv_at, rs, pt, go) };
            unsafe { matmul(lq, n, dh, dp.as_mut_ptr(), n, go, vt) };
            softmax_backward(p, dp, n, scale);
            let ds = View { ptr: dp.as_ptr(), rs: n as isize, cs: 1 };
            unsafe { matmul(lq, dh, n, dq_at, s.d, ds, keys.k) };
            unsafe { matmul(n, dh, lq, dk_at, rs, transposed(dp, n), qh) };
            if let Some(c) = compacted {
                // SAFETY: the rows of sample b, columns of head h, as above.
                unsafe { scatter_keys(grads, &c.cols, (dkp, dvp), at, s.d, dh) };
            }
        },
    );
    // SAFETY: the [Lq, dh] blocks of all (b, h) tile dQ.
    unsafe { dq.set_len(s.batch * lq * s.d) };
    (dq, dk, dv)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample whose every key is blocked (which the models never make) gives zeros, forward and
    /// backward, beside a sample computed on its seen keys.
    #[test]
    fn fully_blocked_sample_is_zero() {
        let s = AttnShape { batch: 2, lq: 3, lk: 8, heads: 2, d: 4 };
        let x = |n: usize, k: usize| (0..n).map(|i| ((i * k) % 17) as f32 / 8.0 - 1.0).collect();
        let (q, k, v, g): (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) =
            (x(24, 5), x(64, 7), x(64, 3), x(24, 11));
        let keys: Vec<bool> = (0..16).map(|i| i < 8 || i % 3 != 0).collect();
        let mask = Mask::Keys(Arc::new(keys));
        let out = attention_forward(&q, &k, &v, &s, &mask);
        let (dq, dk, dv) = attention_backward(&q, &k, &v, &g, &s, &mask);
        assert!(out[..12]
            .iter()
            .chain(&dq[..12])
            .chain(&dk[..32])
            .chain(&dv[..32])
            .all(|&x| x == 0.0));
        // Sample 1 sees keys 1, 4 and 7 only: its output mixes their values, its dK/dV elsewhere 0.
        assert!(
            out[12..].iter().any(|&x| x != 0.0) && dv[32 + 4..32 + 2 * 4].iter().any(|&x| x != 0.0)
        );
        for j in [0, 2, 3, 5, 6] {
            assert!(dk[32 + j * 4..32 + (j + 1) * 4].iter().all(|&x| x == 0.0));
        }
    }
}

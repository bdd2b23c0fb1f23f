//! Attention for small heads (dh <= 32: the tiny and mid networks' 16 and 32), flash-style: one
//! pass per block of `R` query rows computes their scores against every key, the masked softmax
//! and the product with the values, the block's [R, Lk] scores staying in L1. (The per-head path
//! of `mha.rs` writes a head's whole [Lq, Lk] scores out and reads them back three times, and its
//! `gemm` calls pack operands whose inner dimension is only 16.) The forward keeps each row's
//! log-sum-exp; the backward recomputes a block's probabilities from it in one pass (no max, no
//! sum) and accumulates dK and dV over the blocks. Products run on register tiles (`tiles.rs`) of
//! `R` rows by `W` keys (scores) or by the head width (values), padded to `P` = 16 or 32
//! channels: AVX2 + FMA intrinsics where the CPU has them (chosen at run time), else plain loops.

use rayon::prelude::*;

use super::attention_call::{AttnShape, Mask};
use super::host::Out;
use super::mha::{compact, Compact, HeadKeys};
use super::simd::{avx2, avx512};
use super::softmax::{self, Open};

#[cfg(target_arch = "x86_64")]
use super::tiles::{Avx2, Avx512};
use super::tiles::{Lanes, Scalar, W};

/// Whether this kernel serves heads of `dh` channels.
pub fn serves(dh: usize) -> bool {
    dh <= 32
}

/// One head's operands laid out for the blocks: rows of `P` channels (zero beyond dh), key
/// columns padded to `n16`, query rows to a multiple of `R`.
struct HeadLayout {
    p: usize,
    n: usize,
    n16: usize,
    lq: usize,
}

impl HeadLayout {
    fn new(s: &AttnShape, n: usize, p: usize, r: usize) -> HeadLayout {
        HeadLayout { p, n, n16: n.div_ceil(W) * W, lq: s.lq.div_ceil(r) * r }
    }

    /// Rows `rows` of a head view ([rows, dh], stride `rs`) as [len, P] rows.
    fn rows(
        &self,
        src: *const f32,
        rs: usize,
        rows: usize,
        len: usize,
        dh: usize,
        buf: &mut Vec<f32>,
    ) {
        buf.clear();
        buf.resize(len * self.p, 0.0);
        for i in 0..rows {
            // SAFETY: the view has `rows` rows of `dh` channels at stride `rs`.
            let row = unsafe { std::slice::from_raw_parts(src.add(i * rs), dh) };
            copy_row(row, &mut buf[i * self.p..i * self.p + dh]);
        }
    }

    /// The same rows transposed: [P, n16].
    fn columns(&self, src: *const f32, rs: usize, dh: usize, buf: &mut Vec<f32>) {
        buf.clear();
        buf.resize(self.p * self.n16, 0.0);
        for j in 0..self.n {
            for d in 0..dh {
                // SAFETY: as in `rows`, for the head's n key rows.
                buf[d * self.n16 + j] = unsafe { *src.add(j * rs + d) };
            }
        }
    }
}

/// The rows' log-sum-exp: written by the forward, read by the backward.
enum Lse<'a> {
    Write(&'a mut [f32]),
    Read(&'a [f32]),
}

/// A block's scores to probabilities in place: the forward's softmax (each row's log-sum-exp
/// written), or the backward's exp(score - lse) from it; padding rows and columns become 0. (No
/// closure: a closure's body would be compiled without the caller's target features.)
#[inline(always)]
fn probabilities(
    sc: &mut [f32],
    g: &HeadLayout,
    keys: &HeadKeys,
    s: &AttnShape,
    i0: usize,
    lse: &mut Lse,
) {
    let shape = AttnShape { lk: g.n, ..*s };
    for (r, row) in sc.chunks_mut(g.n16).enumerate() {
        let i = i0 + r;
        if i >= s.lq {
            row.fill(0.0);
            continue;
        }
        let open = keys.open.row(&shape, keys.sample, i);
        match lse {
            Lse::Write(l) => l[i] = softmax::row_softmax(&mut row[..g.n], open),
            Lse::Read(l) => softmax::row_exp(&mut row[..g.n], open, l[i]),
        }
        row[g.n..].fill(0.0);
    }
}

/// d[j] = p[j] (d[j] - p . d) * scale for each row of a block (p and d [R, n16]): the softmax's
/// backward, dS from dP. The dot product in W lanes, so that it vectorises.
#[inline(always)]
fn softmax_grad(p: &[f32], d: &mut [f32], n16: usize, scale: f32) {
    for (pr, dr) in p.chunks_exact(n16).zip(d.chunks_exact_mut(n16)) {
        let mut lanes = [0f32; W];
        for (pc, dc) in pr.chunks_exact(W).zip(dr.chunks_exact(W)) {
            for l in 0..W {
                lanes[l] += pc[l] * dc[l];
            }
        }
        let dot: f32 = lanes.iter().sum();
        for (x, &pv) in dr.iter_mut().zip(pr) {
            *x = pv * (*x - dot) * scale;
        }
    }
}

/// `src` to `dst` (equal lengths). A head row of 16 or 32 channels goes as a fixed-size copy, a
/// few vector moves inline: copies of a length known only at run time are calls to memmove,
/// tens of thousands per sampling call.
#[inline(always)]
fn copy_row(src: &[f32], dst: &mut [f32]) {
    match (src.len(), dst.len()) {
        (16, 16) => dst.copy_from_slice(&src[..16]),
        (32, 32) => dst.copy_from_slice(&src[..32]),
        _ => dst.copy_from_slice(src),
    }
}

/// The first `rows` rows of a block's result `out` ([R, P]) to `dst` (row stride `stride`), dh
/// channels each.
#[inline(always)]
fn write_rows(out: &[f32], p: usize, rows: usize, dh: usize, dst: *mut f32, stride: usize) {
    for r in 0..rows {
        // SAFETY: the caller's destination has `rows` rows of dh channels at `stride`.
        let to = unsafe { std::slice::from_raw_parts_mut(dst.add(r * stride), dh) };
        copy_row(&out[r * p..r * p + dh], to);
    }
}

/// Scratch of one worker: the head's operands and one block's rows.
#[derive(Default)]
struct Scratch {
    q: Vec<f32>,
    kt: Vec<f32>,
    v: Vec<f32>,
    sc: Vec<f32>,
    out: Vec<f32>,
    gather: (Vec<f32>, Vec<f32>),
    // Backward only.
    g: Vec<f32>,
    vt: Vec<f32>,
    k: Vec<f32>,
    dp: Vec<f32>,
    dk: Vec<f32>,
    dv: Vec<f32>,
}

/// What every head of one call shares: the inputs, the shape and the mask.
struct Call<'a> {
    q: &'a [f32],
    k: &'a [f32],
    v: &'a [f32],
    s: &'a AttnShape,
    open: Open,
    comp: Vec<Option<Compact>>,
}

impl<'a> Call<'a> {
    fn new((q, k, v): Qkv<'a>, s: &'a AttnShape, mask: &Mask) -> Call<'a> {
        Call { q, k, v, s, open: Open::new(mask), comp: compact(mask, s) }
    }

    fn keys<'b>(
        &'b self,
        (b, h): (usize, usize),
        buf: &'b mut (Vec<f32>, Vec<f32>),
    ) -> HeadKeys<'b> {
        HeadKeys::new(self.k, self.v, self.s, &self.open, &self.comp[b], b, h, buf)
    }
}

/// Forward of head (b, h) into `dst` (its [Lq, dh] block of the output, row stride d) and its
/// rows' log-sum-exp into `lse` ([Lq]).
#[inline(always)]
fn head_forward<const P: usize, L: Lanes>(
    c: &Call,
    (b, h): (usize, usize),
    dst: *mut f32,
    lse: &mut [f32],
    w: &mut Scratch,
) {
    let (s, dh) = (c.s, c.s.dh());
    let keys = c.keys((b, h), &mut w.gather);
    let g = HeadLayout::new(s, keys.lk, P, L::R);
    g.rows(s.head(c.q, s.lq, b, h).ptr, s.d, s.lq, g.lq, dh, &mut w.q);
    g.columns(keys.k.ptr, keys.k.rs as usize, dh, &mut w.kt);
    g.rows(keys.v.ptr, keys.v.rs as usize, g.n, g.n, dh, &mut w.v);
    w.sc.resize(L::R * g.n16, 0.0);
    w.out.resize(L::R * P, 0.0);
    for i0 in (0..g.lq).step_by(L::R) {
        L::dots::<P>(&w.q[i0 * P..], &w.kt, g.n16, s.scale(), &mut w.sc);
        probabilities(&mut w.sc, &g, &keys, s, i0, &mut Lse::Write(lse));
        L::mix::<P>(&w.sc, g.n16, g.n, &w.v, &mut w.out);
        // The head's block of rows i0.. (row stride d).
        write_rows(&w.out, P, L::R.min(s.lq - i0), dh, dst.wrapping_add(i0 * s.d), s.d);
    }
}

/// Backward of head (b, h): dQ into its block of `dq` (row stride d), dK and dV into the rows of
/// the keys it saw in `dk` and `dv` ([Lk, d] blocks of sample b), from the forward's `lse`.
#[inline(always)]
fn head_backward<const P: usize, L: Lanes>(
    c: &Call,
    dout: &[f32],
    (b, h): (usize, usize),
    lse: &[f32],
    (dq, dk, dv): (Out, Out, Out),
    w: &mut Scratch,
) {
    let (s, dh, scale) = (c.s, c.s.dh(), c.s.scale());
    let keys = c.keys((b, h), &mut w.gather);
    let g = HeadLayout::new(s, keys.lk, P, L::R);
    let (n, n16) = (g.n, g.n16);
    g.rows(s.head(c.q, s.lq, b, h).ptr, s.d, s.lq, g.lq, dh, &mut w.q);
    g.rows(s.head(dout, s.lq, b, h).ptr, s.d, s.lq, g.lq, dh, &mut w.g);
    g.columns(keys.k.ptr, keys.k.rs as usize, dh, &mut w.kt);
    g.columns(keys.v.ptr, keys.v.rs as usize, dh, &mut w.vt);
    g.rows(keys.k.ptr, keys.k.rs as usize, n, n, dh, &mut w.k);
    for acc in [&mut w.dk, &mut w.dv] {
        acc.clear();
        acc.resize(n * P, 0.0);
    }
    w.sc.resize(L::R * n16, 0.0);
    w.dp.resize(L::R * n16, 0.0);
    w.out.resize(L::R * P, 0.0);
    let dq_at = unsafe { dq.0.add(b * s.lq * s.d + h * dh) };
    for i0 in (0..g.lq).step_by(L::R) {
        let (qb, gb) = (&w.q[i0 * P..(i0 + L::R) * P], &w.g[i0 * P..(i0 + L::R) * P]);
        L::dots::<P>(qb, &w.kt, n16, scale, &mut w.sc);
        probabilities(&mut w.sc, &g, &keys, s, i0, &mut Lse::Read(lse));
        // dV += P^T dO; dP = dO V^T; dS = P o (dP - rowsum(P o dP)) * scale.
        L::spread::<P>(&w.sc, n16, n, gb, &mut w.dv);
        L::dots::<P>(gb, &w.vt, n16, 1.0, &mut w.dp);
        softmax_grad(&w.sc, &mut w.dp, n16, scale);
        // dQ = dS K; dK += dS^T Q.
        L::mix::<P>(&w.dp, n16, n, &w.k, &mut w.out);
        write_rows(&w.out, P, L::R.min(s.lq - i0), dh, dq_at.wrapping_add(i0 * s.d), s.d);
        L::spread::<P>(&w.dp, n16, n, qb, &mut w.dk);
    }
    for j in 0..n {
        let row = c.comp[b].as_ref().map_or(j, |cp| cp.cols[j]);
        let at = (b * s.lk + row) * s.d + h * dh;
        // SAFETY: key row `row` of sample b, head h's dh channels: only this head writes them.
        unsafe {
            std::ptr::copy_nonoverlapping(w.dk[j * P..].as_ptr(), dk.0.add(at), dh);
            std::ptr::copy_nonoverlapping(w.dv[j * P..].as_ptr(), dv.0.add(at), dh);
        }
    }
}

/// The AVX2 + FMA and AVX-512 builds of a head function (its tiles inline into each with those
/// features; its own loops, the softmax's exp among them, vectorise to the build's width).
macro_rules! compiled_for {
    ($generic:ident, $avx2:ident, $avx512:ident, ($($arg:ident: $ty:ty),*)) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn $avx2<const P: usize>($($arg: $ty),*) {
            $generic::<P, Avx2>($($arg),*)
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx2,fma")]
        fn $avx512<const P: usize>($($arg: $ty),*) {
            $generic::<P, Avx512>($($arg),*)
        }
    };
}

/// Calls the build of a head function for this CPU and head width.
macro_rules! dispatch {
    ($wide:expr, $generic:ident, $avx2:ident, $avx512:ident, ($($a:expr),*)) => {
        match (avx512(), avx2(), $wide) {
            // SAFETY (every arm): the CPU has the features the build was compiled for.
            #[cfg(target_arch = "x86_64")]
            (true, _, false) => unsafe { $avx512::<16>($($a),*) },
            #[cfg(target_arch = "x86_64")]
            (true, _, true) => unsafe { $avx512::<32>($($a),*) },
            #[cfg(target_arch = "x86_64")]
            (_, true, false) => unsafe { $avx2::<16>($($a),*) },
            #[cfg(target_arch = "x86_64")]
            (_, true, true) => unsafe { $avx2::<32>($($a),*) },
            (_, _, false) => $generic::<16, Scalar<4>>($($a),*),
            (_, _, true) => $generic::<32, Scalar<4>>($($a),*),
        }
    };
}

type Qkv<'a> = (&'a [f32], &'a [f32], &'a [f32]);

compiled_for!(head_forward, head_forward_avx2, head_forward_avx512,
    (c: &Call, bh: (usize, usize), dst: *mut f32, lse: &mut [f32], w: &mut Scratch));
compiled_for!(head_backward, head_backward_avx2, head_backward_avx512,
    (c: &Call, dout: &[f32], bh: (usize, usize), lse: &[f32], d: (Out, Out, Out), w: &mut Scratch));

/// softmax(Q K^T / sqrt(dh) + mask) V per head -> ([B, Lq, d], log-sum-exp [B, H, Lq]).
pub fn forward(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    s: &AttnShape,
    mask: &Mask,
) -> (Vec<f32>, Vec<f32>) {
    let c = Call::new((q, k, v), s, mask);
    let mut out: Vec<f32> = vec![0.0; s.batch * s.lq * s.d];
    let mut lse = vec![0f32; s.batch * s.heads * s.lq];
    let dst = Out(out.as_mut_ptr());
    let wide = s.dh() > 16;
    lse.par_chunks_mut(s.lq).enumerate().for_each_init(Scratch::default, |w, (bh, lse)| {
        let (b, h) = (bh / s.heads, bh % s.heads);
        let d = dst;
        // SAFETY: head (b, h) writes only its own dh columns of sample b's rows.
        let at = unsafe { d.0.add(b * s.lq * s.d + h * s.dh()) };
        dispatch!(
            wide,
            head_forward,
            head_forward_avx2,
            head_forward_avx512,
            (&c, (b, h), at, lse, w)
        );
    });
    (out, lse)
}

/// Gradients (dQ, dK, dV) of [`forward`] for the output gradient `dout` [B, Lq, d], from the
/// forward's log-sum-exp.
pub fn backward(
    x: Qkv,
    dout: &[f32],
    lse: &[f32],
    s: &AttnShape,
    mask: &Mask,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let c = Call::new(x, s, mask);
    // dK and dV start at 0: keys that no query sees get no gradient.
    let mut dq = vec![0f32; s.batch * s.lq * s.d];
    let (mut dk, mut dv) = (vec![0f32; s.batch * s.lk * s.d], vec![0f32; s.batch * s.lk * s.d]);
    let outs = (Out(dq.as_mut_ptr()), Out(dk.as_mut_ptr()), Out(dv.as_mut_ptr()));
    let wide = s.dh() > 16;
    lse.par_chunks(s.lq).enumerate().for_each_init(Scratch::default, |w, (bh, lse)| {
        let (b, h) = (bh / s.heads, bh % s.heads);
        dispatch!(
            wide,
            head_backward,
            head_backward_avx2,
            head_backward_avx512,
            (&c, dout, (b, h), lse, outs, w)
        );
    });
    (dq, dk, dv)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::kernels::mha::{attention_backward, attention_forward};

    fn data(n: usize, seed: usize) -> Vec<f32> {
        (0..n).map(|i| ((i * 7919 + seed * 104_729) % 1013) as f32 / 506.0 - 1.0).collect()
    }

    fn worst(a: &[f32], b: &[f32]) -> f32 {
        let scale = b.iter().fold(1e-6f32, |m, x| m.max(x.abs()));
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max) / scale
    }

    /// The flash kernel against the per-head path (itself tested against Burn's composed ops in
    /// tests/kernels.rs): head widths below, at and between the two paddings, query counts off
    /// the block size, key counts off the chunk size, masks with fully blocked rows and with keys
    /// few enough to be gathered.
    #[test]
    fn matches_the_per_head_kernel_forward_and_backward() {
        for (dh, heads, lq, lk) in [(16, 4, 7, 37), (8, 2, 5, 16), (32, 2, 9, 40), (24, 3, 4, 3)] {
            let (b, d) = (2, dh * heads);
            let s = AttnShape { batch: b, lq, lk, heads, d };
            let (q, k, v, g) = (
                data(b * lq * d, 1),
                data(b * lk * d, 2),
                data(b * lk * d, 3),
                data(b * lq * d, 4),
            );
            let keys: Vec<bool> = (0..b * lk).map(|i| i % lk > lk / 2 && i % 3 != 0).collect();
            let full: Vec<bool> =
                (0..b * lq * lk).map(|i| (i / lk) % lq == 1 || (i * 31) % 7 < 3).collect();
            let sparse: Vec<bool> = (0..b * lq * lk).map(|i| i % lk > 2).collect();
            for mask in [
                Mask::None,
                Mask::Keys(Arc::new(keys.clone())),
                Mask::Full(Arc::new(full.clone())),
                Mask::Full(Arc::new(sparse.clone())),
            ] {
                let (out, lse) = forward(&q, &k, &v, &s, &mask);
                let want = attention_forward(&q, &k, &v, &s, &mask);
                let e = worst(&out, &want);
                assert!(e < 1e-5, "dh {dh} lq {lq} lk {lk} {mask:?}: forward {e}");
                let got = backward((&q, &k, &v), &g, &lse, &s, &mask);
                let want = attention_backward(&q, &k, &v, &g, &s, &mask);
                for (name, a, w) in
                    [("dq", got.0, want.0), ("dk", got.1, want.1), ("dv", got.2, want.2)]
                {
                    let e = worst(&a, &w);
                    assert!(e < 1e-5, "dh {dh} lq {lq} lk {lk} {mask:?}: {name} {e}");
                }
            }
        }
    }
}

#[cfg(test)]
mod timing {
    use super::*;
    use crate::kernels::mha::{attention_backward, attention_forward};

    /// `cargo test --release -p diffkfc-model --lib flash::timing -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn per_head_against_flash() {
        for dh in [16, 32] {
            let (b, heads, l) = (32, 4, 197);
            time_shape(AttnShape { batch: b, lq: l, lk: l, heads, d: heads * dh });
        }
        // A sampling call's self-attention: one motion, both guidance branches.
        for dh in [16, 32] {
            let (b, heads, l) = (2, 4, 147);
            time_shape(AttnShape { batch: b, lq: l, lk: l, heads, d: heads * dh });
        }
    }

    fn time_shape(s: AttnShape) {
        let (b, l) = (s.batch, s.lk);
        let x: Vec<f32> =
            (0..b * l * s.d).map(|i| ((i * 7919) % 1013) as f32 / 506.0 - 1.0).collect();
        // Key padding as the decoder's self-attention has it (a shorter motion's last frames).
        let pad: Vec<bool> = (0..b * l).map(|i| i % l > l - 1 - (i / l) % 40).collect();
        let t = |f: &dyn Fn()| {
            let mut v: Vec<f64> = (0..if s.batch < 8 { 101 } else { 7 })
                .map(|_| {
                    let t0 = std::time::Instant::now();
                    f();
                    t0.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        // The products' FLOPs as the step's count has them: 2 in the forward, 4 in the backward.
        let gflop = 4.0 * (b * s.lq * s.lk * s.d) as f64 / 1e9;
        let peak = crate::bench::matmul_peak(1024, 5);
        for mask in [Mask::None, Mask::Keys(std::sync::Arc::new(pad))] {
            let (_, lse) = forward(&x, &x, &x, &s, &mask);
            let name = if matches!(mask, Mask::None) { "no mask" } else { "key padding" };
            let (fw, bw) = (
                t(&|| drop(forward(&x, &x, &x, &s, &mask))),
                t(&|| drop(backward((&x, &x, &x), &x, &lse, &s, &mask))),
            );
            eprintln!(
                "dh {} {name}: forward: per head {:.3} ms, flash {fw:.3} ms ({:.2} of peak {peak:.0}); \
                 backward: per head {:.3} ms, flash {bw:.3} ms ({:.2})",
                s.dh(),
                t(&|| drop(attention_forward(&x, &x, &x, &s, &mask))),
                gflop / fw * 1e3 / peak,
                t(&|| drop(attention_backward(&x, &x, &x, &x, &s, &mask))),
                2.0 * gflop / bw * 1e3 / peak,
            );
        }
    }
}

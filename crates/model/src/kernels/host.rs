//! The fused kernels on host slices: Linear, GELU and LayerNorm, forward and backward, parallel
//! over rows with rayon, and the single-threaded products the attention kernel (`mha.rs`) runs
//! per head. Burn's flex backend runs elementwise ops on one
//! thread and materialises every intermediate ([B, H, L, L] scores, masked scores, exp, sums,
//! ...); these do each in one pass per row, with the small per-head products on `gemm`.

use rayon::prelude::*;

use super::simd::{elementwise_builds, erf, erf_with, exp_neg};

/// A strided read-only matrix: element (r, c) at `ptr + r * rs + c * cs`.
#[derive(Clone, Copy)]
pub(super) struct View {
    pub ptr: *const f32,
    pub rs: isize,
    pub cs: isize,
}

/// A destination pointer shared by tasks that write disjoint elements.
#[derive(Clone, Copy)]
pub(super) struct Out(pub *mut f32);
// SAFETY: every task writes a disjoint set of elements (one head's columns, one row chunk).
unsafe impl Send for Out {}
unsafe impl Sync for Out {}
unsafe impl Send for View {}
unsafe impl Sync for View {}

/// dst[m, n] (row stride `dst_rs`, unit column stride) = lhs[m, k] . rhs[k, n], single-threaded
/// (the callers are already parallel).
///
/// # Safety
/// The views must cover the [m, k] and [k, n] elements they describe and `dst` the [m, n] ones.
pub(super) unsafe fn matmul(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    dst_rs: usize,
    lhs: View,
    rhs: View,
) {
    matmul_scaled(m, n, k, dst, dst_rs, lhs, rhs, 1.0)
}

/// As [`matmul`], times `scale`.
///
/// # Safety
/// As [`matmul`].
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn matmul_scaled(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    dst_rs: usize,
    lhs: View,
    rhs: View,
    scale: f32,
) {
    gemm::gemm(
        m,
        n,
        k,
        dst,
        1,
        dst_rs as isize,
        false,
        lhs.ptr,
        lhs.cs,
        lhs.rs,
        rhs.ptr,
        rhs.cs,
        rhs.rs,
        0.0,
        scale,
        false,
        false,
        false,
        gemm::Parallelism::None,
    );
}

/// A vector of `n` floats that `fill` writes completely through the pointer: no zeroing pass
/// (on one thread, before the parallel work) for buffers a product overwrites anyway.
///
/// # Safety
/// `fill` must write all `n` elements.
unsafe fn overwritten(n: usize, fill: impl FnOnce(*mut f32)) -> Vec<f32> {
    let mut v: Vec<f32> = Vec::with_capacity(n);
    fill(v.as_mut_ptr());
    v.set_len(n);
    v
}

/// A vector of `n` floats that `fill(c, part)` writes on all threads, chunk `c` being elements
/// `c * chunk..` (at most `chunk` of them), with what each call returns, in chunk order. Each
/// worker zeroes its own chunk just before `fill` writes it (in cache), instead of the calling
/// thread zeroing or copying the whole buffer before the parallel work: on two threads that
/// serial pass was most of what the main thread did alone in a training step.
pub fn par_built<R: Send>(
    n: usize,
    chunk: usize,
    fill: impl Fn(usize, &mut [f32]) -> R + Sync,
) -> (Vec<f32>, Vec<R>) {
    let mut v: Vec<f32> = Vec::with_capacity(n);
    let parts: Vec<R> = v.spare_capacity_mut()[..n]
        .par_chunks_mut(chunk.max(1))
        .enumerate()
        .map(|(c, part)| {
            part.fill(std::mem::MaybeUninit::new(0.0));
            // SAFETY: every element of `part` was initialised just above, and MaybeUninit<f32>
            // has the layout of f32.
            let part = unsafe { &mut *(part as *mut [std::mem::MaybeUninit<f32>] as *mut [f32]) };
            fill(c, part)
        })
        .collect();
    // SAFETY: the chunks cover 0..n and each was initialised.
    unsafe { v.set_len(n) };
    (v, parts)
}

/// The part of `x` that chunk `c` of [`par_built`] covers, for an output chunk of `len`.
fn chunk_of(x: &[f32], chunk: usize, c: usize, len: usize) -> &[f32] {
    &x[c * chunk..c * chunk + len]
}

/// Products of at least this many multiply-adds run on all threads (as burn-flex decides).
const PARALLEL_WORK: usize = 192 * 192 * 192;

/// dst[m, n] = lhs[m, k] . rhs[k, n] (+ dst when `acc`), contiguous `dst`, with `par`.
///
/// # Safety
/// As [`matmul`].
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn gemm_to(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    acc: bool,
    lhs: View,
    rhs: View,
    par: gemm::Parallelism,
) {
    gemm::gemm(
        m, n, k, dst, 1, n as isize, acc, lhs.ptr, lhs.cs, lhs.rs, rhs.ptr, rhs.cs, rhs.rs, 1.0,
        1.0, false, false, false, par,
    );
}

/// As [`gemm_to`], on all threads when big.
///
/// # Safety
/// As [`matmul`].
unsafe fn matmul_par(m: usize, n: usize, k: usize, dst: *mut f32, acc: bool, lhs: View, rhs: View) {
    let par = if m * n * k >= PARALLEL_WORK {
        gemm::Parallelism::Rayon(0)
    } else {
        gemm::Parallelism::None
    };
    gemm_to(m, n, k, dst, acc, lhs, rhs, par)
}

/// Layers with at most this many weights are narrow: `gemm` splits a product over blocks of its
/// output, and a narrow layer's products give it too few (its weight gradient [in, out] is a
/// single block: one thread did all of it), so they are split by rows here instead.
const NARROW: usize = 256 * 256;

/// Rows per task of a narrow layer's products (fixed, so that the weight gradient's partial
/// sums are added in the same order for any thread count).
const ROW_BLOCK: usize = 512;

/// As [`matmul_par`], for a narrow layer: blocks of `ROW_BLOCK` rows in parallel, each one
/// single-threaded product.
///
/// # Safety
/// As [`matmul`].
unsafe fn matmul_rows(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    acc: bool,
    lhs: View,
    rhs: View,
) {
    let out = Out(dst);
    (0..m.div_ceil(ROW_BLOCK)).into_par_iter().for_each(|c| {
        let (out, lhs, rhs) = (out, lhs, rhs);
        let (r0, rows) = (c * ROW_BLOCK, ROW_BLOCK.min(m - c * ROW_BLOCK));
        // SAFETY: block c reads lhs rows r0.. and writes only dst rows r0..r0 + rows.
        unsafe {
            let lhs = View { ptr: lhs.ptr.offset(r0 as isize * lhs.rs), ..lhs };
            gemm_to(rows, n, k, out.0.add(r0 * n), acc, lhs, rhs, gemm::Parallelism::None)
        }
    });
}

/// A layer's row product on all threads: by row blocks for a narrow layer (`NARROW`
/// weights), else as `gemm` splits it.
///
/// # Safety
/// As [`matmul`].
#[allow(clippy::too_many_arguments)]
unsafe fn matmul_layer(
    weights: usize,
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    acc: bool,
    lhs: View,
    rhs: View,
) {
    if weights <= NARROW {
        matmul_rows(m, n, k, dst, acc, lhs, rhs)
    } else {
        matmul_par(m, n, k, dst, acc, lhs, rhs)
    }
}

/// The element-wise sum of `n`-long partial results, added in their order (the parallel
/// kernels' fixed blocks: the same sums for any thread count).
pub(super) fn sum_in_order<'a>(parts: impl IntoIterator<Item = &'a [f32]>, n: usize) -> Vec<f32> {
    let mut sum = vec![0f32; n];
    for p in parts {
        sum.iter_mut().zip(p).for_each(|(a, b)| *a += b);
    }
    sum
}

/// dw [in, out] = x^T dy for x [m, in] and dy [m, out]: for a narrow layer, partial products of
/// `ROW_BLOCK` rows in parallel, added in order.
fn weight_grad(x: &[f32], dy: &[f32], m: usize, n_in: usize, n_out: usize) -> Vec<f32> {
    if n_in * n_out > NARROW {
        // SAFETY: x is [m, n_in], dy [m, n_out]; every element of dw written.
        return unsafe {
            overwritten(n_in * n_out, |p| {
                matmul_par(n_in, n_out, m, p, false, transposed(x, n_in), rows(dy, n_out))
            })
        };
    }
    let parts: Vec<Vec<f32>> = (0..m.div_ceil(ROW_BLOCK))
        .into_par_iter()
        .map(|c| {
            let (r0, r) = (c * ROW_BLOCK, ROW_BLOCK.min(m - c * ROW_BLOCK));
            let (xb, gb) = (&x[r0 * n_in..(r0 + r) * n_in], &dy[r0 * n_out..(r0 + r) * n_out]);
            // SAFETY: xb is [r, n_in], gb [r, n_out]; every element of the part written.
            unsafe {
                overwritten(n_in * n_out, |p| {
                    matmul(n_in, n_out, r, p, n_out, transposed(xb, n_in), rows(gb, n_out))
                })
            }
        })
        .collect();
    sum_in_order(parts.iter().map(Vec::as_slice), n_in * n_out)
}

pub(super) fn rows(x: &[f32], cols: usize) -> View {
    View { ptr: x.as_ptr(), rs: cols as isize, cs: 1 }
}

/// A row-major [_, cols] matrix read as its transpose.
pub(super) fn transposed(x: &[f32], cols: usize) -> View {
    View { ptr: x.as_ptr(), rs: 1, cs: cols as isize }
}

/// y [rows, out] = x [rows, in] . w [in, out] + b `[out]`: the bias is the product's starting
/// value, so there is no separate broadcast pass.
pub fn linear_forward(x: &[f32], w: &[f32], b: &[f32]) -> Vec<f32> {
    let (n_out, n_in) = (b.len(), w.len() / b.len());
    let m = x.len() / n_in;
    let (mut y, _) = par_built(m * n_out, n_out * 64, |_, part| {
        part.chunks_mut(n_out).for_each(|r| r.copy_from_slice(b))
    });
    // SAFETY: x is [m, n_in], w [n_in, n_out], y [m, n_out].
    unsafe {
        matmul_layer(w.len(), m, n_out, n_in, y.as_mut_ptr(), true, rows(x, n_in), rows(w, n_out))
    };
    y
}

/// Gradients (dx, dw, db) of [`linear_forward`] for `dy` [rows, out].
pub fn linear_backward(
    x: &[f32],
    w: &[f32],
    dy: &[f32],
    n_out: usize,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let n_in = w.len() / n_out;
    let m = x.len() / n_in;
    // SAFETY: shapes as in linear_forward; dx = dy w^T, every element written.
    let dx = unsafe {
        overwritten(m * n_in, |p| {
            matmul_layer(w.len(), m, n_in, n_out, p, false, rows(dy, n_out), transposed(w, n_out))
        })
    };
    let dw = weight_grad(x, dy, m, n_in, n_out);
    // Column sums over fixed row blocks, added in order: the same for any thread count.
    let parts: Vec<Vec<f32>> = dy
        .par_chunks(n_out * 64)
        .map(|c| {
            let mut s = vec![0f32; n_out];
            c.chunks(n_out).for_each(|r| s.iter_mut().zip(r).for_each(|(a, b)| *a += b));
            s
        })
        .collect();
    let db = sum_in_order(parts.iter().map(Vec::as_slice), n_out);
    (dx, dw, db)
}

/// gelu(x) = x Phi(x) (the exact form) of each element in place.
#[inline(always)]
fn gelu_rows(c: &mut [f32]) {
    for x in c.iter_mut() {
        *x = 0.5 * *x * (1.0 + erf(*x * std::f32::consts::FRAC_1_SQRT_2));
    }
}

/// o = d gelu(x) / dx * g, element by element.
#[inline(always)]
fn gelu_grad_rows(o: &mut [f32], x: &[f32], g: &[f32]) {
    let inv_sqrt_2pi = 0.5 * std::f32::consts::FRAC_2_SQRT_PI * std::f32::consts::FRAC_1_SQRT_2;
    let (x, g) = (&x[..o.len()], &g[..o.len()]);
    for i in 0..o.len() {
        // erf(x / sqrt 2) needs e^(-x^2 / 2), the density's own factor: one exp for both.
        let gauss = exp_neg(-0.5 * x[i] * x[i]);
        let cdf = 0.5 * (1.0 + erf_with(x[i] * std::f32::consts::FRAC_1_SQRT_2, gauss));
        o[i] = g[i] * (cdf + x[i] * inv_sqrt_2pi * gauss);
    }
}

elementwise_builds!(pub(super) gelu_chunk, gelu_rows, gelu_rows_avx512, gelu_rows_avx2, (c: &mut [f32]));
elementwise_builds!(gelu_grad_chunk, gelu_grad_rows, gelu_grad_rows_avx512, gelu_grad_rows_avx2,
    (o: &mut [f32], x: &[f32], g: &[f32]));

const GELU_CHUNK: usize = 1 << 14;

/// Each element of `o` times its dropout mask value (scale folded in; None: no dropout).
fn apply_mask(o: &mut [f32], m: Option<&[f32]>) {
    if let Some(m) = m {
        o.iter_mut().zip(m).for_each(|(v, m)| *v *= m);
    }
}

/// GELU (exact form, x Phi(x)) in place, then the dropout mask `m` (None: no dropout).
pub fn gelu_inplace(h: &mut [f32], m: Option<&[f32]>) {
    h.par_chunks_mut(GELU_CHUNK).enumerate().for_each(|(c, o)| {
        gelu_chunk(o);
        apply_mask(o, m.map(|m| chunk_of(m, GELU_CHUNK, c, o.len())));
    });
}

/// GELU (exact form) of `h` times the dropout mask `m` into a new vector, `h` kept (the
/// backward pass reads it).
pub fn gelu(h: &[f32], m: Option<&[f32]>) -> Vec<f32> {
    par_built(h.len(), GELU_CHUNK, |c, o| {
        let n = o.len();
        o.copy_from_slice(chunk_of(h, GELU_CHUNK, c, n));
        gelu_chunk(o);
        apply_mask(o, m.map(|m| chunk_of(m, GELU_CHUNK, c, n)));
    })
    .0
}

/// d gelu(h) / dh * (dy * m): the gradient through the dropout mask `m` (None: none) and GELU,
/// in that order, as separate ops would round it.
pub fn gelu_backward(h: &[f32], dy: &[f32], m: Option<&[f32]>) -> Vec<f32> {
    par_built(h.len(), GELU_CHUNK, |c, o| {
        let n = o.len();
        let (h, dy) = (chunk_of(h, GELU_CHUNK, c, n), chunk_of(dy, GELU_CHUNK, c, n));
        match m {
            Some(m) => {
                let mut g = dy.to_vec();
                apply_mask(&mut g, Some(chunk_of(m, GELU_CHUNK, c, n)));
                gelu_grad_chunk(o, h, &g)
            }
            None => gelu_grad_chunk(o, h, dy),
        }
    })
    .0
}

/// Rows per parallel work item of the LayerNorm kernels (fixed, so the parameter-gradient sums
/// are added in the same order for any thread count).
const LN_ROWS: usize = 64;

/// (x - mean) / sqrt(var + eps) * gamma + beta over rows of `gamma.len()` (biased variance).
pub fn layer_norm_forward(x: &[f32], gamma: &[f32], beta: &[f32], eps: f32) -> Vec<f32> {
    let chunk = gamma.len() * LN_ROWS;
    par_built(x.len(), chunk, |c, yc| {
        ln_chunk(yc, chunk_of(x, chunk, c, yc.len()), gamma, beta, eps)
    })
    .0
}

/// Rows whose LayerNorm sums run side by side. Each row's sums still add its elements one after
/// another (the same bits as one row at a time), but one row's chain of dependent additions
/// left the adders idle; eight chains fill them.
const LN_LANES: usize = 8;

/// Mean and 1 / sqrt(biased variance + eps) of each of the K rows of `x` ([K, d]), each row's
/// elements summed in order.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // column j of every row: the rows' chains interleave
fn moments<const K: usize>(x: &[f32], d: usize, eps: f32) -> [(f32, f32); K] {
    let rows: [&[f32]; K] = std::array::from_fn(|r| &x[r * d..(r + 1) * d]);
    let n = d as f32;
    // -0.0: where `Iterator::sum` starts.
    let mut sum = [-0.0f32; K];
    for j in 0..d {
        for r in 0..K {
            sum[r] += rows[r][j];
        }
    }
    let mean = sum.map(|s| s / n);
    let mut var = [-0.0f32; K];
    for j in 0..d {
        for r in 0..K {
            let t = rows[r][j] - mean[r];
            var[r] += t * t;
        }
    }
    std::array::from_fn(|r| (mean[r], 1.0 / (var[r] / n + eps).sqrt()))
}

#[inline(always)]
fn ln_rows(yc: &mut [f32], xc: &[f32], gamma: &[f32], beta: &[f32], eps: f32) {
    let d = gamma.len();
    let norm = |yr: &mut [f32], xr: &[f32], (mean, rstd): (f32, f32)| {
        for j in 0..d {
            yr[j] = (xr[j] - mean) * rstd * gamma[j] + beta[j];
        }
    };
    let whole = xc.len() / (d * LN_LANES) * (d * LN_LANES);
    for (yb, xb) in yc[..whole].chunks_mut(d * LN_LANES).zip(xc[..whole].chunks(d * LN_LANES)) {
        let m = moments::<LN_LANES>(xb, d, eps);
        for ((yr, xr), m) in yb.chunks_mut(d).zip(xb.chunks(d)).zip(m) {
            norm(yr, xr, m);
        }
    }
    for (yr, xr) in yc[whole..].chunks_mut(d).zip(xc[whole..].chunks(d)) {
        norm(yr, xr, moments::<1>(xr, d, eps)[0]);
    }
}

elementwise_builds!(pub(super) ln_chunk, ln_rows, ln_rows_avx512, ln_rows_avx2,
    (yc: &mut [f32], xc: &[f32], gamma: &[f32], beta: &[f32], eps: f32));

/// h + a (o m): a residual branch with its dropout mask, if any.
pub fn residual(h: &[f32], a: &[f32], m: Option<&[f32]>) -> Vec<f32> {
    const CHUNK: usize = 1 << 14;
    par_built(h.len(), CHUNK, |c, x| {
        let n = x.len();
        x.copy_from_slice(chunk_of(h, CHUNK, c, n));
        let a = chunk_of(a, CHUNK, c, n);
        match m {
            Some(m) => add_masked(x, a, chunk_of(m, CHUNK, c, n)),
            None => x.iter_mut().zip(a).for_each(|(x, a)| *x += a),
        }
    })
    .0
}

#[inline(always)]
fn add_masked_rows(x: &mut [f32], a: &[f32], m: &[f32]) {
    x.iter_mut().zip(a.iter().zip(m)).for_each(|(x, (a, m))| *x += a * m);
}

elementwise_builds!(add_masked, add_masked_rows, add_masked_avx512, add_masked_avx2,
    (x: &mut [f32], a: &[f32], m: &[f32]));

/// Gradients (dx, dgamma, dbeta) of [`layer_norm_forward`] for `dy`.
pub fn layer_norm_backward(
    x: &[f32],
    gamma: &[f32],
    dy: &[f32],
    eps: f32,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let (d, chunk) = (gamma.len(), gamma.len() * LN_ROWS);
    let (dx, partial) = par_built(x.len(), chunk, |c, dxc| {
        let n = dxc.len();
        ln_grad_chunk(dxc, chunk_of(x, chunk, c, n), chunk_of(dy, chunk, c, n), gamma, eps)
    });
    let dgamma = sum_in_order(partial.iter().map(|(g, _)| g.as_slice()), d);
    let dbeta = sum_in_order(partial.iter().map(|(_, b)| b.as_slice()), d);
    (dx, dgamma, dbeta)
}

/// One chunk of rows of [`layer_norm_backward`]: dx in place, and the chunk's (dgamma, dbeta).
#[inline(always)]
fn ln_grad_rows(
    dxc: &mut [f32],
    xc: &[f32],
    gc: &[f32],
    gamma: &[f32],
    eps: f32,
) -> (Vec<f32>, Vec<f32>) {
    let d = gamma.len();
    let (mut dg, mut db) = (vec![0f32; d], vec![0f32; d]);
    let mut g = vec![0f32; d];
    let rows = xc.len() / d;
    let whole = rows / LN_LANES * LN_LANES;
    let stats: Vec<(f32, f32)> = xc[..whole * d]
        .chunks(d * LN_LANES)
        .flat_map(|xb| moments::<LN_LANES>(xb, d, eps))
        .chain(xc[whole * d..].chunks(d).map(|xr| moments::<1>(xr, d, eps)[0]))
        .collect();
    let rows = dxc.chunks_mut(d).zip(xc.chunks(d)).zip(gc.chunks(d)).zip(stats);
    for (((dxr, xr), gr), (mean, rstd)) in rows {
        let (mut sum_g, mut sum_gx) = (0f32, 0f32);
        for j in 0..d {
            let xhat = (xr[j] - mean) * rstd;
            dg[j] += gr[j] * xhat;
            db[j] += gr[j];
            g[j] = gr[j] * gamma[j];
            sum_g += g[j];
            sum_gx += g[j] * xhat;
        }
        let (mg, mgx) = (sum_g / d as f32, sum_gx / d as f32);
        for j in 0..d {
            let xhat = (xr[j] - mean) * rstd;
            dxr[j] = rstd * (g[j] - mg - xhat * mgx);
        }
    }
    (dg, db)
}

elementwise_builds!(ln_grad_chunk, ln_grad_rows, ln_grad_rows_avx512, ln_grad_rows_avx2,
    (dxc: &mut [f32], xc: &[f32], gc: &[f32], gamma: &[f32], eps: f32) -> (Vec<f32>, Vec<f32>));

/// The AVX-512 and AVX2 builds give the same bits as the plain one (only the width differs).
#[cfg(all(test, target_arch = "x86_64"))]
mod builds {
    use super::*;

    fn values(len: usize, k: usize) -> Vec<f32> {
        (0..len).map(|i| ((i * k) % 193) as f32 / 32.0 - 3.0).collect()
    }

    #[test]
    fn wide_builds_give_the_plain_builds_bits() {
        if !crate::kernels::simd::every_build_here() {
            return;
        }
        let (x, g, m) = (values(3000, 7), values(3000, 11), values(3000, 13));
        let (gamma, beta) = (values(120, 3), values(120, 5));
        let mut outs: Vec<Vec<Vec<f32>>> = Vec::new();
        for build in 0..3 {
            let mut o = Vec::new();
            let mut h = x.clone();
            let mut dh = vec![0f32; 3000];
            let mut y = vec![0f32; 3000];
            let mut dx = vec![0f32; 3000];
            let mut r = x.clone();
            // SAFETY: the CPU has both feature sets (checked above).
            let (dg, db) = unsafe {
                match build {
                    0 => {
                        gelu_rows(&mut h);
                        gelu_grad_rows(&mut dh, &x, &g);
                        ln_rows(&mut y, &x, &gamma, &beta, 1e-5);
                        add_masked_rows(&mut r, &g, &m);
                        ln_grad_rows(&mut dx, &x, &g, &gamma, 1e-5)
                    }
                    1 => {
                        gelu_rows_avx2(&mut h);
                        gelu_grad_rows_avx2(&mut dh, &x, &g);
                        ln_rows_avx2(&mut y, &x, &gamma, &beta, 1e-5);
                        add_masked_avx2(&mut r, &g, &m);
                        ln_grad_rows_avx2(&mut dx, &x, &g, &gamma, 1e-5)
                    }
                    _ => {
                        gelu_rows_avx512(&mut h);
                        gelu_grad_rows_avx512(&mut dh, &x, &g);
                        ln_rows_avx512(&mut y, &x, &gamma, &beta, 1e-5);
                        add_masked_avx512(&mut r, &g, &m);
                        ln_grad_rows_avx512(&mut dx, &x, &g, &gamma, 1e-5)
                    }
                }
            };
            o.extend([h, dh, y, r, dx, dg, db]);
            outs.push(o);
        }
        let bits = |v: &[Vec<f32>]| -> Vec<Vec<u32>> {
            v.iter().map(|x| x.iter().map(|f| f.to_bits()).collect()).collect()
        };
        assert!(bits(&outs[1]) == bits(&outs[0]), "AVX2 build differs");
        assert!(bits(&outs[2]) == bits(&outs[0]), "AVX-512 build differs");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every element is written once, by its own chunk (the last one short), and the chunks'
    /// results come back in order; the parallel kernels built on it match serial loops.
    #[test]
    fn par_built_covers_every_chunk_in_order() {
        let (v, parts) = par_built(10_007, 1000, |c, part| {
            part.iter_mut().enumerate().for_each(|(i, x)| *x = (c * 1000 + i) as f32);
            (c, part.len())
        });
        assert!(v.iter().enumerate().all(|(i, &x)| x == i as f32));
        let expect: Vec<(usize, usize)> =
            (0..11).map(|c| (c, if c == 10 { 7 } else { 1000 })).collect();
        assert_eq!(parts, expect);
        let (empty, none) = par_built(0, 64, |_, _| ());
        assert!(empty.is_empty() && none.is_empty());
        // Residual (a strided chunk boundary) and GELU against plain element-wise loops.
        let h: Vec<f32> = (0..40_000).map(|i| (i % 97) as f32 / 20.0 - 2.0).collect();
        let a: Vec<f32> = (0..40_000).map(|i| (i % 31) as f32 / 10.0).collect();
        let m: Vec<f32> = (0..40_000).map(|i| (i % 3 == 0) as u8 as f32).collect();
        let want: Vec<f32> = h.iter().zip(&a).zip(&m).map(|((h, a), m)| h + a * m).collect();
        assert_eq!(residual(&h, &a, Some(&m)), want);
        let mut g = h.clone();
        gelu_inplace(&mut g, None);
        assert_eq!(gelu(&h, None), g);
    }

    /// Eight rows' LayerNorm statistics side by side are, bit for bit, each row's alone, and
    /// those of summing the row in order as `Iterator::sum` does.
    #[test]
    fn rows_side_by_side_give_each_rows_own_bits() {
        let d = 37;
        let x: Vec<f32> =
            (0..LN_LANES * d).map(|i| ((i * 7919) % 1013) as f32 / 97.0 - 5.0).collect();
        let together = moments::<LN_LANES>(&x, d, 1e-5);
        for (r, row) in x.chunks(d).enumerate() {
            assert_eq!(together[r], moments::<1>(row, d, 1e-5)[0], "row {r}");
            let mean = row.iter().sum::<f32>() / d as f32;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / d as f32;
            assert_eq!(together[r], (mean, 1.0 / (var + 1e-5).sqrt()), "row {r}");
        }
    }
}

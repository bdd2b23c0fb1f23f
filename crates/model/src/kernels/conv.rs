//! The decoder's depthwise temporal convolution (`network::temporal`) on host slices, forward
//! and backward, parallel over samples: one pass over each sample's frames, where the composed
//! Burn ops take a slice, a concatenation, a product and a sum of the whole sequence per tap
//! (and their backward as many), every one of them on a single thread.

use super::host::{par_built, sum_in_order};
use super::simd::elementwise_builds;

/// Shapes of one call: tokens [B, M, d] whose rows `skip`.. are the N = M - skip frames the
/// convolution runs over; taps [K, d], K odd, tap k reading frame t + k - K/2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConvShape {
    pub batch: usize,
    pub rows: usize,
    pub skip: usize,
    pub d: usize,
    pub kernel: usize,
}

impl ConvShape {
    fn frames(&self) -> usize {
        self.rows - self.skip
    }

    /// The frame tap k reads for output frame t, if it is inside the sequence and real.
    fn source(&self, t: usize, k: usize, real: &[f32]) -> Option<usize> {
        let src = (t + k).checked_sub(self.kernel / 2)?;
        (src < self.frames() && real[src] != 0.0).then_some(src)
    }
}

/// y[b, skip + t] = sum_k w[k] o h[b, skip + t + k - K/2] over the taps whose frame is inside
/// the sequence and real (`real` [B, N]: 1 on real frames, 0 on padding, which reads as 0);
/// the first `skip` rows of every sample are 0. h [B, M, d], w [K, d] -> [B, M, d].
pub fn temporal_forward(h: &[f32], w: &[f32], real: &[f32], s: &ConvShape) -> Vec<f32> {
    let (m, n, d) = (s.rows, s.frames(), s.d);
    par_built(s.batch * m * d, m * d, |b, yb| {
        let (hb, rb) = (&h[b * m * d..(b + 1) * m * d], &real[b * n..(b + 1) * n]);
        sample_forward(yb, hb, rb, w, s);
    })
    .0
}

/// One sample of [`temporal_forward`]: yb, hb [M, d], rb [N].
#[inline(always)]
fn sample_forward_rows(yb: &mut [f32], hb: &[f32], rb: &[f32], w: &[f32], s: &ConvShape) {
    let d = s.d;
    for t in 0..s.frames() {
        frame_taps_rows(&mut yb[(s.skip + t) * d..(s.skip + t + 1) * d], hb, rb, w, s, t);
    }
}

elementwise_builds!(sample_forward, sample_forward_rows, sample_forward_avx512,
    sample_forward_avx2, (yb: &mut [f32], hb: &[f32], rb: &[f32], w: &[f32], s: &ConvShape));

/// Adds the convolution of token rows `rows` (of all B x M, flattened) to `out` [rows, d]: the
/// single-threaded row form of `temporal_forward` for the sampling path (one parallel region
/// chains it with the rows' other ops), each value summed over the taps in the same order.
pub fn temporal_add_rows(
    h: &[f32],
    w: &[f32],
    real: &[f32],
    s: &ConvShape,
    rows: std::ops::Range<usize>,
    out: &mut [f32],
) {
    let (m, n, d) = (s.rows, s.frames(), s.d);
    let mut y = vec![0f32; d];
    for (r, o) in rows.zip(out.chunks_mut(d)) {
        let (b, i) = (r / m, r % m);
        y.fill(0.0);
        if i >= s.skip {
            let (hb, rb) = (&h[b * m * d..(b + 1) * m * d], &real[b * n..(b + 1) * n]);
            frame_taps(&mut y, hb, rb, w, s, i - s.skip);
        }
        o.iter_mut().zip(&y).for_each(|(o, y)| *o += y);
    }
}

/// y [d] += the taps' sum for frame t of one sample's tokens hb [M, d], tap after tap.
#[inline(always)]
fn frame_taps_rows(y: &mut [f32], hb: &[f32], rb: &[f32], w: &[f32], s: &ConvShape, t: usize) {
    let d = s.d;
    for k in 0..s.kernel {
        let Some(src) = s.source(t, k, rb) else { continue };
        let x = &hb[(s.skip + src) * d..(s.skip + src + 1) * d];
        for ((o, &wv), &xv) in y.iter_mut().zip(&w[k * d..(k + 1) * d]).zip(x) {
            *o += xv * wv;
        }
    }
}

elementwise_builds!(frame_taps, frame_taps_rows, frame_taps_avx512, frame_taps_avx2,
    (y: &mut [f32], hb: &[f32], rb: &[f32], w: &[f32], s: &ConvShape, t: usize));

/// Gradients (dh, dw) of [`temporal_forward`] for `dy` [B, M, d]. The taps' gradient is summed
/// per sample, then over the samples in order: the same for any thread count.
pub fn temporal_backward(
    h: &[f32],
    w: &[f32],
    real: &[f32],
    dy: &[f32],
    s: &ConvShape,
) -> (Vec<f32>, Vec<f32>) {
    let (m, n, d) = (s.rows, s.frames(), s.d);
    let (dh, parts) = par_built(s.batch * m * d, m * d, |b, dhb| {
        let (hb, rb) = (&h[b * m * d..(b + 1) * m * d], &real[b * n..(b + 1) * n]);
        sample_backward(dhb, hb, rb, &dy[b * m * d..(b + 1) * m * d], w, s)
    });
    (dh, sum_in_order(parts.iter().map(Vec::as_slice), s.kernel * d))
}

/// One sample of [`temporal_backward`]: dhb in place, and the sample's tap gradient [K, d].
#[inline(always)]
fn sample_backward_rows(
    dhb: &mut [f32],
    hb: &[f32],
    rb: &[f32],
    dyb: &[f32],
    w: &[f32],
    s: &ConvShape,
) -> Vec<f32> {
    let d = s.d;
    let mut dw = vec![0f32; s.kernel * d];
    for t in 0..s.frames() {
        let g = &dyb[(s.skip + t) * d..(s.skip + t + 1) * d];
        for k in 0..s.kernel {
            let Some(src) = s.source(t, k, rb) else { continue };
            let row = (s.skip + src) * d..(s.skip + src + 1) * d;
            let (x, dx) = (&hb[row.clone()], &mut dhb[row]);
            let (wk, dwk) = (&w[k * d..(k + 1) * d], &mut dw[k * d..(k + 1) * d]);
            for c in 0..d {
                dx[c] += g[c] * wk[c];
                dwk[c] += g[c] * x[c];
            }
        }
    }
    dw
}

elementwise_builds!(sample_backward, sample_backward_rows, sample_backward_avx512,
    sample_backward_avx2,
    (dhb: &mut [f32], hb: &[f32], rb: &[f32], dyb: &[f32], w: &[f32], s: &ConvShape) -> Vec<f32>);

#[cfg(all(test, target_arch = "x86_64"))]
mod builds {
    use super::*;

    #[test]
    fn wide_builds_give_the_plain_builds_bits() {
        if !crate::kernels::simd::every_build_here() {
            return;
        }
        let s = ConvShape { batch: 1, rows: 40, skip: 3, d: 24, kernel: 9 };
        let v = |len: usize, k: usize| -> Vec<f32> {
            (0..len).map(|i| ((i * k) % 101) as f32 / 25.0 - 2.0).collect()
        };
        let (h, w, g) = (v(40 * 24, 7), v(9 * 24, 3), v(40 * 24, 5));
        let real: Vec<f32> = (0..37).map(|t| if t % 11 == 4 { 0.0 } else { 1.0 }).collect();
        let run = |build: usize| {
            let (mut y, mut dh) = (vec![0f32; 40 * 24], vec![0f32; 40 * 24]);
            // SAFETY: the CPU has both feature sets (checked above).
            let dw = unsafe {
                match build {
                    0 => {
                        sample_forward_rows(&mut y, &h, &real, &w, &s);
                        sample_backward_rows(&mut dh, &h, &real, &g, &w, &s)
                    }
                    1 => {
                        sample_forward_avx2(&mut y, &h, &real, &w, &s);
                        sample_backward_avx2(&mut dh, &h, &real, &g, &w, &s)
                    }
                    _ => {
                        sample_forward_avx512(&mut y, &h, &real, &w, &s);
                        sample_backward_avx512(&mut dh, &h, &real, &g, &w, &s)
                    }
                }
            };
            [y, dh, dw].map(|x| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>())
        };
        assert!(run(1) == run(0), "AVX2 build differs");
        assert!(run(2) == run(0), "AVX-512 build differs");
    }
}

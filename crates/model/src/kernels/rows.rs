//! Single-threaded kernels over a block of token rows, for the sampling path
//! (`network::inference`): one parallel region hands each thread its rows and chains several
//! of these on them, instead of one pool round trip (and one new buffer) per op. Each gives the
//! same values as its parallel twin in `host.rs`: rows are computed independently, in the same
//! order of operations.

use super::host::{gelu_chunk, gemm_to, ln_chunk, rows};
use super::LN_EPS;

/// y [m, out] = x [m, in] . w [in, out] + b `[out]` (`host::linear_forward`: the bias is the
/// product's starting value).
pub fn linear(x: &[f32], w: &[f32], b: &[f32], y: &mut [f32]) {
    let (n_out, n_in) = (b.len(), w.len() / b.len());
    let m = x.len() / n_in;
    assert_eq!(y.len(), m * n_out, "linear: output [rows, out]");
    y.chunks_mut(n_out).for_each(|r| r.copy_from_slice(b));
    // SAFETY: x is [m, n_in], w [n_in, n_out], y [m, n_out] (checked above).
    unsafe {
        gemm_to(
            m,
            n_out,
            n_in,
            y.as_mut_ptr(),
            true,
            rows(x, n_in),
            rows(w, n_out),
            gemm::Parallelism::None,
        )
    }
}

/// y = LayerNorm(h + a) over rows of `gamma.len()`; `a` is left holding h + a
/// (`host::residual`, then `host::layer_norm_forward`).
pub fn residual_layer_norm(h: &[f32], a: &mut [f32], gamma: &[f32], beta: &[f32], y: &mut [f32]) {
    a.iter_mut().zip(h).for_each(|(a, h)| *a += h);
    ln_chunk(y, a, gamma, beta, LN_EPS);
}

/// GELU (exact form) in place (`host::gelu_inplace` without dropout).
pub fn gelu(x: &mut [f32]) {
    gelu_chunk(x);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::host;

    fn ramp(n: usize, k: f32) -> Vec<f32> {
        (0..n).map(|i| ((i as f32 * k).sin() * 1.7).round() / 4.0 + (i % 7) as f32 * 0.01).collect()
    }

    fn worst(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    /// Each row kernel on blocks of rows against the parallel kernel on the whole matrix: the
    /// same bits. (A block of one row would not be: `gemm` takes a matrix-vector path for it.)
    #[test]
    fn blocks_of_rows_match_the_parallel_kernels() {
        let (m, n_in, n_out) = (37, 24, 40);
        let (x, w, b) = (ramp(m * n_in, 0.37), ramp(n_in * n_out, 0.11), ramp(n_out, 0.5));
        let whole = host::linear_forward(&x, &w, &b);
        let mut got = vec![0.0; m * n_out];
        for (r0, r1) in [(0, 11), (11, 14), (14, m)] {
            linear(&x[r0 * n_in..r1 * n_in], &w, &b, &mut got[r0 * n_out..r1 * n_out]);
        }
        assert!(got == whole, "products differ by {}", worst(&got, &whole));

        let (gamma, beta) = (ramp(n_out, 0.7), ramp(n_out, 0.3));
        let h = ramp(m * n_out, 0.23);
        let want =
            host::layer_norm_forward(&host::residual(&h, &whole, None), &gamma, &beta, LN_EPS);
        let (mut y, mut a) = (vec![0.0; m * n_out], got);
        residual_layer_norm(&h, &mut a, &gamma, &beta, &mut y);
        assert!(y == want, "LayerNorm differs by {}", worst(&y, &want));

        let mut g = want.clone();
        gelu(&mut g);
        let mut par = want;
        host::gelu_inplace(&mut par, None);
        assert!(g == par, "GELU differs by {}", worst(&g, &par));
    }
}

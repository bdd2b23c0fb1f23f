//! Transition guidance (paper Eq. 4-5): around each keyframe i, the window
//! G_i = [x_{i-l} .. x_i^kf .. x_{i+l}] (clipped at the ends) should lie in the span of the
//! first m DCT-II bases along time; L_tr = 1/((2l+1)K) sum_i ||D D^T G_i - G_i||^2. Its gradient
//! with respect to the generated frames of a window is 2/((2l+1)K) (I - D D^T) G_i on those rows
//! (the projection is symmetric and idempotent), so no autodiff is needed in x0 mode.

/// Orthonormal DCT-II basis of length `n`: `m` columns, row-major [n, m].
pub fn dct_basis(n: usize, m: usize) -> Vec<f64> {
    let mut d = vec![0.0; n * m];
    for k in 0..m.min(n) {
        let scale = if k == 0 { (1.0 / n as f64).sqrt() } else { (2.0 / n as f64).sqrt() };
        for t in 0..n {
            d[t * m + k] =
                scale * (std::f64::consts::PI * (t as f64 + 0.5) * k as f64 / n as f64).cos();
        }
    }
    d
}

/// Projection onto the first `m` DCT bases of a window of `n` frames: [n, n].
pub fn projection(n: usize, m: usize) -> Vec<f64> {
    let d = dct_basis(n, m);
    let mut p = vec![0.0; n * n];
    for a in 0..n {
        for b in 0..n {
            p[a * n + b] = (0..m).map(|k| d[a * m + k] * d[b * m + k]).sum();
        }
    }
    p
}

/// L_tr and its gradient for one sample. `x` is [N, D] (predicted x0, normalised), keyframe
/// frames `keys` with their observed values in `kf` [N, D] and per-dim mask `mask` [N, D]
/// (observed dims of a keyframe frame take the keyframe's value inside the window; the rest the
/// prediction's). Frames >= `len` are padding and stay outside windows. Returns (loss, grad [N, D]).
#[allow(clippy::too_many_arguments)] // the paper's symbols (Eq. 4-5): window l, bases m
pub fn loss_and_grad(
    x: &[f32],
    kf: &[f32],
    mask: &[f32],
    keys: &[usize],
    len: usize,
    dim: usize,
    l: usize,
    m: usize,
) -> (f64, Vec<f32>) {
    let mut grad = vec![0f32; x.len()];
    if keys.is_empty() || len == 0 {
        return (0.0, grad);
    }
    let value = |f: usize, c: usize| -> f64 {
        let k = f * dim + c;
        if mask[k] > 0.0 {
            kf[k] as f64
        } else {
            x[k] as f64
        }
    };
    let norm = 1.0 / ((2 * l + 1) as f64 * keys.len() as f64);
    let mut loss = 0.0;
    for &i in keys {
        let lo = i.saturating_sub(l);
        let hi = (i + l).min(len - 1);
        let n = hi - lo + 1;
        let p = projection(n, m.min(n));
        for c in 0..dim {
            let g: Vec<f64> = (lo..=hi).map(|f| value(f, c)).collect();
            // r = (I - P) g
            let r: Vec<f64> =
                (0..n).map(|a| g[a] - (0..n).map(|b| p[a * n + b] * g[b]).sum::<f64>()).collect();
            loss += norm * r.iter().map(|v| v * v).sum::<f64>();
            for (a, f) in (lo..=hi).enumerate() {
                // Observed elements are data, not variables.
                if mask[f * dim + c] == 0.0 {
                    grad[f * dim + c] += (2.0 * norm * r[a]) as f32;
                }
            }
        }
    }
    (loss, grad)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dct_is_orthonormal_and_keeps_constants() {
        let (n, m) = (5, 5);
        let d = dct_basis(n, m);
        for a in 0..m {
            for b in 0..m {
                let dot: f64 = (0..n).map(|t| d[t * m + a] * d[t * m + b]).sum();
                assert!((dot - if a == b { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        // A constant window is its own projection for any m >= 1: zero loss.
        let p = projection(5, 1);
        let g = [0.7f64; 5];
        for a in 0..5 {
            let pg: f64 = (0..5).map(|b| p[a * 5 + b] * g[b]).sum();
            assert!((pg - 0.7).abs() < 1e-12);
        }
        let x = vec![0.3f32; 10 * 2];
        let (loss, grad) = loss_and_grad(&x, &x, &[0.0; 20], &[4], 10, 2, 2, 1);
        assert!(loss.abs() < 1e-12 && grad.iter().all(|g| g.abs() < 1e-7));
    }

    /// The analytic gradient against finite differences.
    #[test]
    fn gradient_matches_finite_differences() {
        let (n, dim) = (12, 3);
        let mut r = diffkfc_data::rng::Rng::new(5);
        let x: Vec<f32> = (0..n * dim).map(|_| r.normal() as f32).collect();
        let kf: Vec<f32> = (0..n * dim).map(|_| r.normal() as f32).collect();
        let mut mask = vec![0f32; n * dim];
        for c in 0..dim {
            mask[5 * dim + c] = 1.0;
        }
        mask[0] = 1.0; // a partial keyframe element at frame 0
        let keys = [0usize, 5];
        let (_, g) = loss_and_grad(&x, &kf, &mask, &keys, 10, dim, 2, 2);
        for k in 0..n * dim {
            let h = 1e-3f32;
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[k] += h;
            xm[k] -= h;
            let fd = (loss_and_grad(&xp, &kf, &mask, &keys, 10, dim, 2, 2).0
                - loss_and_grad(&xm, &kf, &mask, &keys, 10, dim, 2, 2).0)
                / (2.0 * h as f64);
            assert!((fd - g[k] as f64).abs() < 1e-3, "element {k}: fd {fd} vs {}", g[k]);
        }
    }
}

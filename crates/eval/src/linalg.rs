//! Dense symmetric linear algebra for FID (row-major f64 n x n): eigen-decomposition by
//! Householder tridiagonalisation and implicit symmetric QR steps with Wilkinson shifts
//! (Golub & Van Loan §8.3), O(n^3) with a small constant (a 512 x 512 covariance takes a
//! fraction of a second, where cyclic Jacobi took seconds), and the PSD square root.
//! Hand-written rather than faer because faer 0.22 added 1 m 40 s to a cold release build on the
//! 2-core machine (2 m 10 s of CPU) for this one decomposition; FID agrees with numpy/scipy's
//! to 1e-10 (crates/eval/tests/fid_scipy.rs).

pub fn matmul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            let (bk, ci) = (&b[k * n..(k + 1) * n], &mut c[i * n..(i + 1) * n]);
            ci.iter_mut().zip(bk).for_each(|(c, b)| *c += aik * b);
        }
    }
    c
}

/// Reduce symmetric `t` in place to tridiagonal form T = Q^T A Q; returns Q (row-major).
fn tridiagonalise(t: &mut [f64], n: usize) -> Vec<f64> {
    let mut q = vec![0.0; n * n];
    (0..n).for_each(|i| q[i * n + i] = 1.0);
    for k in 0..n.saturating_sub(2) {
        // Householder vector v (unit) that maps column k below the diagonal onto e1.
        let m = n - k - 1;
        let mut v: Vec<f64> = (k + 1..n).map(|i| t[i * n + k]).collect();
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm < 1e-300 {
            continue;
        }
        let alpha = if v[0] > 0.0 { -norm } else { norm };
        v[0] -= alpha;
        let vn = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if vn < 1e-300 {
            continue;
        }
        v.iter_mut().for_each(|x| *x /= vn);
        // H A22 H = A22 - 2 (v w^T + w v^T), p = A22 v, w = p - (v^T p) v.
        let p: Vec<f64> =
            (0..m).map(|i| (0..m).map(|j| t[(k + 1 + i) * n + k + 1 + j] * v[j]).sum()).collect();
        let kk: f64 = v.iter().zip(&p).map(|(a, b)| a * b).sum();
        let w: Vec<f64> = p.iter().zip(&v).map(|(p, v)| p - kk * v).collect();
        for i in 0..m {
            let row = &mut t[(k + 1 + i) * n + k + 1..(k + 2 + i) * n];
            row.iter_mut().enumerate().for_each(|(j, x)| *x -= 2.0 * (v[i] * w[j] + w[i] * v[j]));
        }
        t[(k + 1) * n + k] = alpha;
        t[k * n + k + 1] = alpha;
        for i in k + 2..n {
            t[i * n + k] = 0.0;
            t[k * n + i] = 0.0;
        }
        // Q <- Q H on columns k+1..n.
        for r in 0..n {
            let row = &mut q[r * n + k + 1..(r + 1) * n];
            let dot: f64 = row.iter().zip(&v).map(|(a, b)| a * b).sum();
            row.iter_mut().zip(&v).for_each(|(x, v)| *x -= 2.0 * dot * v);
        }
    }
    q
}

/// Rotation acting on indices (p, p+1) of `t` (entries within `lo..=hi`) and on columns of `q`:
/// T <- G^T T G, Q <- Q G with G = [[c, s], [-s, c]] in that plane.
fn rotate(
    t: &mut [f64],
    q: &mut [f64],
    n: usize,
    p: usize,
    (lo, hi): (usize, usize),
    (c, s): (f64, f64),
) {
    let (a, b) = (p.saturating_sub(1).max(lo), (p + 2).min(hi));
    for j in a..=b {
        let (x, y) = (t[p * n + j], t[(p + 1) * n + j]);
        t[p * n + j] = c * x - s * y;
        t[(p + 1) * n + j] = s * x + c * y;
    }
    for i in a..=b {
        let (x, y) = (t[i * n + p], t[i * n + p + 1]);
        t[i * n + p] = c * x - s * y;
        t[i * n + p + 1] = s * x + c * y;
    }
    for r in 0..n {
        let (x, y) = (q[r * n + p], q[r * n + p + 1]);
        q[r * n + p] = c * x - s * y;
        q[r * n + p + 1] = s * x + c * y;
    }
}

/// (c, s) with s x + c z = 0: the rotation that zeroes z against x.
fn givens(x: f64, z: f64) -> (f64, f64) {
    let r = x.hypot(z);
    if r == 0.0 {
        (1.0, 0.0)
    } else {
        (x / r, -z / r)
    }
}

/// Eigen-decomposition of a symmetric matrix: (eigenvalues, eigenvectors as columns,
/// row-major), so that A = V diag(w) V^T.
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut t = a.to_vec();
    let mut q = tridiagonalise(&mut t, n);
    let off = |t: &[f64], i: usize| t[i * n + i - 1];
    let mut hi = n.saturating_sub(1);
    let mut iterations = 0;
    while hi > 0 && iterations < 60 * n {
        // Deflate converged trailing eigenvalues.
        if off(&t, hi).abs()
            <= f64::EPSILON * (t[hi * n + hi].abs() + t[(hi - 1) * n + hi - 1].abs())
        {
            t[hi * n + hi - 1] = 0.0;
            t[(hi - 1) * n + hi] = 0.0;
            hi -= 1;
            continue;
        }
        let mut lo = hi - 1;
        while lo > 0
            && off(&t, lo).abs()
                > f64::EPSILON * (t[lo * n + lo].abs() + t[(lo - 1) * n + lo - 1].abs())
        {
            lo -= 1;
        }
        // Wilkinson shift from the trailing 2 x 2 block.
        let (x1, b, x2) = (t[(hi - 1) * n + hi - 1], off(&t, hi), t[hi * n + hi]);
        let d = (x1 - x2) / 2.0;
        let sign = if d >= 0.0 { 1.0 } else { -1.0 };
        let mu = x2 - b * b / (d + sign * d.hypot(b));
        let (mut x, mut z) = (t[lo * n + lo] - mu, off(&t, lo + 1));
        for p in lo..hi {
            let (c, s) = givens(x, z);
            rotate(&mut t, &mut q, n, p, (lo, hi), (c, s));
            if p + 1 < hi {
                x = t[(p + 1) * n + p];
                z = t[(p + 2) * n + p];
            }
        }
        iterations += 1;
    }
    ((0..n).map(|i| t[i * n + i]).collect(), q)
}

/// Symmetric positive semi-definite square root (negative eigenvalues from round-off clipped).
pub fn sqrtm_psd(a: &[f64], n: usize) -> Vec<f64> {
    let (w, v) = sym_eigen(a, n);
    // V diag(sqrt w) V^T = (V S)(V^T) with S scaling the columns.
    let vs: Vec<f64> = (0..n * n).map(|k| v[k] * w[k % n].max(0.0).sqrt()).collect();
    let vt: Vec<f64> = (0..n * n).map(|k| v[(k % n) * n + k / n]).collect();
    matmul(&vs, &vt, n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffkfc_data::rng::Rng;

    fn random_symmetric(n: usize, seed: u64) -> Vec<f64> {
        let mut r = Rng::new(seed);
        let a: Vec<f64> = (0..n * n).map(|_| r.normal()).collect();
        (0..n * n).map(|k| a[k] + a[(k % n) * n + k / n]).collect()
    }

    /// A V = V diag(w), V orthonormal, for random symmetric (indefinite) matrices.
    #[test]
    fn eigen_equation_holds() {
        for (n, seed) in [(1, 1), (2, 2), (3, 3), (10, 4), (64, 5)] {
            let a = random_symmetric(n, seed);
            let (w, v) = sym_eigen(&a, n);
            let av = matmul(&a, &v, n);
            let vtv =
                matmul(&(0..n * n).map(|k| v[(k % n) * n + k / n]).collect::<Vec<_>>(), &v, n);
            for i in 0..n {
                for j in 0..n {
                    assert!((av[i * n + j] - v[i * n + j] * w[j]).abs() < 1e-9, "n={n}");
                    assert!((vtv[i * n + j] - (i == j) as i32 as f64).abs() < 1e-10, "n={n}");
                }
            }
        }
        // Repeated eigenvalues (identity block) and a zero matrix.
        let (w, _) = sym_eigen(&[2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 5.0], 3);
        assert_eq!(w, vec![2.0, 2.0, 5.0]);
        assert_eq!(sym_eigen(&[0.0; 4], 2).0, vec![0.0, 0.0]);
    }

    #[test]
    fn sqrtm_squares_back() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let r = sqrtm_psd(&a, 3);
        let back = matmul(&r, &r, 3);
        assert!(a.iter().zip(&back).all(|(x, y)| (x - y).abs() < 1e-9), "{back:?}");
    }

    /// Random SPD matrices (A A^T + eps I): the root is symmetric and squares back.
    #[test]
    fn sqrtm_random_spd() {
        let mut r = Rng::new(11);
        for n in [2, 5, 16, 40] {
            let a: Vec<f64> = (0..n * n).map(|_| r.normal()).collect();
            let mut spd =
                matmul(&a, &(0..n * n).map(|k| a[(k % n) * n + k / n]).collect::<Vec<_>>(), n);
            (0..n).for_each(|i| spd[i * n + i] += 1e-3);
            let root = sqrtm_psd(&spd, n);
            let back = matmul(&root, &root, n);
            let scale = spd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(spd.iter().zip(&back).all(|(x, y)| (x - y).abs() < 1e-9 * scale), "n={n}");
            assert!((0..n * n)
                .all(|k| (root[k] - root[(k % n) * n + k / n]).abs() < 1e-9 * scale.sqrt()));
        }
    }
}

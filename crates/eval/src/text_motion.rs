//! Text-motion metrics of Guo et al. 2022 as MDM uses them, on evaluator embeddings
//! (rows of equal width): FID with a symmetric matrix square root, R-precision in fixed
//! batches of 32, MultiModal distance, Diversity and MultiModality.

use diffkfc_data::rng::Rng;

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
}

/// Mean and (population-corrected, n-1) covariance of rows.
pub fn mean_cov(x: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let (n, d) = (x.len(), x[0].len());
    let mut mu = vec![0.0; d];
    for r in x {
        for k in 0..d {
            mu[k] += r[k] / n as f64;
        }
    }
    let mut cov = vec![0.0; d * d];
    for r in x {
        for i in 0..d {
            let a = r[i] - mu[i];
            for j in i..d {
                cov[i * d + j] += a * (r[j] - mu[j]);
            }
        }
    }
    let denom = (n.max(2) - 1) as f64;
    for i in 0..d {
        for j in i..d {
            let v = cov[i * d + j] / denom;
            cov[i * d + j] = v;
            cov[j * d + i] = v;
        }
    }
    (mu, cov)
}

/// Eigen-decomposition of a symmetric matrix (cyclic Jacobi): (eigenvalues, eigenvectors as
/// columns, row-major).
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut m = a.to_vec();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n).flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j))).map(|(i, j)| m[i * n + j].powi(2)).sum();
        if off < 1e-22 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (m[q * n + q] - m[p * n + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (m[k * n + p], m[k * n + q]);
                    m[k * n + p] = c * akp - s * akq;
                    m[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (m[p * n + k], m[q * n + k]);
                    m[p * n + k] = c * apk - s * aqk;
                    m[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| m[i * n + i]).collect(), v)
}

/// Symmetric positive semi-definite square root (negative eigenvalues from round-off clipped).
pub fn sqrtm_psd(a: &[f64], n: usize) -> Vec<f64> {
    let (w, v) = sym_eigen(a, n);
    let mut out = vec![0.0; n * n];
    for k in 0..n {
        let s = w[k].max(0.0).sqrt();
        for i in 0..n {
            for j in 0..n {
                out[i * n + j] += v[i * n + k] * s * v[j * n + k];
            }
        }
    }
    out
}

fn matmul(a: &[f64], b: &[f64], n: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i * n + k];
            for j in 0..n {
                c[i * n + j] += aik * b[k * n + j];
            }
        }
    }
    c
}

/// Fréchet distance between Gaussians fitted to two embedding sets:
/// |mu1 - mu2|^2 + tr(S1 + S2 - 2 (S1^1/2 S2 S1^1/2)^1/2), the symmetric form of
/// tr((S1 S2)^1/2) (equal, but with a real symmetric square root).
pub fn fid(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let d = a[0].len();
    let (m1, s1) = mean_cov(a);
    let (m2, s2) = mean_cov(b);
    let r1 = sqrtm_psd(&s1, d);
    let inner = matmul(&matmul(&r1, &s2, d), &r1, d);
    let sym: Vec<f64> = (0..d * d).map(|k| 0.5 * (inner[k] + inner[(k % d) * d + k / d])).collect();
    let covmean = sqrtm_psd(&sym, d);
    let tr = (0..d).map(|i| s1[i * d + i] + s2[i * d + i] - 2.0 * covmean[i * d + i]).sum::<f64>();
    m1.iter().zip(&m2).map(|(x, y)| (x - y).powi(2)).sum::<f64>() + tr
}

/// R-precision top-1..3 and MultiModal distance: texts and motions are paired by index; in
/// consecutive batches of 32 (a final partial batch is dropped, as in T2M), each motion ranks the
/// batch's 32 texts by distance; top-k counts the true text within the k nearest.
pub fn r_precision(texts: &[Vec<f64>], motions: &[Vec<f64>], batch: usize) -> ([f64; 3], f64) {
    let (mut hits, mut n, mut mm) = ([0usize; 3], 0usize, 0.0);
    for start in (0..texts.len() / batch).map(|b| b * batch) {
        for i in start..start + batch {
            let d_true = dist(&motions[i], &texts[i]);
            mm += d_true;
            let closer = (start..start + batch).filter(|&j| j != i && dist(&motions[i], &texts[j]) < d_true).count();
            for (k, h) in hits.iter_mut().enumerate() {
                if closer <= k {
                    *h += 1;
                }
            }
            n += 1;
        }
    }
    let n = n.max(1) as f64;
    ([hits[0] as f64 / n, hits[1] as f64 / n, hits[2] as f64 / n], mm / n)
}

/// Mean distance between `pairs` random pairs of distinct rows.
pub fn diversity(x: &[Vec<f64>], pairs: usize, seed: u64) -> f64 {
    let mut r = Rng::new(seed);
    let mut total = 0.0;
    for _ in 0..pairs {
        let i = r.below(x.len());
        let mut j = r.below(x.len());
        while j == i && x.len() > 1 {
            j = r.below(x.len());
        }
        total += dist(&x[i], &x[j]);
    }
    total / pairs.max(1) as f64
}

/// MultiModality: for each text, the mean distance of `pairs` random pairs among its
/// generations; averaged over texts.
pub fn multimodality(groups: &[Vec<Vec<f64>>], pairs: usize, seed: u64) -> f64 {
    let per: Vec<f64> = groups.iter().enumerate().map(|(g, x)| diversity(x, pairs, seed ^ g as u64)).collect();
    per.iter().sum::<f64>() / per.len().max(1) as f64
}

/// Mean and 95% interval half-width (1.96 std / sqrt(n)) over replications.
pub fn mean_ci(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let m = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n;
    (m, 1.96 * var.sqrt() / n.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian(n: usize, d: usize, shift: f64, scale: f64, seed: u64) -> Vec<Vec<f64>> {
        let mut r = Rng::new(seed);
        (0..n).map(|_| (0..d).map(|_| shift + scale * r.normal()).collect()).collect()
    }

    #[test]
    fn sqrtm_squares_back() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let r = sqrtm_psd(&a, 3);
        let back = matmul(&r, &r, 3);
        assert!(a.iter().zip(&back).all(|(x, y)| (x - y).abs() < 1e-9), "{back:?}");
    }

    /// FID of a set with itself is 0; of isotropic Gaussians it is |mu1-mu2|^2 + d (s1 - s2)^2.
    #[test]
    fn fid_closed_forms() {
        let a = gaussian(4000, 4, 0.0, 1.0, 1);
        assert!(fid(&a, &a).abs() < 1e-8);
        let b = gaussian(4000, 4, 0.5, 2.0, 2);
        let want = 4.0 * 0.25 + 4.0 * (2.0f64 - 1.0).powi(2);
        let got = fid(&a, &b);
        assert!((got - want).abs() < 0.25, "{got} vs {want}");
    }

    #[test]
    fn r_precision_perfect_and_random() {
        let t = gaussian(320, 8, 0.0, 1.0, 3);
        let ([r1, r2, r3], mm) = r_precision(&t, &t, 32);
        assert_eq!((r1, r2, r3, mm), (1.0, 1.0, 1.0, 0.0));
        let m = gaussian(3200, 8, 0.0, 1.0, 4);
        let t = gaussian(3200, 8, 0.0, 1.0, 5);
        let ([r1, _, r3], _) = r_precision(&t, &m, 32);
        assert!((r1 - 1.0 / 32.0).abs() < 0.015 && (r3 - 3.0 / 32.0).abs() < 0.02, "{r1} {r3}");
    }

    #[test]
    fn diversity_and_multimodality_hand_made() {
        // Two points 5 apart: every distinct pair is at distance 5.
        let x = vec![vec![0.0, 0.0], vec![3.0, 4.0]];
        assert!((diversity(&x, 300, 1) - 5.0).abs() < 1e-12);
        assert!((multimodality(&[x.clone(), vec![vec![0.0, 0.0], vec![0.0, 1.0]]], 10, 2) - 3.0).abs() < 1e-12);
        let (m, ci) = mean_ci(&[1.0, 1.0, 1.0]);
        assert_eq!((m, ci), (1.0, 0.0));
    }
}

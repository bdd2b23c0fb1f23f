//! Text-motion metrics of Guo et al. 2022 as MDM uses them, on evaluator embeddings
//! (rows of equal width): FID with a symmetric matrix square root, R-precision in fixed
//! batches of 32, MultiModal distance, Diversity and MultiModality.

use diffkfc_data::rng::Rng;

use crate::linalg::{matmul, sqrtm_psd};

/// `rows` if every value is finite: a NaN embedding ranks every text first (R-precision 1.0)
/// beside FID NaN, a score that lies.
pub fn finite(rows: Vec<Vec<f64>>, what: &str) -> crate::error::Result<Vec<Vec<f64>>> {
    match rows.iter().flatten().find(|x| !x.is_finite()) {
        Some(x) => Err(crate::error::EvalError::NonFinite(format!("evaluator: {what} hold {x} (not finite): the evaluator's weights or the motions are broken; retrain it with `diffkfc eval train-evaluator` and check the motions with `diffkfc data check`"))),
        None => Ok(rows),
    }
}

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

/// A Gaussian fitted to an embedding set, with its covariance square root kept so that many
/// sets can be compared against one reference cheaply.
pub struct Gaussian {
    pub mean: Vec<f64>,
    pub cov: Vec<f64>,
    sqrt_cov: Vec<f64>,
}

impl Gaussian {
    pub fn fit(x: &[Vec<f64>]) -> Gaussian {
        let (mean, cov) = mean_cov(x);
        let sqrt_cov = sqrtm_psd(&cov, mean.len());
        Gaussian { mean, cov, sqrt_cov }
    }

    /// Fréchet distance to the Gaussian fitted to `x`:
    /// |mu1 - mu2|^2 + tr(S1 + S2 - 2 (S1^1/2 S2 S1^1/2)^1/2), the symmetric form of
    /// tr((S1 S2)^1/2) (equal, but with a real symmetric square root).
    pub fn fid_to(&self, x: &[Vec<f64>]) -> f64 {
        let (mean_term, cov_term) = self.fid_terms_to(x);
        mean_term + cov_term
    }

    /// The two terms of `fid_to`: |mu1 - mu2|^2 (where the sets sit) and the trace term (how
    /// they spread), so a report can tell a shifted set from a narrowed or widened one.
    pub fn fid_terms_to(&self, x: &[Vec<f64>]) -> (f64, f64) {
        let d = self.mean.len();
        let (m2, s2) = mean_cov(x);
        let (s1, r1) = (&self.cov, &self.sqrt_cov);
        let inner = matmul(&matmul(r1, &s2, d), r1, d);
        let sym: Vec<f64> =
            (0..d * d).map(|k| 0.5 * (inner[k] + inner[(k % d) * d + k / d])).collect();
        let covmean = sqrtm_psd(&sym, d);
        let tr =
            (0..d).map(|i| s1[i * d + i] + s2[i * d + i] - 2.0 * covmean[i * d + i]).sum::<f64>();
        (self.mean.iter().zip(&m2).map(|(x, y)| (x - y).powi(2)).sum::<f64>(), tr)
    }
}

/// FID between two embedding sets (see `Gaussian::fid_to`).
pub fn fid(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    Gaussian::fit(a).fid_to(b)
}

/// R-precision top-1..3 and MultiModal distance: texts and motions are paired by index; in
/// consecutive batches of 32 (a final partial batch is dropped, as in T2M), each motion ranks the
/// batch's 32 texts by distance; top-k counts the true text within the k nearest.
pub fn r_precision(texts: &[Vec<f64>], motions: &[Vec<f64>], batch: usize) -> ([f64; 3], f64) {
    r_precision_of(&text_ranks(texts, motions, batch), texts, motions)
}

/// `r_precision` from ranks already taken with `text_ranks` (same texts and motions).
pub fn r_precision_of(
    ranks: &[Option<usize>],
    texts: &[Vec<f64>],
    motions: &[Vec<f64>],
) -> ([f64; 3], f64) {
    let (mut hits, mut n, mut mm) = ([0usize; 3], 0usize, 0.0);
    for (i, rank) in ranks.iter().enumerate() {
        let Some(closer) = *rank else { continue };
        mm += dist(&motions[i], &texts[i]);
        for (k, h) in hits.iter_mut().enumerate() {
            if closer <= k {
                *h += 1;
            }
        }
        n += 1;
    }
    let n = n.max(1) as f64;
    ([hits[0] as f64 / n, hits[1] as f64 / n, hits[2] as f64 / n], mm / n)
}

/// Per motion, how many of its batch's other texts lie closer to it than its own (0: its own
/// text is the nearest; R-precision's batches); `None` for the final partial batch.
pub fn text_ranks(texts: &[Vec<f64>], motions: &[Vec<f64>], batch: usize) -> Vec<Option<usize>> {
    let full = texts.len() / batch * batch;
    (0..texts.len())
        .map(|i| {
            (i < full).then(|| {
                let start = i / batch * batch;
                let d_true = dist(&motions[i], &texts[i]);
                (start..start + batch)
                    .filter(|&j| j != i && dist(&motions[i], &texts[j]) < d_true)
                    .count()
            })
        })
        .collect()
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
    let per: Vec<f64> =
        groups.iter().enumerate().map(|(g, x)| diversity(x, pairs, seed ^ g as u64)).collect();
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

    #[test]
    fn non_finite_embeddings_are_an_error_not_a_score() {
        let rows = vec![vec![0.5, 1.0], vec![2.0, -1.0]];
        assert_eq!(finite(rows.clone(), "x").unwrap(), rows);
        let e = finite(vec![vec![0.5, f64::NAN]], "the motion embeddings").unwrap_err().to_string();
        assert!(
            e.contains("the motion embeddings hold NaN") && e.contains("train-evaluator"),
            "{e}"
        );
        // What a NaN evaluator would report as scores: FID NaN (beside R-precision 1.0).
        let nan = vec![vec![f64::NAN; 4]; 32];
        assert!(fid(&nan, &nan).is_nan());
    }

    use super::*;

    fn gaussian(n: usize, d: usize, shift: f64, scale: f64, seed: u64) -> Vec<Vec<f64>> {
        let mut r = Rng::new(seed);
        (0..n).map(|_| (0..d).map(|_| shift + scale * r.normal()).collect()).collect()
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
        // The terms: the mean shift alone (4 x 0.5^2) and the spread alone (4 x (2 - 1)^2).
        let (mean_term, cov_term) = Gaussian::fit(&a).fid_terms_to(&b);
        assert!(
            (mean_term - 1.0).abs() < 0.2 && (cov_term - 4.0).abs() < 0.25,
            "{mean_term} {cov_term}"
        );
        assert!((mean_term + cov_term - got).abs() < 1e-9);
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
        assert!(
            (multimodality(&[x.clone(), vec![vec![0.0, 0.0], vec![0.0, 1.0]]], 10, 2) - 3.0).abs()
                < 1e-12
        );
        // MM-dist: true pairs at distances 1 and 3 -> 2 (32 pairs: one full batch).
        let texts: Vec<Vec<f64>> = (0..32).map(|i| vec![100.0 * i as f64, 0.0]).collect();
        let motions: Vec<Vec<f64>> = texts
            .iter()
            .enumerate()
            .map(|(i, t)| vec![t[0], if i % 2 == 0 { 1.0 } else { 3.0 }])
            .collect();
        let (r, mm) = r_precision(&texts, &motions, 32);
        assert_eq!((r, mm), ([1.0; 3], 2.0));
        // Ranks: motion 0 moved onto text 2 has texts 1, 2 and 3 closer than its own; the 33rd
        // item is outside a full batch.
        let mut moved = motions.clone();
        moved[0] = texts[2].clone();
        let mut texts33 = texts.clone();
        texts33.push(vec![0.0, 0.0]);
        moved.push(vec![0.0, 0.0]);
        let ranks = text_ranks(&texts33, &moved, 32);
        assert_eq!((ranks[0], ranks[1], ranks[32]), (Some(3), Some(0), None));
        let (m, ci) = mean_ci(&[1.0, 1.0, 1.0]);
        assert_eq!((m, ci), (1.0, 0.0));
    }
}

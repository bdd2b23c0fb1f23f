//! FID against the formula as T2M and MDM compute it (numpy's covariance, scipy's `sqrtm`), on
//! the evaluator's 512 dimensions and on a small, nearly singular case.

use diffkfc_data::{io::npy, rng::Rng, testing::fixtures};
use diffkfc_eval::text_motion::fid;

const SCRIPT: &str = r#"
import sys, numpy as np
from scipy import linalg
a, b = np.load(sys.argv[1]), np.load(sys.argv[2])
m1, m2 = a.mean(0), b.mean(0)
s1, s2 = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
covmean, _ = linalg.sqrtm(s1.dot(s2), disp=False)
covmean = covmean.real
d = m1 - m2
print(repr(float(d.dot(d) + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean))))
"#;

/// `n` rows of `d` correlated Gaussian features: x = z M + shift (M mixes `rank` factors).
fn sample(rng: &mut Rng, n: usize, d: usize, m: &[f64], shift: f64) -> Vec<Vec<f64>> {
    let rank = m.len() / d;
    (0..n)
        .map(|_| {
            let z: Vec<f64> = (0..rank).map(|_| rng.normal()).collect();
            (0..d).map(|j| (0..rank).map(|k| z[k] * m[k * d + j]).sum::<f64>() + shift).collect()
        })
        .collect()
}

#[test]
fn fid_matches_numpy_and_scipy() {
    let dir = std::env::temp_dir().join(format!("diffkfc-fid-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = Rng::new(3);
    // (rows, dims, factors): the evaluator's 512-d embeddings of 768 items, and a 16-d case of
    // rank 12 (singular covariances, where sqrtm's choices matter).
    for (n, d, rank) in [(768, 512, 512), (200, 16, 12)] {
        // Two sets from one distribution but for a small shift: FIDs of the size evaluations see.
        let m: Vec<f64> = (0..rank * d).map(|_| rng.normal() * 0.05).collect();
        let a = sample(&mut rng, n, d, &m, 0.0);
        let b = sample(&mut rng, n, d, &m, 0.01);
        let (pa, pb) = (dir.join("a.npy"), dir.join("b.npy"));
        npy::write(&pa, &[n, d], &a.concat()).unwrap();
        npy::write(&pb, &[n, d], &b.concat()).unwrap();
        let Some(out) = fixtures::python(&["numpy", "scipy"], SCRIPT, &[&pa, &pb]) else {
            return;
        };
        let want: f64 = out.trim().parse().unwrap();
        let got = fid(&a, &b);
        assert!(
            (got - want).abs() <= 1e-6 * want.abs().max(1.0),
            "{n}x{d}: ours {got}, scipy {want}"
        );
        eprintln!("{n}x{d}: ours {got:.9}, numpy/scipy {want:.9}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

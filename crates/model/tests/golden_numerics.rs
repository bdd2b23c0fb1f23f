//! Numerical identity across performance work: the tiny network with fixed weights (from our
//! own RNG, not Burn's initialiser) on fixed inputs must give the outputs recorded before the
//! optimisations (`tests/golden/*.npy`, written by the build before them with
//! DIFFKFC_WRITE_GOLDEN=1) within 1e-5 (relative to the output scale).

use burn::prelude::*;
use diffkfc_data::{io::npy, rng::Rng};
use diffkfc_model::bench::{request, Sampling};
use diffkfc_model::{network::params, DiffKfcConfig};

fn model(cfg: &DiffKfcConfig, device: &Device) -> diffkfc_model::Denoiser {
    let m = cfg.init(device);
    let mut r = Rng::new(17);
    let vals: Vec<Vec<f32>> = params::values(&m)
        .into_iter()
        .map(|(shape, v)| {
            // Fan-in scaled normals: activations stay O(1) through every layer.
            let fan_in = if shape.len() >= 2 { shape[0] } else { 1 } as f64;
            (0..v.len())
                .map(|_| {
                    (r.normal() / fan_in.sqrt()) as f32 * if shape.len() >= 2 { 1.0 } else { 0.1 }
                })
                .collect()
        })
        .collect();
    params::load(m, &vals)
}

fn check(name: &str, got: &[f32], shape: &[usize]) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(name);
    if std::env::var("DIFFKFC_WRITE_GOLDEN").is_ok_and(|v| v == "1") {
        npy::write(&path, shape, got).unwrap();
        eprintln!("wrote {}", path.display());
        return;
    }
    let want = npy::read_f32(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (record it with DIFFKFC_WRITE_GOLDEN=1 on the reference build)",
            path.display()
        )
    });
    assert_eq!(want.shape, shape);
    let scale = want.data.iter().fold(0f32, |m, v| m.max(v.abs())).max(1.0);
    let err = got.iter().zip(&want.data).fold(0f32, |m, (a, b)| m.max((a - b).abs())) / scale;
    eprintln!("{name}: max error {err:.2e} relative to scale {scale:.3}");
    assert!(err < 1e-5, "{name}: {err}");
}

#[test]
fn forward_and_sample_match_the_recorded_outputs() {
    let device = Device::flex();
    // Recorded before keyframes had root channels: the same network without them.
    let cfg = DiffKfcConfig::tiny().with_root_channels(0);
    let m = model(&cfg, &device);
    let (n, d) = (24, cfg.feat_dim);
    let req = request(&cfg, 2, n, 5);
    let cond = req.condition(&device);
    let mut r = Rng::new(6);
    let x = Tensor::<1>::from_floats(
        (0..2 * n * d).map(|_| r.normal() as f32).collect::<Vec<_>>().as_slice(),
        &device,
    )
    .reshape([2, n, d]);
    let out = params::host(m.forward(x, &[10, 700], &cond));
    check("forward_tiny.npy", &out, &[2, n, d]);
    let s = Sampling::new(&m, &cfg, 1, n);
    // Recorded with the observed keyframe values written back after the last step.
    let mut ddim5 = s.sample(5);
    for ((v, &m), &k) in ddim5.iter_mut().zip(&s.req.mask).zip(&s.req.kf) {
        if m > 0.0 {
            *v = k;
        }
    }
    check("ddim5_tiny.npy", &ddim5, &[1, n, d]);
    check("call_cached_tiny.npy", &s.call(false), &[2, n, d]);
}

//! The fused attention and LayerNorm kernels against the same math composed from Burn ops:
//! outputs and every input gradient (autodiff), with each kind of mask, on random data.

use std::sync::Arc;

use burn::nn::LayerNormConfig;
use burn::prelude::*;
use burn::tensor::Distribution;
use diffkfc_model::kernels::{self, Mask};
use diffkfc_model::network::params::host;

/// Largest difference, relative to the reference's largest magnitude when that is above 1
/// (parameter gradients sum hundreds of rows, where float32 rounding grows with the sum).
fn max_err(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1.0f32, |m, x| m.max(x.abs()));
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max) / scale
}

fn random(shape: [usize; 3], dev: &Device) -> Tensor<3> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), dev)
}

/// Output and (dq, dk, dv) of sum(attention(q, k, v) * w), through `f`.
fn attention_grads(
    f: impl Fn(Tensor<3>, Tensor<3>, Tensor<3>) -> Tensor<3>,
    inputs: &[Tensor<3>; 4],
) -> Vec<Vec<f32>> {
    let [q, k, v, w] =
        inputs.clone().map(|t| Tensor::<3>::from_data(t.into_data(), &Device::flex().autodiff()));
    let (q, k, v) = (q.require_grad(), k.require_grad(), v.require_grad());
    let out = f(q.clone(), k.clone(), v.clone());
    let grads = (out.clone() * w).sum().backward();
    vec![
        host(out),
        host(q.grad(&grads).unwrap()),
        host(k.grad(&grads).unwrap()),
        host(v.grad(&grads).unwrap()),
    ]
}

#[test]
fn fused_attention_matches_composed_with_gradients() {
    let dev = Device::flex();
    let (b, lq, lk, heads, d) = (3, 11, 13, 4, 32);
    let keys: Vec<bool> = (0..b * lk).map(|i| i % lk > 9 || i % 5 == 3).collect();
    // Every query keeps key 0 open (as the models guarantee), the rest is a pseudo-random pattern.
    let full: Vec<bool> = (0..b * lq * lk).map(|i| i % lk != 0 && (i * 7919) % 3 == 0).collect();
    // DMA-like: besides key 0, each sample's queries see a few keys of their own (some rows
    // not all of them), so the kernel runs on the 4 seen keys instead of 13.
    let sparse: Vec<bool> = (0..b * lq * lk)
        .map(|i| {
            let (s, qi, j) = (i / (lq * lk), i / lk % lq, i % lk);
            !(j == 0 || (j % 4 == s + 1 && (qi + j) % 3 != 0))
        })
        .collect();
    for mask in [
        Mask::None,
        Mask::Keys(Arc::new(keys)),
        Mask::Full(Arc::new(full)),
        Mask::Full(Arc::new(sparse)),
    ] {
        let inputs = [
            random([b, lq, d], &dev),
            random([b, lk, d], &dev),
            random([b, lk, d], &dev),
            random([b, lq, d], &dev),
        ];
        assert!(kernels::fused(&dev), "flex runs the fused kernel");
        let fused =
            attention_grads(|q, k, v| kernels::attention(q, k, v, heads, mask.clone()), &inputs);
        let composed =
            attention_grads(|q, k, v| kernels::attention_composed(q, k, v, heads, &mask), &inputs);
        for (what, (f, c)) in ["output", "dq", "dk", "dv"].iter().zip(fused.iter().zip(&composed)) {
            let e = max_err(f, c);
            assert!(e < 2e-5, "{mask:?} {what}: max error {e}");
            assert!(c.iter().any(|x| x.abs() > 1e-3), "{what} is not trivially zero");
        }
        // Inference (no autodiff) takes the same kernel.
        let plain = kernels::attention(
            inputs[0].clone(),
            inputs[1].clone(),
            inputs[2].clone(),
            heads,
            mask.clone(),
        );
        assert!(max_err(&host(plain), &fused[0]) < 1e-6);
    }
}

#[test]
fn fused_layer_norm_matches_burn_with_gradients() {
    let ad = Device::flex().autodiff();
    let mut ln = LayerNormConfig::new(24).init(&ad);
    // Non-trivial scale and shift, so their gradients and effect are both tested.
    ln.gamma = ln.gamma.map(|g| g.random_like(Distribution::Normal(1.0, 0.5)).require_grad());
    ln.beta =
        ln.beta.map(|p| p.map(|b| b.random_like(Distribution::Normal(0.0, 0.5)).require_grad()));
    let x = random([5, 70, 24], &ad).mul_scalar(3.0).add_scalar(1.5);
    let w = random([5, 70, 24], &ad);
    let run = |fused: bool| {
        let x = x.clone().detach().require_grad();
        let y = if fused { kernels::layer_norm(&ln, x.clone()) } else { ln.forward(x.clone()) };
        let grads = (y.clone() * w.clone()).sum().backward();
        let beta = ln.beta.as_ref().unwrap().val();
        vec![
            host(y),
            host(x.grad(&grads).unwrap()),
            host(ln.gamma.val().grad(&grads).unwrap()),
            host(beta.grad(&grads).unwrap()),
        ]
    };
    let (f, c) = (run(true), run(false));
    for (what, (a, b)) in ["output", "dx", "dgamma", "dbeta"].iter().zip(f.iter().zip(&c)) {
        let e = max_err(a, b);
        assert!(e < 2e-5, "{what}: max error {e}");
    }
}

#[test]
fn fused_linear_and_linear_gelu_match_burn_with_dropout_and_gradients() {
    let ad = Device::flex().autodiff();
    // Narrow layers (products split by row blocks of 512 here): one block, and three with a
    // partial last one (the weight gradient summed over blocks); a wide layer (gemm's own split).
    for (rows, n_in, n_out) in [(3 * 70, 48, 40), (1300, 64, 48), (400, 256, 200), (300, 320, 256)]
    {
        let lin = burn::nn::LinearConfig::new(n_in, n_out).init(&ad);
        let x = Tensor::<3>::random([1, rows, n_in], Distribution::Normal(0.0, 1.0), &ad);
        let w = Tensor::<3>::random([1, rows, n_out], Distribution::Normal(0.0, 1.0), &ad);
        // GELU with dropout: the fused op applies the mask inside (forward and backward), the
        // reference multiplies Burn's GELU by `Dropout::forward`'s mask of the same stream.
        let drop = diffkfc_model::network::dropout::Dropout::new(0.3);
        let run = |fused: bool, act: usize| {
            diffkfc_model::network::dropout::seed(5);
            let x = x.clone().detach().require_grad();
            let gelu = |y| burn::tensor::activation::gelu(y);
            let y = match (fused, act) {
                (true, 0) => kernels::linear(&lin, x.clone()),
                (true, 1) => kernels::linear_gelu(&lin, x.clone()),
                (true, _) => kernels::linear_gelu_dropout(&lin, x.clone(), &drop),
                (false, 0) => lin.forward(x.clone()),
                (false, 1) => gelu(lin.forward(x.clone())),
                (false, _) => drop.forward(gelu(lin.forward(x.clone()))),
            };
            let grads = (y.clone() * w.clone()).sum().backward();
            let b = lin.bias.as_ref().unwrap().val();
            vec![
                host(y),
                host(x.grad(&grads).unwrap()),
                host(lin.weight.val().grad(&grads).unwrap()),
                host(b.grad(&grads).unwrap()),
            ]
        };
        for act in 0..3 {
            let (f, c) = (run(true, act), run(false, act));
            for (what, (a, b)) in ["output", "dx", "dw", "db"].iter().zip(f.iter().zip(&c)) {
                let e = max_err(a, b);
                assert!(e < 1e-4, "{rows}x{n_in}x{n_out} activation {act} {what}: max error {e}");
            }
            if act == 2 {
                // The mask dropped about 30% of the outputs, in both.
                let zeros = f[0].iter().filter(|v| **v == 0.0).count() as f64 / f[0].len() as f64;
                assert!((zeros - 0.3).abs() < 0.05, "{zeros}");
                assert!(f[0].iter().zip(&c[0]).all(|(a, b)| (*a == 0.0) == (*b == 0.0)));
            }
        }
    }
}

/// LayerNorm(h + dropout(a)) in one op against Burn's LayerNorm of the composed sum, with the
/// same dropout mask (the stream restarted from one seed for both), gradients of h, a, gamma, beta.
#[test]
fn fused_residual_layer_norm_matches_burn_with_dropout_and_gradients() {
    let ad = Device::flex().autodiff();
    let mut ln = LayerNormConfig::new(24).init(&ad);
    ln.gamma = ln.gamma.map(|g| g.random_like(Distribution::Normal(1.0, 0.5)).require_grad());
    let h0 = random([4, 33, 24], &ad);
    let a0 = random([4, 33, 24], &ad);
    let w = random([4, 33, 24], &ad);
    for prob in [0.0, 0.3] {
        let drop = diffkfc_model::network::dropout::Dropout::new(prob);
        let run = |fused: bool| {
            diffkfc_model::network::dropout::seed(11);
            let (h, a) = (h0.clone().detach().require_grad(), a0.clone().detach().require_grad());
            let y = if fused {
                kernels::residual_layer_norm(&ln, h.clone(), a.clone(), &drop)
            } else {
                ln.forward(h.clone() + drop.forward(a.clone()))
            };
            let grads = (y.clone() * w.clone()).sum().backward();
            let beta = ln.beta.as_ref().unwrap().val();
            vec![
                host(y),
                host(h.grad(&grads).unwrap()),
                host(a.grad(&grads).unwrap()),
                host(ln.gamma.val().grad(&grads).unwrap()),
                host(beta.grad(&grads).unwrap()),
            ]
        };
        let (f, c) = (run(true), run(false));
        for (what, (x, y)) in ["output", "dh", "da", "dgamma", "dbeta"].iter().zip(f.iter().zip(&c))
        {
            let e = max_err(x, y);
            assert!(e < 2e-5, "p {prob} {what}: max error {e}");
        }
        if prob > 0.0 {
            // Some of a's gradient is dropped, h's never is.
            assert!(f[2].iter().filter(|&&g| g == 0.0).count() > f[2].len() / 10);
        }
    }
}

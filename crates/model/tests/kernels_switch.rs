//! `DIFFKFC_KERNELS=burn` turns the fused kernels off (read once per process, so this test has
//! a binary of its own): attention then gives exactly what the composed ops give.

use burn::prelude::*;
use burn::tensor::Distribution;
use diffkfc_model::kernels::{self, Mask};
use diffkfc_model::network::params::host;

#[test]
fn the_environment_switch_selects_the_composed_ops() {
    let dev = Device::flex();
    let (q, k, v) = (
        Tensor::<3>::random([2, 5, 8], Distribution::Normal(0.0, 1.0), &dev),
        Tensor::<3>::random([2, 6, 8], Distribution::Normal(0.0, 1.0), &dev),
        Tensor::<3>::random([2, 6, 8], Distribution::Normal(0.0, 1.0), &dev),
    );
    let composed =
        host(kernels::attention_composed(q.clone(), k.clone(), v.clone(), 2, &Mask::None));
    std::env::set_var("DIFFKFC_KERNELS", "burn");
    assert!(!kernels::fused(&dev), "DIFFKFC_KERNELS=burn must select the composed ops");
    assert!(!kernels::fused(&dev.clone().autodiff()));
    let out = host(kernels::attention(q, k, v, 2, Mask::None));
    assert_eq!(out, composed);
}

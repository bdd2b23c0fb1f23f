//! A depthwise convolution over the frame axis, added to each decoder layer's self-attention
//! (our extension; `model.temporal_kernel`, 0 = the paper's pure transformer).
//!
//! Why: the tiny models' samples were incoherent frame to frame (each frame settled on its own
//! phase of a gait: toes jumping 30-60 cm between frames), and training longer did not fix it.
//! Attention in a 2-layer, 64-wide network couples neighbouring frames only weakly; a short
//! per-channel filter over time couples them directly, at the cost of K multiply-adds per value.

use std::sync::Arc;

use burn::module::{Initializer, Param};
use burn::prelude::*;

use crate::kernels::{self, ConvArgs};

/// Which frames of a batch are real, [B, N]: as a tensor [B, N, 1] (1 real, 0 padding) for the
/// composed ops and on the host for the fused kernel.
#[derive(Clone, Debug)]
pub struct RealFrames {
    pub tensor: Tensor<3>,
    pub host: Arc<Vec<f32>>,
}

impl RealFrames {
    /// `real` [B * N], true on real frames.
    pub fn new(real: &[bool], b: usize, n: usize, device: &Device) -> RealFrames {
        let host: Vec<f32> = real.iter().map(|&r| if r { 1.0 } else { 0.0 }).collect();
        let tensor = Tensor::<1>::from_floats(host.as_slice(), device).reshape([b, n, 1]);
        RealFrames { tensor, host: Arc::new(host) }
    }
}

#[derive(Module, Debug)]
pub struct TemporalConv {
    /// [K, d] one filter tap per offset -K/2..=K/2 and channel; zero at initialisation, so a new
    /// layer starts as the plain transformer.
    pub(super) weight: Param<Tensor<2>>,
    pub(super) kernel: usize,
}

impl TemporalConv {
    pub fn new(kernel: usize, d: usize, device: &Device) -> Self {
        assert!(kernel % 2 == 1, "temporal kernel must be odd");
        TemporalConv { weight: Initializer::Zeros.init([kernel, d], device), kernel }
    }

    /// The convolution of the frame rows of decoder tokens `h` [B, skip + N, d] (padding frames
    /// read as 0) -> [B, skip + N, d], 0 on the first `skip` rows: one fused op on flex, Burn
    /// ops elsewhere ([`TemporalConv::forward_composed`]).
    pub fn forward_tokens(&self, h: Tensor<3>, real: &RealFrames, skip: usize) -> Tensor<3> {
        if kernels::fused(&h.device()) {
            let args = ConvArgs { skip, real: real.host.clone() };
            return kernels::temporal_conv(h, self.weight.val(), args);
        }
        self.forward_composed(h, real, skip)
    }

    /// [`TemporalConv::forward_tokens`] from Burn tensor ops (any backend; the kernel's reference).
    pub fn forward_composed(&self, h: Tensor<3>, real: &RealFrames, skip: usize) -> Tensor<3> {
        let [b, m, d] = h.dims();
        let frames = h.clone().slice([0..b, skip..m, 0..d]) * real.tensor.clone();
        let zeros = Tensor::<3>::zeros([b, skip, d], &h.device());
        Tensor::cat(vec![zeros, self.forward(frames)], 1)
    }

    /// `frames` [B, N, d] (padding frames already zeroed) -> [B, N, d]: y[t] = sum_k w[k] x[t + k - K/2],
    /// zero outside the sequence.
    pub fn forward(&self, frames: Tensor<3>) -> Tensor<3> {
        let [b, n, d] = frames.dims();
        let half = self.kernel / 2;
        let w = self.weight.val();
        let mut out: Option<Tensor<3>> = None;
        for k in 0..self.kernel {
            let tap = w.clone().slice([k..k + 1, 0..d]).reshape([1, 1, d]);
            let shifted = shift(frames.clone(), k as isize - half as isize, b, n, d);
            let Some(shifted) = shifted else { continue };
            let term = shifted * tap;
            out = Some(match out {
                Some(o) => o + term,
                None => term,
            });
        }
        out.unwrap_or_else(|| frames.zeros_like())
    }
}

/// x[t + o] along the frame axis with zeros past either end; None when nothing is left.
fn shift(x: Tensor<3>, o: isize, b: usize, n: usize, d: usize) -> Option<Tensor<3>> {
    let s = o.unsigned_abs();
    if s >= n {
        return None;
    }
    if s == 0 {
        return Some(x);
    }
    let zeros = Tensor::<3>::zeros([b, s, d], &x.device());
    Some(if o > 0 {
        Tensor::cat(vec![x.slice([0..b, s..n, 0..d]), zeros], 1)
    } else {
        Tensor::cat(vec![zeros, x.slice([0..b, 0..n - s, 0..d])], 1)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::params;

    #[test]
    fn filters_each_channel_over_time_with_zero_padding() {
        let device = Device::flex();
        let conv = TemporalConv::new(3, 2, &device);
        // Zero-initialised: the layer adds nothing until trained.
        let x = Tensor::<1>::from_floats(
            [1.0, 10.0, 2.0, 20.0, 3.0, 30.0, 4.0, 40.0].as_slice(),
            &device,
        )
        .reshape([1, 4, 2]);
        assert!(params::host(conv.forward(x.clone())).iter().all(|&v| v == 0.0));
        // Taps (previous, current, next) = (1, 0, -1) on channel 0 and (0, 2, 0) on channel 1.
        let w = Tensor::<1>::from_floats([1.0, 0.0, 0.0, 2.0, -1.0, 0.0].as_slice(), &device)
            .reshape([3, 2]);
        let conv = TemporalConv { weight: Param::from_tensor(w), kernel: 3 };
        let y = params::host(conv.forward(x));
        // Channel 0: x[t-1] - x[t+1] = 0-2, 1-3, 2-4, 3-0; channel 1: 2 x[t].
        assert_eq!(y, vec![-2.0, 20.0, -2.0, 40.0, -2.0, 60.0, 3.0, 80.0]);
    }

    /// The fused kernel against the composed ops: output and the gradients of h and the taps,
    /// with padding frames (a shorter second sample), tokens before the frames, and a sequence
    /// shorter than the kernel's reach.
    #[test]
    fn fused_kernel_matches_composed_ops_with_gradients() {
        use burn::tensor::Distribution;
        let device = Device::flex().autodiff();
        for (b, skip, n, d, k) in [(3, 2, 11, 8, 5), (2, 2, 3, 4, 9), (1, 0, 6, 3, 3)] {
            let real: Vec<bool> = (0..b * n).map(|i| i % n < n - (i / n) * 2).collect();
            let real = RealFrames::new(&real, b, n, &device);
            let h0 = Tensor::<3>::random([b, skip + n, d], Distribution::Normal(0.0, 1.0), &device);
            let w0 = Tensor::<2>::random([k, d], Distribution::Normal(0.0, 1.0), &device);
            let r = Tensor::<3>::random([b, skip + n, d], Distribution::Normal(0.0, 1.0), &device);
            let run = |fused: bool| {
                let h = h0.clone().detach().require_grad();
                let w = w0.clone().detach().require_grad();
                let conv = TemporalConv { weight: Param::from_tensor(w.clone()), kernel: k };
                let y = if fused {
                    conv.forward_tokens(h.clone(), &real, skip)
                } else {
                    conv.forward_composed(h.clone(), &real, skip)
                };
                let grads = (y.clone() * r.clone()).sum().backward();
                let hg = h.grad(&grads).expect("h's gradient");
                let wg = w.grad(&grads).expect("the taps' gradient");
                [params::host(y), params::host(hg), params::host(wg)]
            };
            let (fused, composed) = (run(true), run(false));
            for (what, a, e) in [("y", 0, 1e-6), ("dh", 1, 1e-6), ("dw", 2, 1e-5)] {
                let worst = fused[a]
                    .iter()
                    .zip(&composed[a])
                    .map(|(x, y)| (x - y).abs())
                    .fold(0f32, f32::max);
                assert!(worst < e, "b {b} n {n} k {k}: {what} differs by {worst}");
            }
        }
    }
}

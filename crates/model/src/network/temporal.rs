//! A depthwise convolution over the frame axis, added to each decoder layer's self-attention
//! (our extension; `model.temporal_kernel`, 0 = the paper's pure transformer).
//!
//! Why: the tiny models' samples were incoherent frame to frame (each frame settled on its own
//! phase of a gait: toes jumping 30-60 cm between frames), and training longer did not fix it.
//! Attention in a 2-layer, 64-wide network couples neighbouring frames only weakly; a short
//! per-channel filter over time couples them directly, at the cost of K multiply-adds per value.

use burn::module::{Initializer, Param};
use burn::prelude::*;

#[derive(Module, Debug)]
pub struct TemporalConv {
    /// [K, d] one filter tap per offset -K/2..=K/2 and channel; zero at initialisation, so a new
    /// layer starts as the plain transformer.
    weight: Param<Tensor<2>>,
    kernel: usize,
}

impl TemporalConv {
    pub fn new(kernel: usize, d: usize, device: &Device) -> Self {
        assert!(kernel % 2 == 1, "temporal kernel must be odd");
        TemporalConv { weight: Initializer::Zeros.init([kernel, d], device), kernel }
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
}

//! Dropout whose mask comes from a counter-based hash (`Rng::hash`, SplitMix64, of the seed,
//! the call number and the element index), made on the host in parallel with the 1 / keep scale
//! folded in: Burn's dropout draws every element through ChaCha and a generic sampler and
//! multiplies twice, about 5% of a paper training step. Active only on an autodiff device
//! (training), as Burn's. `seed` (the trainer calls it every step) makes the masks reproducible,
//! so resumed runs repeat the same masks. The stream is per thread: data-parallel replicas run
//! on their own threads, each on a shard of the batch (`seed_shard`).

use std::cell::Cell;

use crate::kernels::host::par_built;
use burn::prelude::*;
use diffkfc_data::rng::Rng;

/// This thread's stream: seed, calls so far, and the shard (first sample, samples).
#[derive(Clone, Copy)]
struct Stream {
    seed: u64,
    calls: u64,
    first: usize,
    samples: usize,
}

thread_local! {
    static STREAM: Cell<Stream> = const { Cell::new(Stream { seed: 0, calls: 0, first: 0, samples: 0 }) };
}

/// Restart this thread's mask stream on a whole batch.
pub fn seed(seed: u64) {
    seed_shard(seed, 0, 0);
}

/// Restart this thread's mask stream for a shard of a batch: `samples` samples from sample
/// `first`. Every tensor dropout sees has the sample as its outermost dimension, so an element's
/// index in the whole batch is its index in the shard plus `first` times the shard's elements
/// per sample, and the shard draws exactly the whole batch's mask for its samples.
pub fn seed_shard(seed: u64, first: usize, samples: usize) {
    STREAM.set(Stream { seed, calls: 0, first, samples });
}

/// The mask of `n` elements: 1 / keep where kept, 0 where dropped; element `i` is hashed as
/// `offset + i`.
fn mask(n: usize, prob: f64, key: u64, offset: usize) -> Vec<f32> {
    let keep = 1.0 - prob;
    let threshold = (keep * u64::MAX as f64) as u64;
    let scale = (1.0 / keep) as f32;
    let (m, _) = par_built(n, 1 << 16, |c, chunk| {
        for (i, v) in chunk.iter_mut().enumerate() {
            let h = Rng::hash(key ^ (offset + (c << 16) + i) as u64);
            *v = if h < threshold { scale } else { 0.0 };
        }
    });
    m
}

#[derive(Module, Debug)]
pub struct Dropout {
    pub prob: f64,
}

impl Dropout {
    pub fn new(prob: f64) -> Self {
        Dropout { prob }
    }

    pub fn forward<const D: usize>(&self, x: Tensor<D>) -> Tensor<D> {
        match self.host_mask(&x) {
            Some(m) => {
                x.clone() * Tensor::<D>::from_data(TensorData::new(m, x.shape()), &x.device())
            }
            None => x,
        }
    }

    /// The mask `forward` would apply to `x` (None: dropout is off), for kernels that apply it
    /// themselves; it takes the next mask of the stream, as `forward` does.
    pub fn host_mask<const D: usize>(&self, x: &Tensor<D>) -> Option<Vec<f32>> {
        self.host_mask_of(x.shape().num_elements(), &x.device())
    }

    /// [`Dropout::host_mask`] for a tensor of `n` elements on `device` that is not built yet
    /// (a fused op's output).
    pub fn host_mask_of(&self, n: usize, device: &Device) -> Option<Vec<f32>> {
        if self.prob <= 0.0 || !device.is_autodiff() {
            return None;
        }
        let s = STREAM.get();
        STREAM.set(Stream { calls: s.calls + 1, ..s });
        let key = Rng::hash(s.seed ^ Rng::hash(s.calls.wrapping_add(1)));
        let offset = n.checked_div(s.samples).map_or(0, |per| s.first * per);
        Some(mask(n, self.prob, key, offset))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_keeps_the_right_share_with_the_right_scale() {
        let m = mask(200_000, 0.1, 7, 0);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.9).abs() < 0.005, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.9).abs() < 1e-6));
        // Expectation preserved; same key, same mask; another key, another mask.
        let mean = m.iter().map(|&v| v as f64).sum::<f64>() / m.len() as f64;
        assert!((mean - 1.0).abs() < 0.01, "{mean}");
        assert_eq!(m, mask(200_000, 0.1, 7, 0));
        assert_ne!(m, mask(200_000, 0.1, 8, 0));
    }

    #[test]
    fn a_shard_draws_the_whole_batch_mask_for_its_samples() {
        let dev = Device::flex().autodiff();
        let x = |b: usize| Tensor::<3>::zeros([b, 3, 50], &dev);
        let d = Dropout::new(0.3);
        seed(11);
        let whole = [d.host_mask(&x(4)).unwrap(), d.host_mask(&x(4)).unwrap()];
        let per = 3 * 50;
        for (first, samples) in [(0, 2), (2, 2), (1, 3)] {
            seed_shard(11, first, samples);
            for w in &whole {
                let m = d.host_mask(&x(samples)).unwrap();
                assert_eq!(m, w[first * per..(first + samples) * per]);
            }
        }
    }

    #[test]
    fn identity_off_autodiff_or_at_zero() {
        let x = Tensor::<1>::from_floats([1.0, 2.0, 3.0].as_slice(), &Device::flex());
        assert_eq!(
            crate::network::params::host(Dropout::new(0.5).forward(x.clone())),
            vec![1.0, 2.0, 3.0]
        );
        let ad = Tensor::<1>::from_floats([1.0, 2.0, 3.0].as_slice(), &Device::flex().autodiff());
        assert_eq!(
            crate::network::params::host(Dropout::new(0.0).forward(ad.clone())),
            vec![1.0, 2.0, 3.0]
        );
        let y = crate::network::params::host(Dropout::new(0.5).forward(ad));
        assert!(y
            .iter()
            .zip([1.0, 2.0, 3.0])
            .all(|(a, b)| *a == 0.0 || (*a - 2.0 * b).abs() < 1e-6));
    }
}

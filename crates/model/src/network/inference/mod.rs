//! The denoiser for sampling, on host buffers: what [`Denoiser::encode`] and
//! [`Denoiser::decode`] compute, without Burn's dispatch, the condition encoded once per sample,
//! the weights read in place and the activations in buffers reused across the denoising steps.
//!
//! Why: a sampling call of the small networks is ~1 GFLOP in ~45 ops; through the tensor API
//! each op is a pool round trip and a new buffer, and a narrow layer's product (128 x 128) ran
//! on one thread. Here each thread takes a block of token rows and chains the row-wise ops on it
//! (products, residual, LayerNorm, GELU, the temporal convolution); only the attention cores,
//! which read whole sequences, are separate parallel steps: three row regions per layer, each
//! ending with the next one's first products.
//! Every value is computed by the same kernels in the same order as the tensor path: the
//! outputs are the same bits (tested), and so are the samples.

mod encoder;
mod par;
mod pass;
mod weights;

use burn::prelude::*;
use rayon::prelude::*;

use crate::network::condition::Condition;
use crate::network::denoiser::{Denoiser, Encoded};
use crate::network::sinusoidal::sinusoid_table;
use encoder::Encoding;
use par::{at, par_rows, RowsMut};
use pass::{Buffers, Inputs, Pass, RunMasks};
use weights::{HostLayer, HostLinear};

/// Whether the host decoder serves sampling on `device`: flex without autodiff (where the
/// tensor path runs the same kernels), unless `DIFFKFC_DECODER=tensor` asks for the tensor path
/// (A/B runs) or `DIFFKFC_KERNELS=burn` for the composed ops.
pub fn serves(device: &Device) -> bool {
    static TENSOR: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let tensor =
        *TENSOR.get_or_init(|| std::env::var("DIFFKFC_DECODER").is_ok_and(|v| v == "tensor"));
    !tensor && !device.is_autodiff() && crate::kernels::fused(device)
}

/// The activations of one call, [B * (2 + N), width] each, reused across calls.
struct Workspace {
    h: Vec<f32>,
    h2: Vec<f32>,
    q: Vec<f32>,
    k: Vec<f32>,
    v: Vec<f32>,
    tmp: Vec<f32>,
    ff: Vec<f32>,
    /// x_t . W_in + b [b, N, d] (once for the branches that share x_t) and the output [B, N, D].
    frames: Vec<f32>,
    out: Vec<f32>,
}

/// A sample's decoder on the host: the weights and one condition's encoding.
pub struct DecoderPlan {
    /// The timestep MLP's two layers.
    time: [HostLinear; 2],
    x_in: HostLinear,
    out: HostLinear,
    layers: Vec<HostLayer>,
    heads: usize,
    enc: Encoding,
    /// The runs of samples the passes take, with their masks.
    runs: Vec<RunMasks>,
    ws: Workspace,
}

impl DecoderPlan {
    /// The decoder of `model` for the condition `c` (B samples, N frames), encoded here.
    pub fn new(model: &Denoiser, c: &Condition) -> DecoderPlan {
        rayon::scope(|_| DecoderPlan::with(model, Encoding::new(model, c)))
    }

    /// The decoder of `model` for a condition the tensor path encoded.
    pub fn of_encoded(model: &Denoiser, e: &Encoded) -> DecoderPlan {
        DecoderPlan::with(model, Encoding::of_encoded(e))
    }

    fn with(model: &Denoiser, enc: Encoding) -> DecoderPlan {
        let (b, n, d) = (enc.batch, enc.n, enc.d);
        let layers: Vec<HostLayer> = model.layers.iter().map(HostLayer::new).collect();
        let ffn = layers.first().map_or(d, |l| l.ff1.width());
        let rows = b * (n + 2);
        let zeros = |k: usize| vec![0f32; k];
        let out = HostLinear::new(&model.out);
        let ws = Workspace {
            h: zeros(rows * d),
            h2: zeros(rows * d),
            q: zeros(rows * d),
            k: zeros(rows * d),
            v: zeros(rows * d),
            tmp: zeros(rows * d),
            ff: zeros(rows * ffn),
            frames: Vec::new(),
            out: zeros(b * n * out.width()),
        };
        DecoderPlan {
            time: [&model.time.fc1, &model.time.fc2].map(HostLinear::new),
            x_in: HostLinear::new(&model.x_in),
            out,
            heads: model.layers.first().map_or(1, |l| l.self_attn.heads),
            layers,
            runs: runs(&enc),
            enc,
            ws,
        }
    }

    /// x0 [B, N, D] predicted from x_t [b, N, D] at timestep `t`, where B is a multiple of b:
    /// sample s reads x_t's sample s mod b (guidance branches share x_t, stacked branch after
    /// branch). The same values as `Denoiser::decode` of x_t repeated B / b times.
    pub fn decode(&mut self, x_t: &[f32], t: usize) -> &[f32] {
        self.decode_each(x_t, &vec![t; self.enc.batch])
    }

    /// As [`DecoderPlan::decode`], sample s at timestep `t[s]` (B of them).
    pub fn decode_each(&mut self, x_t: &[f32], t: &[usize]) -> &[f32] {
        assert_eq!(t.len(), self.enc.batch, "one timestep per sample");
        let time = self.time_embedding(t);
        // On a pool thread: each parallel region is then a cheap join, not a hand-over from a
        // thread outside the pool (a futex wake and wait each).
        rayon::scope(|_| {
            self.frames(x_t);
            self.layers(&time);
        });
        &self.ws.out
    }

    /// y_t [B, d]: `TimestepEmbed::forward` (sinusoid, Linear, SiLU, Linear) of each sample's
    /// timestep, as the tensor path batches them (`gemm` rounds a single row differently).
    fn time_embedding(&self, t: &[usize]) -> Vec<f32> {
        let [fc1, fc2] = &self.time;
        let t: Vec<f32> = t.iter().map(|&t| t as f32).collect();
        let table = sinusoid_table(&t, self.enc.d);
        let mut h = fc1.applied(&table);
        h.iter_mut().for_each(|v| *v *= sigmoid(*v));
        fc2.applied(&h)
    }

    /// x_t . W_in + b [b, N, d] into `frames`, once for the samples that share x_t.
    fn frames(&mut self, x_t: &[f32]) {
        let (n, d) = (self.enc.n, self.enc.d);
        let dim = self.x_in.w.len() / d;
        let xb = x_t.len() / (n * dim);
        assert!(
            xb > 0 && self.enc.batch.is_multiple_of(xb),
            "x_t [b, N, D] with b dividing the batch"
        );
        self.ws.frames.resize(xb * n * d, 0.0);
        let frames = RowsMut::of(&mut self.ws.frames, d);
        let x_in = &self.x_in;
        // SAFETY: each task writes its own rows.
        par_rows(xb * n, |r| x_in.apply(at(x_t, &r, dim), unsafe { frames.get(&r) }));
    }

    /// The layers over every sample: one pass per run of `self.runs`, on a thread each where
    /// there are several, else one pass whose regions split over the threads.
    fn layers(&mut self, time: &[f32]) {
        let d = self.enc.d;
        let (ffn, width) = (self.layers.first().map_or(d, |l| l.ff1.width()), self.out.width());
        if self.runs.len() != run_count(self.enc.batch) {
            self.runs = runs(&self.enc);
        }
        let ws = &mut self.ws;
        let bufs = Buffers {
            h: RowsMut::of(&mut ws.h, d),
            h2: RowsMut::of(&mut ws.h2, d),
            q: RowsMut::of(&mut ws.q, d),
            k: RowsMut::of(&mut ws.k, d),
            v: RowsMut::of(&mut ws.v, d),
            tmp: RowsMut::of(&mut ws.tmp, d),
            ff: RowsMut::of(&mut ws.ff, ffn),
            out: RowsMut::of(&mut ws.out, width),
        };
        let inputs = Inputs {
            layers: &self.layers,
            out: &self.out,
            heads: self.heads,
            enc: &self.enc,
            time,
            frames: &ws.frames,
        };
        match self.runs.as_slice() {
            [all] => Pass::new(&inputs, all, bufs, false).run(),
            runs => runs.par_iter().for_each(|m| Pass::new(&inputs, m, bufs, true).run()),
        }
    }
}

/// The runs of samples a call's passes take: one per thread where the batch splits evenly over
/// the threads (the blocks `par_rows` gives them), else one of all samples.
fn runs(enc: &Encoding) -> Vec<RunMasks> {
    let per = enc.batch / run_count(enc.batch);
    (0..enc.batch / per).map(|k| RunMasks::new(enc, k * per..(k + 1) * per)).collect()
}

/// How many runs a batch of `b` samples splits into on this pool: its thread count where it
/// divides the batch, else 1.
fn run_count(b: usize) -> usize {
    let threads = rayon::current_num_threads();
    if threads > 1 && b >= threads && b.is_multiple_of(threads) {
        threads
    } else {
        1
    }
}

/// The logistic function as flex computes it (Burn's SiLU is x times it), in both branches.
fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::config::DiffKfcConfig;
    use crate::network::params;
    use crate::sampling::sampler::Request;
    use burn::tensor::Distribution;

    /// A network with every optional part (temporal convolution, key input, word states), its
    /// zero-started branches (taps, key input, word outputs) moved off zero.
    fn network(dev: &Device) -> (DiffKfcConfig, Denoiser) {
        let mut cfg = DiffKfcConfig::new();
        cfg.d_model = 32;
        cfg.heads = 2;
        cfg.ffn = 64;
        cfg.dec_layers = 2;
        cfg.dma_sizes = vec![2, 4, 0];
        cfg.temporal_kernel = 5;
        cfg.key_input = true;
        cfg.text_dim = 16;
        cfg.text_words = 4;
        let model = cfg.init(dev);
        let vals: Vec<Vec<f32>> = params::values(&model)
            .into_iter()
            .enumerate()
            .map(|(k, (_, v))| {
                let wobble = |i: usize| ((i * 31 + k * 17) % 13) as f32 / 60.0 - 0.1;
                v.iter().enumerate().map(|(i, x)| x + wobble(i)).collect()
            })
            .collect();
        (cfg, params::load(model, &vals))
    }

    /// Two samples (the second with padding frames and its last word slots empty), each keyed on
    /// its `keyed` frames: sparse keys gather the DMA blocks' rows, dense ones do not, and none
    /// leave the decoder only the text token to attend to.
    fn request(cfg: &DiffKfcConfig, n: usize, keyed: &[usize]) -> Request {
        let (dim, width) = (cfg.feat_dim, cfg.text_dim * (1 + cfg.text_words));
        let mut text: Vec<f32> =
            (0..2 * width).map(|i| ((i * 37 % 11) as f32 - 5.0) / 7.0).collect();
        text[2 * width - 2 * cfg.text_dim..].fill(0.0);
        let mut req = Request::text_only(n, dim, text, width, vec![n, n - 6]);
        for f in keyed.iter().flat_map(|&f| [f, n + f]) {
            req.mask[f * dim..(f + 1) * dim].fill(1.0);
            req.kf[f * dim..(f + 1) * dim]
                .iter_mut()
                .enumerate()
                .for_each(|(j, v)| *v = 0.3 - j as f32 * 1e-3);
            req.root_mask[f * 4..f * 4 + 2].fill(1.0);
            req.root[f * 4..f * 4 + 2].fill(0.5);
        }
        req
    }

    /// The host path against `Denoiser::encode` and `decode` on the tensor path: the decoder
    /// alone on the tensor encoder's output, and the whole path from the condition, with two
    /// samples sharing x_t as guidance branches do. The same kernels on the same rows in the
    /// same order: the same bits. On one, two and three threads: with two, each thread takes
    /// one sample through the layers (`pass.rs`); otherwise the regions split the rows.
    #[test]
    fn matches_the_tensor_path_bit_for_bit() {
        for threads in [2, 1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let dev = Device::flex();
                let (cfg, model) = network(&dev);
                let plan = DecoderPlan::new(&model, &request(&cfg, 9, &[0, 4]).condition(&dev));
                assert_eq!(plan.runs.len(), if threads == 2 { 2 } else { 1 }, "{threads} threads");
                matches_on_this_pool();
            });
        }
    }

    fn matches_on_this_pool() {
        let dev = Device::flex();
        let (cfg, model) = network(&dev);
        let n = 23;
        let dense: Vec<usize> = (0..n).collect();
        for keyed in [&[0, 9, 16][..], &dense[..], &[]] {
            let cond = request(&cfg, n, keyed).condition(&dev);
            let enc = model.encode(&cond);
            let x = Tensor::<3>::random([1, n, cfg.feat_dim], Distribution::Normal(0.0, 1.0), &dev);
            let xs = Tensor::cat(vec![x.clone(), x.clone()], 0);
            let mut plans =
                [DecoderPlan::of_encoded(&model, &enc), DecoderPlan::new(&model, &cond)];
            for t in [[999, 999], [17, 17], [600, 3]] {
                let want = params::host(model.decode(xs.clone(), &t, &enc));
                for (which, plan) in ["decoder", "encoder and decoder"].iter().zip(&mut plans) {
                    let got = plan.decode_each(&params::host(x.clone()), &t);
                    assert_eq!(got.len(), want.len());
                    let worst =
                        got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
                    let keys = keyed.len();
                    assert!(got == want, "{which}, {keys} keys, t {t:?}: off by up to {worst}");
                }
            }
        }
    }
}

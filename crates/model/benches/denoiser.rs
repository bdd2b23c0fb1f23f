//! Criterion benches of the denoiser on the quick start's tiny network (the tiny preset with
//! the temporal convolution of `configs/tiny.json`, so that every fused kernel runs; the
//! paper-size figures and the PyTorch comparison come from `diffkfc bench`, which runs the same
//! workloads): a training step, a guided sampling call with and without the encoder, and a
//! 5-step DDIM sample.
//! Run: cargo bench -p diffkfc-model --bench denoiser   (CI: `-- --test`, each case once)

use burn::prelude::*;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use diffkfc_model::bench::{Sampling, TrainStep};
use diffkfc_model::DiffKfcConfig;

const FRAMES: usize = 60;

fn denoiser(c: &mut Criterion) {
    let cfg = DiffKfcConfig::tiny().with_temporal_kernel(9);
    let device = Device::flex();
    let mut g = c.benchmark_group("tiny");
    g.sample_size(10);
    let mut train = TrainStep::new(&cfg, 8, FRAMES, &device);
    // Throughput in "elements" = FLOPs, so criterion reports FLOP/s.
    g.throughput(Throughput::Elements(train.flops(&cfg) as u64));
    g.bench_function("train_step_b8", |b| b.iter(|| train.step()));
    let model = cfg.init(&device);
    let s = Sampling::new(&model, &cfg, 1, FRAMES);
    let f = s.flops(&cfg);
    g.throughput(Throughput::Elements(f.total() as u64));
    g.bench_function("sampling_call", |b| b.iter(|| s.call(true)));
    g.throughput(Throughput::Elements(f.decoder as u64));
    g.bench_function("sampling_call_cached", |b| b.iter(|| s.call(false)));
    g.throughput(Throughput::Elements((f.encoder + 5.0 * f.decoder) as u64));
    g.bench_function("ddim5", |b| b.iter(|| s.sample(5)));
    g.finish();
}

criterion_group!(benches, denoiser);
criterion_main!(benches);

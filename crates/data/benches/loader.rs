//! Criterion bench of batch assembly from the packed cache (crop, normalise, keyframe masks,
//! pad) on a generated 200-clip set; `diffkfc bench --cases loader --data DIR` runs the same
//! on any dataset. Run: cargo bench -p diffkfc-data --bench loader
//! (CI: `-- --test`, each case once).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use diffkfc_data::dataset::batch::{KeyframeConfig, Loader};
use diffkfc_data::dataset::cache::{default_cache_dir, PackedSplit};
use diffkfc_data::dataset::Dataset;

fn loader(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("diffkfc-loader-bench-{}", std::process::id()));
    diffkfc_synth::write_dataset(&dir, &diffkfc_synth::SynthSpec::legacy(200, 0), 2, &|_, _| {})
        .expect("synthetic set");
    let ds = Dataset::open(&dir).expect("dataset");
    let split = PackedSplit::open(&ds, "train", &default_cache_dir(&ds), |_, _| {}).expect("cache");
    let mut g = c.benchmark_group("loader");
    g.throughput(Throughput::Elements(64));
    for threads in [1, 2] {
        let mut l = Loader::new(&ds, &split, 64, 0, KeyframeConfig::default());
        l.threads = threads;
        let per_epoch = l.batches_per_epoch().max(1);
        let mut k = 0usize;
        g.bench_function(format!("batch64_threads{threads}"), |b| {
            b.iter(|| {
                k += 1;
                l.batch((k / per_epoch) as u64, k % per_epoch)
            })
        });
    }
    g.finish();
    drop(split);
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, loader);
criterion_main!(benches);

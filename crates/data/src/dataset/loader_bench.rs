//! Data-loading throughput: the packed cache opened (built if absent) and batches drawn as
//! training draws them, with resident memory (`diffkfc data bench-loader`, a case of
//! `diffkfc bench`).

use std::path::Path;

use crate::dataset::batch::{KeyframeConfig, Loader};
use crate::dataset::cache::{default_cache_dir, PackedSplit};
use crate::dataset::Dataset;
use crate::DataError;

/// Resident memory of this process in MiB (Linux): (total, anonymous). Memory-mapped cache
/// pages count in the total but are clean file pages the kernel can drop; the anonymous part is
/// what the process itself holds.
pub fn rss_mib() -> (f64, f64) {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| -> f64 {
        s.lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
            / 1024.0
    };
    (field("VmRSS:"), field("RssAnon:"))
}

/// `batches` batches of `batch_size` from `split` of the dataset at `dir` with `threads` loader
/// threads: one JSON line of timings, memory and a checksum.
pub fn run(
    dir: &Path,
    split_name: &str,
    batches: usize,
    batch_size: usize,
    threads: usize,
    progress: impl FnMut(usize, usize),
) -> Result<serde_json::Value, DataError> {
    let ds = Dataset::open(dir)?;
    let rss0 = rss_mib();
    let t0 = std::time::Instant::now();
    let split = PackedSplit::open(&ds, split_name, &default_cache_dir(&ds), progress)?;
    let open_s = t0.elapsed().as_secs_f64();
    if split.items.is_empty() {
        return Err(DataError::Invalid(format!(
            "{}: split '{split_name}' has no usable items",
            dir.display()
        )));
    }
    let mut loader = Loader::new(&ds, &split, batch_size, 0, KeyframeConfig::default());
    loader.threads = threads;
    let per_epoch = loader.batches_per_epoch();
    let t1 = std::time::Instant::now();
    let (mut peak, mut peak_anon) = rss0;
    let mut checksum = 0.0f64;
    for b in 0..batches {
        let batch = loader.batch((b / per_epoch) as u64, b % per_epoch);
        checksum += batch.x0[0] as f64;
        if b % 10 == 0 {
            let (r, an) = rss_mib();
            peak = peak.max(r);
            peak_anon = peak_anon.max(an);
        }
    }
    let secs = t1.elapsed().as_secs_f64();
    Ok(serde_json::json!({
        "case": "loader",
        "split": split_name,
        "frames_in_split": split.total_frames(),
        "cache_bytes": split.total_frames() * ds.dim() * 4,
        "cache_built": split.built,
        "open_s": open_s,
        "batches": batches,
        "batch_size": batch_size,
        "threads": threads,
        "items_per_s": (batches * batch_size) as f64 / secs,
        "ms_per_batch": secs * 1000.0 / batches as f64,
        "rss_mib_before": rss0.0,
        "rss_mib_peak": peak,
        "rss_anon_mib_before": rss0.1,
        "rss_anon_mib_peak": peak_anon,
        "checksum": checksum,
    }))
}

//! How much memory a training run will take, estimated before it starts, so that a batch too
//! large for the memory the process may use is refused instead of killed by the kernel; and
//! how much a GPU device holds while it runs (`device_memory`).
//!
//! Calibrated on the flex backend (peak resident memory over two training steps, 2026-11-23):
//! tiny at batch 8 / 32 / 256: 246 / 246 / 1689 MB; small at batch 16 / 64: 603 / 1966 MB. Per
//! sample and frame the activations kept for the backward pass come to about 5.3 floats per
//! (d_model + ffn) per layer plus 0.6 per attention score per layer, over the decoder layers
//! and the DMA blocks; the fixed part (parameters with their gradient, EMA and Adam moments, the
//! packed dataset and caption cache) adds to that.

use crate::run::config::RunConfig;

/// Resident memory a run outside the network itself needs (binary, caches, buffers).
const BASE_BYTES: f64 = 150e6;

/// Estimated peak resident bytes of a training step of `cfg` on `frames`-frame batches:
/// `fixed_bytes + batch_size * per_sample_bytes`.
pub fn training_bytes(cfg: &RunConfig, frames: usize) -> f64 {
    fixed_bytes(cfg) + cfg.training.batch_size as f64 * per_sample_bytes(cfg, frames)
}

/// Activations one sample of `frames` frames keeps for the backward pass.
pub fn per_sample_bytes(cfg: &RunConfig, frames: usize) -> f64 {
    let m = &cfg.model;
    let layers = (m.dec_layers + m.dma_sizes.len()) as f64;
    let per_token =
        5.3 * (m.d_model + m.ffn) as f64 * layers + 0.6 * (m.heads * frames) as f64 * layers;
    frames as f64 * per_token * 4.0
}

/// The part that does not grow with the batch: weights, gradients, EMA and two Adam moments
/// (five copies of the parameters) and the process itself.
pub fn fixed_bytes(cfg: &RunConfig) -> f64 {
    let m = &cfg.model;
    let layers = (m.dec_layers + m.dma_sizes.len()) as f64;
    let d = m.d_model as f64;
    let params = layers * (4.0 * d * d + 2.0 * d * m.ffn as f64)
        + 2.0 * d * (m.feat_dim + m.text_dim) as f64
        + if m.text_words > 0 {
            m.dec_layers as f64 * 4.0 * d * d + d * m.text_dim as f64
        } else {
            0.0
        };
    BASE_BYTES + 5.0 * params * 4.0
}

/// Memory this process can still take: the least of the system's `MemAvailable`, what its
/// cgroup's limit leaves (v2 `memory.max`, v1 `memory.limit_in_bytes`) and what its address-space
/// and data-size limits (`ulimit -v`, `ulimit -d`) leave; None when none of them can be read.
pub fn available_bytes() -> Option<f64> {
    let read = |p: &str| std::fs::read_to_string(p).ok();
    let status = read("/proc/self/status").unwrap_or_default();
    let limits = read("/proc/self/limits").unwrap_or_default();
    [
        read("/proc/meminfo").and_then(|t| kib_field(&t, "MemAvailable:")),
        cgroup_left(read("/sys/fs/cgroup/memory.max"), read("/sys/fs/cgroup/memory.current")),
        cgroup_left(
            read("/sys/fs/cgroup/memory/memory.limit_in_bytes"),
            read("/sys/fs/cgroup/memory/memory.usage_in_bytes"),
        ),
        rlimit(&limits, "Max address space")
            .map(|l| l - kib_field(&status, "VmSize:").unwrap_or(0.0)),
        rlimit(&limits, "Max data size").map(|l| l - kib_field(&status, "VmData:").unwrap_or(0.0)),
    ]
    .into_iter()
    .flatten()
    .map(|b| b.max(0.0))
    .reduce(f64::min)
}

/// What a GPU device's memory pools hold (CubeCL's report, every stream of the device).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DeviceMemory {
    /// Bytes of live tensors.
    pub in_use: u64,
    /// Bytes the pools hold from the driver. Pools keep their pages until cleaned up, so this
    /// is the high-water mark of the run so far (like PyTorch's max_memory_reserved).
    pub reserved: u64,
}

/// The memory of `device` where Burn runs it through CubeCL (wgpu, cuda); None for the CPU
/// backends (their memory is the process's: `available_bytes`, the run's resident size).
/// It waits for the device's queued work, so read it once per step, not inside one.
pub fn device_memory(device: &burn::prelude::Device) -> Option<DeviceMemory> {
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    if let burn::backend::DispatchDevice::Cube(d) = device.as_dispatch().clone().inner() {
        let u = d.client().memory_report(burn::cubecl::MemoryScope::Device).usage();
        return Some(DeviceMemory { in_use: u.bytes_in_use, reserved: u.bytes_reserved });
    }
    let _ = device;
    None
}

/// A `Name:   123 kB` line of /proc, in bytes.
fn kib_field(text: &str, name: &str) -> Option<f64> {
    let kb: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix(name))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024.0)
}

/// A cgroup's limit less its usage (no limit: None).
fn cgroup_left(limit: Option<String>, usage: Option<String>) -> Option<f64> {
    let limit: f64 = limit?.trim().parse().ok()?;
    let usage: f64 = usage.and_then(|u| u.trim().parse().ok()).unwrap_or(0.0);
    // cgroup v1 reports "no limit" as a huge page-rounded number.
    (limit < 1e18).then_some(limit - usage)
}

/// The soft limit of a /proc/self/limits row, in bytes (unlimited: None).
fn rlimit(limits: &str, name: &str) -> Option<f64> {
    let row = limits.lines().find_map(|l| l.strip_prefix(name))?;
    row.split_whitespace().next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_are_read_from_proc_text() {
        let limits = "Limit                     Soft Limit           Hard Limit           Units\nMax data size             unlimited            unlimited            bytes\nMax address space         8589934592           unlimited            bytes\n";
        assert_eq!(rlimit(limits, "Max address space"), Some(8589934592.0));
        assert_eq!(rlimit(limits, "Max data size"), None);
        assert_eq!(kib_field("VmSize:\t  2048 kB\n", "VmSize:"), Some(2048.0 * 1024.0));
        assert_eq!(cgroup_left(Some("max\n".into()), Some("5".into())), None);
        assert_eq!(cgroup_left(Some("1000\n".into()), Some("400\n".into())), Some(600.0));
    }

    #[test]
    fn estimate_follows_the_measured_runs() {
        // (preset, batch, measured peak MB): the calibration runs.
        for (preset, batch, mb) in
            [("tiny", 8, 246.0), ("tiny", 256, 1689.0), ("small", 16, 603.0), ("small", 64, 1966.0)]
        {
            let mut cfg = RunConfig::parse(&format!(r#"{{"model": "{preset}"}}"#)).unwrap();
            cfg.training.batch_size = batch;
            let est = training_bytes(&cfg, 196) / 1e6;
            assert!(
                (est / mb - 1.0).abs() < 0.3,
                "{preset} batch {batch}: estimate {est:.0} MB vs measured {mb} MB"
            );
        }
    }
}

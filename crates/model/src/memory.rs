//! How much memory a training run will take, estimated before it starts (a batch too large for
//! the machine used to grow until the kernel killed the process).
//!
//! Calibrated on the flex backend (peak resident memory over two training steps, 2026-11-23):
//! tiny at batch 8 / 32 / 256: 246 / 246 / 1689 MB; small at batch 16 / 64: 603 / 1966 MB. Per
//! sample and frame the activations kept for the backward pass come to about 5.3 floats per
//! (d_model + ffn) per layer plus 0.6 per attention score per layer, over the decoder layers
//! and the DMA blocks; the fixed part (parameters with their gradient, EMA and Adam moments, the
//! packed dataset and caption cache) adds to that.

use crate::run_config::RunConfig;

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
        + 2.0 * d * (m.feat_dim + m.text_dim) as f64;
    BASE_BYTES + 5.0 * params * 4.0
}

/// Memory the system can still give (`MemAvailable` of /proc/meminfo), when it can be read.
pub fn available_bytes() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("MemAvailable:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

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

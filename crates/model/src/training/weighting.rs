//! Weights of the reconstruction terms (L_simple and the keyframe term) per sample and feature
//! channel, our options beside the paper's uniform mean:
//! * **root and contact emphasis** (`training.root_loss_weight`, `contact_loss_weight`): 4 root
//!   channels and 4 foot contacts of 263 are easily treated as noise by a small network, yet
//!   they decide whether a motion covers ground and plants its feet (GMD's emphasis projection
//!   and the T2M code's feature bias raise them for the same reason).
//! * **min-SNR** (`training.min_snr_gamma` = gamma): an x0 predictor's error at timestep t
//!   weighted by min(SNR(t), gamma) / gamma (Hang et al. 2023, their x0 form scaled so the
//!   cleanest steps weigh 1), so the nearly hopeless high-noise steps do not dominate.
//!
//! The weights enter as their square roots scaling both the target and the prediction, so the
//! fused masked-MSE kernel computes the weighted means unchanged.

use burn::prelude::*;

use crate::diffusion::Schedule;
use crate::run::config::TrainingConfig;

/// Root channels of a HumanML3D-style feature vector (yaw rate, ground velocity, height).
pub const ROOT_CHANNELS: std::ops::Range<usize> = 0..4;
/// Foot-contact channels: the last four of the feature vector.
pub const CONTACT_CHANNELS: usize = 4;

/// Square roots of the reconstruction weights, [B, 1, D]; None where every weight is 1.
pub fn sqrt_weights(
    cfg: &TrainingConfig,
    schedule: &Schedule,
    t: &[usize],
    d: usize,
    device: &Device,
) -> Option<Tensor<3>> {
    let channels = channel_weights(cfg, d);
    let samples = sample_weights(cfg, schedule, t);
    if channels.is_none() && samples.is_none() {
        return None;
    }
    let channels = channels.unwrap_or_else(|| vec![1.0; d]);
    let samples = samples.unwrap_or_else(|| vec![1.0; t.len()]);
    let w: Vec<f32> =
        samples.iter().flat_map(|s| channels.iter().map(move |c| (s * c).sqrt() as f32)).collect();
    Some(Tensor::<1>::from_floats(w.as_slice(), device).reshape([t.len(), 1, d]))
}

/// Per feature channel: the root and contact emphasis; None when both are 1.
pub fn channel_weights(cfg: &TrainingConfig, d: usize) -> Option<Vec<f64>> {
    if cfg.root_loss_weight == 1.0 && cfg.contact_loss_weight == 1.0 {
        return None;
    }
    let mut w = vec![1.0; d];
    w.iter_mut().take(ROOT_CHANNELS.end).for_each(|v| *v = cfg.root_loss_weight);
    w.iter_mut()
        .skip(d.saturating_sub(CONTACT_CHANNELS))
        .for_each(|v| *v = cfg.contact_loss_weight);
    Some(w)
}

/// Per sample: min(SNR(t), gamma) / gamma; None when min-SNR is off (gamma 0).
pub fn sample_weights(cfg: &TrainingConfig, schedule: &Schedule, t: &[usize]) -> Option<Vec<f64>> {
    let gamma = cfg.min_snr_gamma;
    (gamma > 0.0).then(|| {
        t.iter()
            .map(|&t| {
                let abar = schedule.alphas_cumprod[t];
                let snr = abar / (1.0 - abar).max(1e-12);
                snr.min(gamma) / gamma
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_weigh_nothing() {
        let cfg = TrainingConfig::default();
        let s = Schedule::cosine(1000);
        assert!(sqrt_weights(&cfg, &s, &[0, 500, 999], 263, &Device::flex()).is_none());
    }

    #[test]
    fn root_and_contacts_are_emphasised() {
        let cfg = TrainingConfig {
            root_loss_weight: 4.0,
            contact_loss_weight: 9.0,
            ..Default::default()
        };
        let w = channel_weights(&cfg, 263).unwrap();
        assert_eq!(&w[0..5], &[4.0, 4.0, 4.0, 4.0, 1.0]);
        assert_eq!(&w[258..263], &[1.0, 9.0, 9.0, 9.0, 9.0]);
        let s = Schedule::cosine(1000);
        let sq = sqrt_weights(&cfg, &s, &[3, 900], 263, &Device::flex()).unwrap();
        let v = sq.into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(v.len(), 2 * 263);
        assert_eq!((v[0], v[4], v[262], v[263 + 1]), (2.0, 1.0, 3.0, 2.0));
    }

    #[test]
    fn min_snr_weighs_noisy_steps_down() {
        let cfg = TrainingConfig { min_snr_gamma: 5.0, ..Default::default() };
        let s = Schedule::cosine(1000);
        let w = sample_weights(&cfg, &s, &[0, 100, 500, 999]).unwrap();
        // Clean steps have SNR far above 5: weight 1; t = 500 on the cosine schedule has
        // alpha_bar about 0.49, SNR about 0.97; the last step almost nothing.
        assert_eq!(w[0], 1.0);
        assert_eq!(w[1], 1.0);
        let abar = s.alphas_cumprod[500];
        assert!((w[2] - abar / (1.0 - abar) / 5.0).abs() < 1e-12 && w[2] < 0.25);
        assert!(w[3] < 1e-3);
    }
}

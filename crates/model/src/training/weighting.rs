//! Weights of the reconstruction terms (L_simple and the keyframe term) per feature channel,
//! our option beside the paper's uniform mean: root and contact emphasis
//! (`training.root_loss_weight`, `contact_loss_weight`). 4 root channels and 4 foot contacts
//! of 263 are easily treated as noise by a small network, yet they decide whether a motion
//! covers ground and plants its feet (GMD's emphasis projection and the T2M code's feature
//! bias raise them for the same reason).
//!
//! The weights enter as their square roots scaling both the target and the prediction, so the
//! fused masked-MSE kernel computes the weighted means unchanged.

use burn::prelude::*;

use crate::run::config::TrainingConfig;

/// Root channels of a HumanML3D-style feature vector (yaw rate, ground velocity, height).
pub const ROOT_CHANNELS: std::ops::Range<usize> = 0..4;
/// Foot-contact channels: the last four of the feature vector.
pub const CONTACT_CHANNELS: usize = 4;

/// Square roots of the reconstruction weights, [1, 1, D]; None where every weight is 1.
pub fn sqrt_weights(cfg: &TrainingConfig, d: usize, device: &Device) -> Option<Tensor<3>> {
    let w: Vec<f32> = channel_weights(cfg, d)?.iter().map(|c| c.sqrt() as f32).collect();
    Some(Tensor::<1>::from_floats(w.as_slice(), device).reshape([1, 1, d]))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_weigh_nothing() {
        let cfg = TrainingConfig::default();
        assert!(sqrt_weights(&cfg, 263, &Device::flex()).is_none());
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
        let sq = sqrt_weights(&cfg, 263, &Device::flex()).unwrap();
        let v = sq.into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(v.len(), 263);
        assert_eq!((v[0], v[4], v[262]), (2.0, 1.0, 3.0));
    }
}

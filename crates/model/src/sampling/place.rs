//! Place guidance: inside the reverse loop, each step nudges the root's linear-velocity
//! channels so that the root path integrated from the predicted x0 passes through the keyed
//! places (as transition guidance nudges the windows around keys). The warp after the last
//! step makes the hit exact; this asks the network for a walk that covers the keyed ground
//! itself, so the warp has less to stretch.

use diffkfc_data::motion::quat;
use diffkfc_data::motion::representation::recover_root_rot_pos;
use diffkfc_data::motion::root_key::{ROOT_CHANNELS, ROOT_POS_SCALE};

/// The root channels place guidance moves: 0 yaw rate, 1 and 2 the ground-plane step in the
/// facing frame.
const VELOCITY_CHANNELS: usize = 3;

/// Normalisation (mean, std) of the velocity root channels 0..3 in the dataset's statistics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityStats {
    pub mean: [f32; VELOCITY_CHANNELS],
    pub std: [f32; VELOCITY_CHANNELS],
}

impl VelocityStats {
    /// From a dataset's full Mean/Std vectors.
    pub fn of(mean: &[f32], std: &[f32]) -> VelocityStats {
        let take = |v: &[f32]| [v[0], v[1], v[2]];
        VelocityStats { mean: take(mean), std: take(std) }
    }

    /// The de-normalised velocity root channels of a normalised motion's first `len` frames
    /// as rows of four (the fourth, height, zero), the layout `recover_root_rot_pos` reads
    /// with `dim` 4.
    pub fn raw_rows(&self, x: &[f32], len: usize, dim: usize) -> Vec<f64> {
        let mut raw = vec![0f64; len * 4];
        for f in 0..len {
            for c in 0..VELOCITY_CHANNELS {
                raw[f * 4 + c] = (x[f * dim + c] * self.std[c] + self.mean[c]) as f64;
            }
        }
        raw
    }
}

/// Strength and the de-normalisation of the root channels 0..3 (angular velocity, linear
/// velocity x and z).
#[derive(Clone, Debug)]
pub struct PlaceGuidance {
    pub strength: f64,
    pub velocity: VelocityStats,
}

impl PlaceGuidance {
    /// From a dataset's feature mean and std.
    pub fn new(strength: f64, mean: &[f32], std: &[f32]) -> Self {
        PlaceGuidance { strength, velocity: VelocityStats::of(mean, std) }
    }

    /// Place guidance of `strength` from a dataset's feature mean and std: none at 0.
    pub fn of_strength(strength: f64, mean: &[f32], std: &[f32]) -> Option<Self> {
        (strength > 0.0).then(|| PlaceGuidance::new(strength, mean, std))
    }

    /// Mean over keyed places of the squared distance (m^2) between the root path of one
    /// sample's normalised x0 [N, D] and its keyed places (`root`, `root_mask` [N, 4]), and
    /// the gradient with respect to x0 (only the linear-velocity channels 1 and 2 are nonzero;
    /// the heading is held fixed).
    pub fn loss_and_grad(
        &self,
        x0: &[f32],
        root: &[f32],
        root_mask: &[f32],
        len: usize,
        dim: usize,
    ) -> (f64, Vec<f32>) {
        let mut grad = vec![0f32; x0.len()];
        let r = ROOT_CHANNELS;
        let keys: Vec<usize> = (1..len).filter(|&f| root_mask[f * r] > 0.0).collect();
        if keys.is_empty() {
            return (0.0, grad);
        }
        // The root channels de-normalised; row 3 (height) does not enter the path.
        let feats = self.velocity.raw_rows(x0, len, dim);
        let (q, pos) = recover_root_rot_pos(&feats, 4);
        let k = keys.len() as f64;
        let mut loss = 0.0;
        let mut residual = vec![[0.0f64; 3]; len];
        for &f in &keys {
            let t =
                [ROOT_POS_SCALE * root[f * r] as f64, 0.0, ROOT_POS_SCALE * root[f * r + 1] as f64];
            let e = [pos[f][0] - t[0], 0.0, pos[f][2] - t[2]];
            loss += (e[0] * e[0] + e[2] * e[2]) / k;
            residual[f] = e;
        }
        // pos(f) = sum_{g=1..f} R(q_g)^-1 v(g-1): dL/dv(g-1) = 2/K R(q_g) sum_{f>=g} e(f).
        let mut suffix = [0.0f64; 3];
        for g in (1..len).rev() {
            suffix = quat::add(suffix, residual[g]);
            let d = quat::qrot(q[g], suffix);
            grad[(g - 1) * dim + 1] = (2.0 / k * d[0]) as f32 * self.velocity.std[1];
            grad[(g - 1) * dim + 2] = (2.0 / k * d[2]) as f32 * self.velocity.std[2];
        }
        (loss, grad)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences_and_descends() {
        let (n, d) = (12, 263);
        let mut x0 = vec![0f32; n * d];
        for f in 0..n {
            x0[f * d] = 0.3 * ((f as f32) * 0.7).sin();
            x0[f * d + 1] = 0.2 * ((f as f32) * 0.3).cos();
            x0[f * d + 2] = 0.5 + 0.1 * f as f32;
        }
        let mut root = vec![0f32; n * 4];
        let mut mask = vec![0f32; n * 4];
        for (f, x, z) in [(5usize, 0.1f32, 0.2f32), (11, -0.2, 0.6)] {
            root[f * 4] = x;
            root[f * 4 + 1] = z;
            mask[f * 4] = 1.0;
            mask[f * 4 + 1] = 1.0;
        }
        let pg = PlaceGuidance::new(1.0, &[0.0, 0.0, 0.05], &[0.05, 0.03, 0.04]);
        let (l0, g) = pg.loss_and_grad(&x0, &root, &mask, n, d);
        assert!(l0 > 0.0);
        for (f, c) in [(0usize, 1usize), (3, 2), (7, 1), (10, 2)] {
            let h = 1e-2f32;
            let mut xp = x0.clone();
            xp[f * d + c] += h;
            let mut xm = x0.clone();
            xm[f * d + c] -= h;
            let num = (pg.loss_and_grad(&xp, &root, &mask, n, d).0
                - pg.loss_and_grad(&xm, &root, &mask, n, d).0)
                / (2.0 * h as f64);
            assert!(
                (num - g[f * d + c] as f64).abs() < 1e-3 * (1.0 + num.abs()),
                "frame {f} channel {c}: {num} vs {}",
                g[f * d + c]
            );
        }
        // A small step against the gradient lowers the loss; only channels 1 and 2 move.
        let step: Vec<f32> = x0.iter().zip(&g).map(|(x, g)| x - 0.5 * g).collect();
        assert!(pg.loss_and_grad(&step, &root, &mask, n, d).0 < l0);
        assert!(g.iter().enumerate().all(|(i, v)| *v == 0.0 || matches!(i % d, 1 | 2)));
    }
}

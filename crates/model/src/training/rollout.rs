//! Training on the sampler's own step (`training.rollout_prob`). A sampler builds each x_t from
//! the network's previous x0 estimate, a blur of the motions the condition allows (for an
//! ambiguous caption, a walk half way to a stand), whereas training noises the true motion; a
//! network that trusts x_t then drifts towards the blur from step to step (measured on the
//! quick start's walk: 0.59 m/s after one DDIM step, 0.32 after five, the source 0.84). For a
//! share of the samples x_t is instead one DDIM step, made with the network itself (detached),
//! from the true motion noised at t + gap: the network learns to correct its own estimate from
//! the condition rather than copy it. The target stays the true x0. This is one step of the
//! trajectory, as in the scheduled-sampling remedies of exposure bias in diffusion models.

use burn::prelude::*;
use diffkfc_data::rng::Rng;

use crate::diffusion::{per_sample, Schedule};
use crate::network::condition::Condition;
use crate::Denoiser;

/// Which samples take the rolled-out x_t: a hash of the training seed, the sample's timestep
/// and its first noise value, so the choice follows from the step's draws alone (the same on
/// resume and in every data-parallel shard) and leaves the other draws unchanged.
pub fn chosen(seed: u64, prob: f64, t: &[usize], noise: &[f32]) -> Vec<bool> {
    let per = noise.len() / t.len().max(1);
    let threshold = (prob.clamp(0.0, 1.0) * u64::MAX as f64) as u64;
    t.iter()
        .enumerate()
        .map(|(i, &ti)| {
            let bits = u64::from(noise[i * per].to_bits());
            Rng::hash(seed ^ 0x5EED_0F5A_4D10 ^ (bits << 20) ^ ti as u64) < threshold
        })
        .collect()
}

/// Which samples of a batch roll out, at which timesteps, and how far back.
pub struct Step<'a> {
    /// Each sample's timestep.
    pub t: &'a [usize],
    pub rolled: &'a [bool],
    /// Timesteps between the noisier x and x_t (`training.rollout_gap`).
    pub gap: usize,
}

/// x_t of every sample, rolled-out ones replaced by a DDIM step from t + gap (capped at the
/// schedule's last step) of x0 noised with the same `noise`, through `model`'s own x0 estimate.
/// `x0`, `noise`, `x_t` [B, N, D] -> [B, N, D].
pub fn rolled_x_t(
    model: &Denoiser,
    schedule: &Schedule,
    cond: &Condition,
    x0: Tensor<3>,
    noise: Tensor<3>,
    x_t: Tensor<3>,
    step: Step,
) -> Tensor<3> {
    if !step.rolled.iter().any(|&r| r) {
        return x_t;
    }
    let last = schedule.alphas_cumprod.len() - 1;
    let hi: Vec<usize> = (step.t.iter().zip(step.rolled))
        .map(|(&t, &r)| if r { (t + step.gap).min(last) } else { t })
        .collect();
    let device = x0.device();
    let x_hi = schedule.q_sample(x0, &hi, noise);
    let est = model.forward(x_hi.clone(), &hi, cond).detach();
    let [c_est, c_hi, keep] = coefficients(schedule, step.t, &hi);
    est * per_sample(&c_est, &device)
        + x_hi.detach() * per_sample(&c_hi, &device)
        + x_t * per_sample(&keep, &device)
}

/// Per sample, the weights of the estimate, of x at `hi` and of the plain x_t in the new x_t:
/// DDIM's x_t = sqrt(ab_t) est + sqrt(1 - ab_t) eps with eps = (x_hi - sqrt(ab_hi) est) /
/// sqrt(1 - ab_hi); a sample with `hi` = t keeps its x_t.
fn coefficients(schedule: &Schedule, t: &[usize], hi: &[usize]) -> [Vec<f32>; 3] {
    let mut c = [Vec::new(), Vec::new(), Vec::new()];
    for (&t, &h) in t.iter().zip(hi) {
        let (ab, ab_hi) = (schedule.alphas_cumprod[t], schedule.alphas_cumprod[h]);
        let ratio = ((1.0 - ab) / (1.0 - ab_hi)).sqrt();
        let on = if h > t { 1.0 } else { 0.0 };
        c[0].push((on * (ab.sqrt() - ab_hi.sqrt() * ratio)) as f32);
        c[1].push((on * ratio) as f32);
        c[2].push((1.0 - on) as f32);
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_choice_follows_the_draws_and_its_rate() {
        let t: Vec<usize> = (0..4000).map(|i| (i * 7) % 1000).collect();
        let noise: Vec<f32> = (0..4000 * 3).map(|i| ((i as f32) * 0.37).sin()).collect();
        let a = chosen(5, 0.5, &t, &noise);
        assert_eq!(a, chosen(5, 0.5, &t, &noise));
        let share = a.iter().filter(|&&c| c).count() as f64 / a.len() as f64;
        assert!((share - 0.5).abs() < 0.03, "{share}");
        assert!(chosen(5, 0.0, &t, &noise).iter().all(|&c| !c));
        assert!(chosen(5, 1.0, &t, &noise).iter().all(|&c| c));
        // A shard of the batch chooses what the whole batch chose for its samples.
        assert_eq!(chosen(5, 0.5, &t[10..20], &noise[30..60]), a[10..20]);
    }

    /// With an exact estimate (est = x0) the DDIM step lands on x0 noised at t with the same
    /// noise: the rolled-out x_t differs from the plain one only by the estimate's error.
    #[test]
    fn an_exact_estimate_gives_the_plain_x_t() {
        let schedule = Schedule::cosine(1000);
        let (t, hi) = ([0usize, 10, 400, 899, 999], [100usize, 110, 500, 999, 999]);
        let [c_est, c_hi, keep] = coefficients(&schedule, &t, &hi);
        for i in 0..t.len() {
            let (x0, n) = (0.7f64, -1.3f64);
            let a = |k: usize| schedule.alphas_cumprod[k].sqrt();
            let s = |k: usize| (1.0 - schedule.alphas_cumprod[k]).sqrt();
            let x_hi = a(hi[i]) * x0 + s(hi[i]) * n;
            let plain = a(t[i]) * x0 + s(t[i]) * n;
            let rolled = c_est[i] as f64 * x0 + c_hi[i] as f64 * x_hi + keep[i] as f64 * plain;
            assert!((rolled - plain).abs() < 1e-5, "t {}: {rolled} against {plain}", t[i]);
        }
        assert_eq!(keep, [0.0, 0.0, 0.0, 0.0, 1.0], "t at the last step keeps its x_t");
    }
}

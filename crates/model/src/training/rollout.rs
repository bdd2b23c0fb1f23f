//! Training on the sampler's own step (`training.rollout_prob`). A sampler builds each x_t from
//! the network's previous x0 estimate, a blur of the motions the condition allows (for an
//! ambiguous caption, a walk half way to a stand), whereas training noises the true motion; a
//! network that trusts x_t then drifts towards the blur from step to step (measured on the
//! quick start's walk: 0.59 m/s after one DDIM step, 0.32 after five, the source 0.84). For a
//! share of the samples x_t is instead made by DDIM steps of the network itself (detached), one
//! from the true motion noised at t + gap, or `rollout_steps` from t + steps * gap: the network
//! learns to correct its own estimate from the condition rather than copy it. The target stays
//! the true x0. These are steps of the trajectory, as in the scheduled-sampling remedies of
//! exposure bias in diffusion models.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use diffkfc_data::rng::Rng;

use crate::diffusion::{per_sample, Schedule};
use crate::network::condition::{row_index, Condition};
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

/// Which samples of a batch roll out, at which timesteps, how far back and in how many steps.
pub struct Step<'a> {
    /// Each sample's timestep.
    pub t: &'a [usize],
    pub rolled: &'a [bool],
    /// Timesteps between two levels of the rollout (`training.rollout_gap`).
    pub gap: usize,
    /// Sampler steps from the noisiest level down to t (`training.rollout_steps`).
    pub steps: usize,
}

/// x_t of every sample, rolled-out ones replaced by `steps` DDIM steps, `gap` timesteps apart
/// (levels capped at the schedule's last step), from x0 noised with the same `noise` at
/// t + steps * gap, each through `model`'s own x0 estimate.
/// `x0`, `noise`, `x_t` [B, N, D] -> [B, N, D].
///
/// Only the rolled-out rows go through the network, on the inner backend with the model's
/// validation copy: nothing here is differentiated, so no graph is recorded, and the network
/// runs without dropout, as the sampler runs it.
pub fn rolled_x_t(
    model: &Denoiser,
    schedule: &Schedule,
    cond: &Condition,
    x0: Tensor<3>,
    noise: Tensor<3>,
    x_t: Tensor<3>,
    step: Step,
) -> Tensor<3> {
    let rows: Vec<usize> = (0..step.rolled.len()).filter(|&i| step.rolled[i]).collect();
    if rows.is_empty() {
        return x_t;
    }
    let last = schedule.alphas_cumprod.len() - 1;
    // Each rolled sample's timestep `j` steps above its t.
    let level = |j: usize| -> Vec<usize> {
        rows.iter().map(|&i| (step.t[i] + j * step.gap).min(last)).collect()
    };
    let autodiff = x_t.is_autodiff();
    let x_t = x_t.without_autodiff();
    let device = x_t.device();
    let idx = row_index(&rows, &device);
    let pick = |t: Tensor<3>| t.without_autodiff().select(0, idx.clone());
    let (model, cond) = (model.valid(), cond.select_rows(&rows).without_autodiff());
    let mut x = schedule.q_sample(pick(x0), &level(step.steps), pick(noise));
    for j in (1..=step.steps).rev() {
        let (hi, lo) = (level(j), level(j - 1));
        let est = model.forward(x.clone(), &hi, &cond);
        let [c_est, c_x] = coefficients(schedule, &lo, &hi);
        x = est * per_sample(&c_est, &device) + x * per_sample(&c_x, &device);
    }
    // The other samples keep the x_t they were given, bit for bit.
    let out = x_t.select_assign(0, idx, x, IndexingUpdateOp::Assign);
    if autodiff {
        out.autodiff()
    } else {
        out
    }
}

/// Per sample, the weights of the estimate and of x at `hi` in x at `lo`: DDIM's
/// x_lo = sqrt(ab_lo) est + sqrt(1 - ab_lo) eps with eps = (x_hi - sqrt(ab_hi) est) /
/// sqrt(1 - ab_hi); a sample with `hi` = `lo` keeps its x.
fn coefficients(schedule: &Schedule, lo: &[usize], hi: &[usize]) -> [Vec<f32>; 2] {
    let mut c = [Vec::new(), Vec::new()];
    for (&l, &h) in lo.iter().zip(hi) {
        let (ab, ab_hi) = (schedule.alphas_cumprod[l], schedule.alphas_cumprod[h]);
        let (c_est, c_x) = if h > l {
            let ratio = ((1.0 - ab) / (1.0 - ab_hi)).sqrt();
            (ab.sqrt() - ab_hi.sqrt() * ratio, ratio)
        } else {
            (0.0, 1.0)
        };
        c[0].push(c_est as f32);
        c[1].push(c_x as f32);
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::params;

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

    /// The rolled-out rows are what each sample's own DDIM steps through the validation model
    /// give (one sample a batch), the others keep x_t bit for bit, and two calls agree (no
    /// dropout), on an autodiff device as in training.
    #[test]
    fn only_the_rolled_rows_roll_each_as_alone() {
        use crate::DiffKfcConfig;
        let dev = Device::flex().autodiff();
        let cfg = DiffKfcConfig::tiny().with_key_input(true).with_temporal_kernel(3);
        let model = cfg.init(&dev);
        let cond = crate::bench::request(&cfg, 4, 30, 1).condition(&dev);
        let schedule = Schedule::cosine(1000);
        let dist = burn::tensor::Distribution::Normal(0.0, 1.0);
        let (x0, noise) = (
            Tensor::<3>::random([4, 30, 263], dist, &dev),
            Tensor::random([4, 30, 263], dist, &dev),
        );
        let t = [10usize, 300, 600, 990];
        let rolled = [true, false, true, true];
        let x_t = schedule.q_sample(x0.clone(), &t, noise.clone());
        let step = || Step { t: &t, rolled: &rolled, gap: 100, steps: 2 };
        let run =
            || rolled_x_t(&model, &schedule, &cond, x0.clone(), noise.clone(), x_t.clone(), step());
        let out = run();
        assert!(out.is_autodiff());
        let (got, again, plain) = (params::host(out), params::host(run()), params::host(x_t));
        assert_eq!(got, again, "no dropout in the rollout");
        let row = 30 * 263;
        assert_eq!(got[row..2 * row], plain[row..2 * row], "an unrolled row keeps x_t");
        let valid = model.valid();
        for i in [0usize, 2, 3] {
            let one = |x: &Tensor<3>| x.clone().without_autodiff().slice(i..i + 1);
            let c = cond.select_rows(&[i]).without_autodiff();
            let lv = |j: usize| vec![(t[i] + 100 * j).min(999)];
            let mut x = schedule.q_sample(one(&x0), &lv(2), one(&noise));
            for j in [2, 1] {
                let est = valid.forward(x.clone(), &lv(j), &c);
                let [ce, cx] = coefficients(&schedule, &lv(j - 1), &lv(j));
                x = est * ce[0] + x * cx[0];
            }
            let want = params::host(x);
            let worst = (want.iter().zip(&got[i * row..(i + 1) * row]))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-4, "row {i}: {worst} from its own rollout");
            assert!(want != plain[i * row..(i + 1) * row], "row {i} rolled");
        }
    }

    /// With an exact estimate (est = x0) the DDIM step lands on x0 noised at t with the same
    /// noise: the rolled-out x_t differs from the plain one only by the estimate's error.
    #[test]
    fn an_exact_estimate_gives_the_plain_x_t() {
        let schedule = Schedule::cosine(1000);
        let (t, hi) = ([0usize, 10, 400, 899, 999], [100usize, 110, 500, 999, 999]);
        let [c_est, c_x] = coefficients(&schedule, &t, &hi);
        for i in 0..t.len() {
            let (x0, n) = (0.7f64, -1.3f64);
            let a = |k: usize| schedule.alphas_cumprod[k].sqrt();
            let s = |k: usize| (1.0 - schedule.alphas_cumprod[k]).sqrt();
            let x_hi = a(hi[i]) * x0 + s(hi[i]) * n;
            let plain = a(t[i]) * x0 + s(t[i]) * n;
            let rolled = c_est[i] as f64 * x0 + c_x[i] as f64 * x_hi;
            assert!((rolled - plain).abs() < 1e-5, "t {}: {rolled} against {plain}", t[i]);
        }
        assert_eq!((c_est[4], c_x[4]), (0.0, 1.0), "t at the last step keeps its x_t");
    }
}

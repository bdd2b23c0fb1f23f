//! One reverse step per sampler (in the manner of candle's schedulers): given x_t, the step's
//! predicted x0 and the guidance shift to subtract, move x_t to the next timestep. DDPM draws
//! fresh noise (ancestral), DDIM (eta = 0) is deterministic, DPM-Solver++(2M) (Lu et al. 2022)
//! extrapolates with the previous step's x0.

use diffkfc_data::rng::Rng;

use crate::diffusion::Schedule;

/// Which scheduler walks the reverse process, and over how many steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sampler {
    /// Ancestral DDPM over every step of the schedule (the paper).
    Ddpm,
    /// Deterministic DDIM (eta = 0) over this many evenly spaced steps.
    Ddim(usize),
    /// DPM-Solver++(2M) (Lu et al. 2022) over this many evenly spaced steps: the data-prediction
    /// multistep solver, second order from the second step (the first is a DDIM step).
    DpmSolver(usize),
}

impl Sampler {
    /// The same sampler over `steps` steps (DDPM always runs every step of the schedule).
    pub fn with_steps(self, steps: usize) -> Sampler {
        match self {
            Sampler::Ddpm => Sampler::Ddpm,
            Sampler::Ddim(_) => Sampler::Ddim(steps),
            Sampler::DpmSolver(_) => Sampler::DpmSolver(steps),
        }
    }
}

/// The timesteps visited, from noisy to clean.
pub fn timesteps(schedule: &Schedule, sampler: Sampler) -> Vec<usize> {
    let t = schedule.steps;
    match sampler {
        Sampler::Ddpm => (0..t).rev().collect(),
        Sampler::Ddim(k) | Sampler::DpmSolver(k) => {
            let k = k.clamp(1, t);
            // One step is the prediction from pure noise, at the schedule's last timestep.
            if k == 1 {
                return vec![t - 1];
            }
            let mut v: Vec<usize> = (0..k)
                .map(|i| ((i as f64) * (t - 1) as f64 / (k - 1).max(1) as f64).round() as usize)
                .collect();
            v.dedup();
            v.reverse();
            v
        }
    }
}

pub trait Scheduler {
    /// x_t -> x_prev in place (`prev` < `t`), from the step's x0 and the guidance `shift`.
    fn step(&mut self, x: &mut [f32], x0: &[f32], shift: &[f32], t: usize, prev: usize);
}

/// The scheduler of `sampler`; DDPM takes over `rng` (the stream that drew the initial noise).
pub fn for_sampler<'a>(
    sampler: Sampler,
    schedule: &'a Schedule,
    rng: Rng,
) -> Box<dyn Scheduler + 'a> {
    match sampler {
        Sampler::Ddpm => Box::new(Ddpm { schedule, rng }),
        Sampler::Ddim(_) => Box::new(Ddim { schedule }),
        Sampler::DpmSolver(_) => Box::new(DpmSolverPp { schedule, last: None }),
    }
}

/// Ancestral sampling through the posterior q(x_{t-1} | x_t, x0) (every step of the schedule).
pub struct Ddpm<'a> {
    schedule: &'a Schedule,
    rng: Rng,
}

impl Scheduler for Ddpm<'_> {
    fn step(&mut self, x: &mut [f32], x0: &[f32], shift: &[f32], t: usize, _prev: usize) {
        let (c0, ct, pvar) = self.schedule.posterior(t);
        let sd = pvar.sqrt() as f32;
        for ((xi, &x0i), &si) in x.iter_mut().zip(x0).zip(shift) {
            let mu = c0 as f32 * x0i + ct as f32 * *xi - si;
            *xi = mu + sd * self.rng.normal() as f32;
        }
    }
}

/// Deterministic DDIM: the noise implied by x_t and x0, re-applied at the next timestep.
pub struct Ddim<'a> {
    schedule: &'a Schedule,
}

impl Scheduler for Ddim<'_> {
    fn step(&mut self, x: &mut [f32], x0: &[f32], shift: &[f32], t: usize, prev: usize) {
        let (ab, ab_prev) = (self.schedule.alphas_cumprod[t], self.schedule.alphas_cumprod[prev]);
        let (sa, s1a) = (ab.sqrt() as f32, (1.0 - ab).sqrt() as f32);
        let (sp, s1p) = (ab_prev.sqrt() as f32, (1.0 - ab_prev).sqrt() as f32);
        for ((xi, &x0i), &si) in x.iter_mut().zip(x0).zip(shift) {
            let eps = (*xi - sa * x0i) / s1a;
            *xi = sp * x0i + s1p * eps - si;
        }
    }
}

/// DPM-Solver++(2M): the data-prediction multistep solver, first order on its first step (a
/// DDIM step), second order after it.
pub struct DpmSolverPp<'a> {
    schedule: &'a Schedule,
    /// The previous step's x0 and its lambda.
    last: Option<(Vec<f32>, f64)>,
}

/// Half the log signal-to-noise ratio of a cumulative alpha.
fn lambda(ab: f64) -> f64 {
    0.5 * (ab / (1.0 - ab)).ln()
}

impl Scheduler for DpmSolverPp<'_> {
    fn step(&mut self, x: &mut [f32], x0: &[f32], shift: &[f32], t: usize, prev: usize) {
        // x_next = (sigma_next / sigma) x - alpha_next (e^-h - 1) D, with D the x0 of this step
        // (first order) or extrapolated with the last one (second order).
        let (ab, ab_prev) = (self.schedule.alphas_cumprod[t], self.schedule.alphas_cumprod[prev]);
        let (l, l_next) = (lambda(ab), lambda(ab_prev));
        let h = l_next - l;
        let ratio = ((1.0 - ab_prev) / (1.0 - ab)).sqrt() as f32;
        let c = (-(ab_prev.sqrt()) * ((-h).exp() - 1.0)) as f32;
        let (w0, w1) = match &self.last {
            Some((_, l_last)) => {
                let r = (l - l_last) / h;
                ((1.0 + 0.5 / r) as f32, (-0.5 / r) as f32)
            }
            None => (1.0, 0.0),
        };
        let before = self.last.as_ref().map(|(v, _)| v.as_slice());
        for (e, ((xi, &x0i), &si)) in x.iter_mut().zip(x0).zip(shift).enumerate() {
            let dv = w0 * x0i + before.map_or(0.0, |b| w1 * b[e]);
            *xi = ratio * *xi + c * dv - si;
        }
        self.last = Some((x0.to_vec(), l));
    }
}

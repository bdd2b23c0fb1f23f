//! Gaussian diffusion with x0 prediction: the noise schedule, q(x_t | x_0) and the DDPM
//! posterior. Coefficients are kept in f64 on the host; per-sample coefficients become
//! [B, 1, 1] tensors.

pub mod scheduler;

use burn::prelude::*;

#[derive(Clone, Debug)]
pub struct Schedule {
    pub steps: usize,
    pub betas: Vec<f64>,
    pub alphas_cumprod: Vec<f64>,
}

impl Schedule {
    /// Cosine schedule (Nichol & Dhariwal): alpha_bar(t) = cos((t/T + s)/(1 + s) * pi/2)^2,
    /// s = 0.008, betas capped at 0.999.
    pub fn cosine(steps: usize) -> Schedule {
        let f = |t: f64| {
            ((t / steps as f64 + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2)
        };
        let betas: Vec<f64> =
            (0..steps).map(|i| (1.0 - f(i as f64 + 1.0) / f(i as f64)).min(0.999)).collect();
        Self::from_betas(betas)
    }

    /// Linear schedule of DDPM, scaled to the number of steps as in improved DDPM.
    pub fn linear(steps: usize) -> Schedule {
        let scale = 1000.0 / steps as f64;
        let (a, b) = (scale * 1e-4, scale * 0.02);
        Self::from_betas(
            (0..steps).map(|i| a + (b - a) * i as f64 / (steps - 1).max(1) as f64).collect(),
        )
    }

    pub fn by_name(name: &str, steps: usize) -> Option<Schedule> {
        match name {
            "cosine" => Some(Self::cosine(steps)),
            "linear" => Some(Self::linear(steps)),
            _ => None,
        }
    }

    fn from_betas(betas: Vec<f64>) -> Schedule {
        let mut acc = 1.0;
        let alphas_cumprod = betas
            .iter()
            .map(|b| {
                acc *= 1.0 - b;
                acc
            })
            .collect();
        Schedule { steps: betas.len(), betas, alphas_cumprod }
    }

    pub fn alpha_bar_prev(&self, t: usize) -> f64 {
        if t == 0 {
            1.0
        } else {
            self.alphas_cumprod[t - 1]
        }
    }

    /// (sqrt(abar_t), sqrt(1 - abar_t)): the weights of x0 and of the noise in x_t.
    fn q_weights(&self, t: usize) -> (f32, f32) {
        let ab = self.alphas_cumprod[t];
        (ab.sqrt() as f32, (1.0 - ab).sqrt() as f32)
    }

    /// x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) noise, per sample.
    pub fn q_sample(&self, x0: Tensor<3>, t: &[usize], noise: Tensor<3>) -> Tensor<3> {
        let (a, s): (Vec<f32>, Vec<f32>) = t.iter().map(|&t| self.q_weights(t)).unzip();
        x0 * per_sample(&a, &noise.device()) + noise.clone() * per_sample(&s, &noise.device())
    }

    /// [`Schedule::q_sample`] of host buffers x0 and noise ([B * N * D] each, `t` one timestep
    /// per sample), samples in parallel: the same products and sums, so the same values.
    pub fn q_sample_host(&self, x0: &[f32], t: &[usize], noise: &[f32]) -> Vec<f32> {
        use rayon::prelude::*;
        let per = (x0.len() / t.len().max(1)).max(1);
        let mut x_t = vec![0f32; x0.len()];
        x_t.par_chunks_mut(per).zip(x0.par_chunks(per)).enumerate().for_each(|(i, (out, x))| {
            let (a, s) = self.q_weights(t[i]);
            let e = &noise[i * per..(i + 1) * per];
            for ((o, &x), &e) in out.iter_mut().zip(x).zip(e) {
                *o = x * a + e * s;
            }
        });
        x_t
    }

    /// Posterior q(x_{t-1} | x_t, x0): (coefficient on x0, coefficient on x_t, variance).
    pub fn posterior(&self, t: usize) -> (f64, f64, f64) {
        let (ab, abp, beta) = (self.alphas_cumprod[t], self.alpha_bar_prev(t), self.betas[t]);
        let c0 = beta * abp.sqrt() / (1.0 - ab);
        let ct = (1.0 - abp) * (1.0 - beta).sqrt() / (1.0 - ab);
        let var = beta * (1.0 - abp) / (1.0 - ab);
        (c0, ct, var)
    }
}

/// Per-sample scalars as a [B, 1, 1] tensor.
pub fn per_sample(v: &[f32], device: &Device) -> Tensor<3> {
    Tensor::<1>::from_floats(v, device).reshape([v.len(), 1, 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_schedule_matches_its_closed_form() {
        let s = Schedule::cosine(1000);
        let f = |t: f64| ((t / 1000.0 + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2);
        for t in [0usize, 1, 10, 500, 900, 998] {
            let want = f(t as f64 + 1.0) / f(0.0);
            assert!((s.alphas_cumprod[t] - want).abs() < 1e-9, "t={t}");
        }
        assert!(s.betas.iter().all(|&b| b > 0.0 && b <= 0.999));
        assert!(s.alphas_cumprod[999] < 1e-4);
        // The posterior mean of x0 itself at t=0 is x0 (no noise left).
        let (c0, ct, var) = s.posterior(0);
        assert!((c0 - 1.0).abs() < 1e-9 && ct.abs() < 1e-9 && var.abs() < 1e-12);
    }

    /// The host noising gives the tensor one's values exactly.
    #[test]
    fn host_q_sample_matches_the_tensor_ops() {
        let dev = Device::flex();
        let s = Schedule::cosine(1000);
        let (b, n, d) = (3, 5, 7);
        let x0: Vec<f32> = (0..b * n * d).map(|i| ((i * 37) % 11) as f32 * 0.3 - 1.5).collect();
        let noise: Vec<f32> = (0..b * n * d).map(|i| ((i * 53) % 13) as f32 * 0.2 - 1.2).collect();
        let t = [0, 499, 999];
        let tensor = |v: &[f32]| Tensor::<1>::from_floats(v, &dev).reshape([b, n, d]);
        let want =
            s.q_sample(tensor(&x0), &t, tensor(&noise)).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(s.q_sample_host(&x0, &t, &noise), want);
    }
}

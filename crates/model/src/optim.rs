//! Adam with gradient-norm clipping, a warm-up / cosine learning-rate schedule and an EMA of the
//! weights, on host-side flat parameters (see `params`).

#[derive(Clone, Debug)]
pub struct Adam {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub step: u64,
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
}

impl Adam {
    pub fn new(shapes: &[usize]) -> Adam {
        Adam { beta1: 0.9, beta2: 0.999, eps: 1e-8, step: 0, m: shapes.iter().map(|&n| vec![0.0; n]).collect(), v: shapes.iter().map(|&n| vec![0.0; n]).collect() }
    }

    /// One update of `params` with `grads` at learning rate `lr`.
    pub fn update(&mut self, params: &mut [Vec<f32>], grads: &[Vec<f32>], lr: f64) {
        self.step += 1;
        let (b1, b2) = (self.beta1 as f32, self.beta2 as f32);
        let c1 = 1.0 - self.beta1.powi(self.step as i32);
        let c2 = 1.0 - self.beta2.powi(self.step as i32);
        let step = (lr * c2.sqrt() / c1) as f32;
        let eps = (self.eps * c2.sqrt()) as f32;
        for (((p, g), m), v) in params.iter_mut().zip(grads).zip(&mut self.m).zip(&mut self.v) {
            for i in 0..p.len() {
                m[i] = b1 * m[i] + (1.0 - b1) * g[i];
                v[i] = b2 * v[i] + (1.0 - b2) * g[i] * g[i];
                p[i] -= step * m[i] / (v[i].sqrt() + eps);
            }
        }
    }
}

/// Global L2 norm of the gradients; scales them down to `max` when above it (max <= 0: off).
pub fn clip_grad_norm(grads: &mut [Vec<f32>], max: f64) -> f64 {
    let norm = grads.iter().flatten().map(|&g| (g as f64) * (g as f64)).sum::<f64>().sqrt();
    if max > 0.0 && norm > max {
        let s = (max / norm) as f32;
        grads.iter_mut().flatten().for_each(|g| *g *= s);
    }
    norm
}

/// Learning rate at `step` (0-based): linear warm-up, then constant or cosine decay to 0.
pub fn learning_rate(base: f64, step: usize, warmup: usize, cosine: bool, max_steps: usize) -> f64 {
    if step < warmup {
        return base * (step + 1) as f64 / warmup as f64;
    }
    if cosine && max_steps > warmup {
        let p = (step - warmup) as f64 / (max_steps - warmup) as f64;
        return base * 0.5 * (1.0 + (std::f64::consts::PI * p.min(1.0)).cos());
    }
    base
}

/// ema = decay * ema + (1 - decay) * params.
pub fn ema_update(ema: &mut [Vec<f32>], params: &[Vec<f32>], decay: f64) {
    let d = decay as f32;
    for (e, p) in ema.iter_mut().zip(params) {
        for (x, y) in e.iter_mut().zip(p) {
            *x = d * *x + (1.0 - d) * y;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam's first step moves every parameter by lr against the gradient's sign.
    #[test]
    fn adam_first_step_and_clipping() {
        let mut p = vec![vec![1.0f32, -2.0]];
        let mut a = Adam::new(&[2]);
        a.update(&mut p, &[vec![0.5, -3.0]], 0.1);
        assert!((p[0][0] - 0.9).abs() < 1e-6 && (p[0][1] + 1.9).abs() < 1e-6, "{p:?}");
        let mut g = vec![vec![3.0f32, 4.0]];
        assert_eq!(clip_grad_norm(&mut g, 1.0), 5.0);
        assert!((g[0][0] - 0.6).abs() < 1e-6 && (g[0][1] - 0.8).abs() < 1e-6);
        assert_eq!(learning_rate(1.0, 0, 10, false, 100), 0.1);
        assert!((learning_rate(1.0, 55, 10, true, 100) - 0.5).abs() < 1e-9);
    }
}

/// One optimiser step as the trainers take it: backward of `loss`, gradients to the host,
/// global-norm clipping, Adam on the flat host values, the new values loaded into `model`.
/// Returns the updated model and the gradient norm before clipping.
pub fn descend<M: burn::module::Module>(model: M, loss: burn::tensor::Tensor<1>, vals: &mut [Vec<f32>], adam: &mut Adam, clip: f64, lr: f64) -> (M, f64) {
    let grads = burn::optim::GradientsParams::from_grads(loss.backward(), &model);
    let mut g = crate::params::grads(&model, &grads);
    let norm = clip_grad_norm(&mut g, clip);
    adam.update(vals, &g, lr);
    (crate::params::load(model, vals), norm)
}

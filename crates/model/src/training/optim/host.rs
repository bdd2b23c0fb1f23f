//! The optimiser on host-side flat parameters (see `params`): for the CPU backends, where the
//! device's memory is the host's, one fused multithreaded pass per step beats a chain of tensor
//! ops (each a pass over every weight).

/// One chunk of Adam's work: parameters, gradients, first and second moments.
type AdamChunk<'a> = (&'a mut [f32], &'a [f32], &'a mut [f32], &'a mut [f32]);

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
        Adam {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            step: 0,
            m: shapes.iter().map(|&n| vec![0.0; n]).collect(),
            v: shapes.iter().map(|&n| vec![0.0; n]).collect(),
        }
    }

    /// One update of `params` with `grads` at learning rate `lr`.
    pub fn update(&mut self, params: &mut [Vec<f32>], grads: &[Vec<f32>], lr: f64) {
        use rayon::prelude::*;
        self.step += 1;
        let (b1, b2) = (self.beta1 as f32, self.beta2 as f32);
        let c1 = 1.0 - self.beta1.powi(self.step as i32);
        let c2 = 1.0 - self.beta2.powi(self.step as i32);
        let step = (lr * c2.sqrt() / c1) as f32;
        let eps = (self.eps * c2.sqrt()) as f32;
        // Every element is independent: chunks across threads give the same bits as one loop.
        let chunks: Vec<AdamChunk> = params
            .iter_mut()
            .zip(grads)
            .zip(self.m.iter_mut())
            .zip(self.v.iter_mut())
            .flat_map(|(((p, g), m), v)| {
                p.chunks_mut(CHUNK)
                    .zip(g.chunks(CHUNK))
                    .zip(m.chunks_mut(CHUNK))
                    .zip(v.chunks_mut(CHUNK))
                    .map(|(((p, g), m), v)| (p, g, m, v))
            })
            .collect();
        chunks.into_par_iter().for_each(|(p, g, m, v)| {
            for i in 0..p.len() {
                m[i] = b1 * m[i] + (1.0 - b1) * g[i];
                v[i] = b2 * v[i] + (1.0 - b2) * g[i] * g[i];
                p[i] -= step * m[i] / (v[i].sqrt() + eps);
            }
        });
    }
}

/// Elements per parallel work item of the host-side optimiser.
const CHUNK: usize = 1 << 16;

/// Global L2 norm of the gradients; scales them down to `max` when above it (max <= 0: off).
pub fn clip_grad_norm(grads: &mut [Vec<f32>], max: f64) -> f64 {
    use rayon::prelude::*;
    // Partial sums over fixed chunks, added in order: the same norm for any thread count.
    let parts: Vec<f64> = grads
        .iter()
        .flat_map(|g| g.chunks(CHUNK))
        .collect::<Vec<_>>()
        .par_iter()
        .map(|c| c.iter().map(|&g| (g as f64) * (g as f64)).sum::<f64>())
        .collect();
    let norm = parts.iter().sum::<f64>().sqrt();
    if max > 0.0 && norm > max {
        let s = (max / norm) as f32;
        grads
            .par_iter_mut()
            .flat_map(|g| g.par_chunks_mut(CHUNK))
            .for_each(|c| c.iter_mut().for_each(|g| *g *= s));
    }
    norm
}

/// ema = decay * ema + (1 - decay) * params.
pub fn ema_update(ema: &mut [Vec<f32>], params: &[Vec<f32>], decay: f64) {
    use rayon::prelude::*;
    let d = decay as f32;
    let chunks: Vec<(&mut [f32], &[f32])> = ema
        .iter_mut()
        .zip(params)
        .flat_map(|(e, p)| e.chunks_mut(CHUNK).zip(p.chunks(CHUNK)))
        .collect();
    chunks
        .into_par_iter()
        .for_each(|(e, p)| e.iter_mut().zip(p).for_each(|(x, y)| *x = d * *x + (1.0 - d) * y));
}

/// The update after the backward pass: gradients to the host, global-norm clipping, Adam on the
/// flat host values, the new values loaded into `model`. Returns the model and the gradient norm
/// before clipping.
pub(super) fn descend<M: burn::module::Module>(
    model: M,
    grads: burn::optim::GradientsParams,
    frozen: &[bool],
    vals: &mut [Vec<f32>],
    adam: &mut Adam,
    clip: f64,
    lr: f64,
) -> (M, f64) {
    let mut g = crate::network::params::grads(&model, &grads);
    drop(grads);
    for (g, _) in g.iter_mut().zip(frozen).filter(|(_, &f)| f) {
        g.fill(0.0);
    }
    let norm = clip_grad_norm(&mut g, clip);
    adam.update(vals, &g, lr);
    (crate::network::params::load(model, vals), norm)
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
    }
}

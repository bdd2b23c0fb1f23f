//! The optimiser as tensor operations on the training device (GPU backends): Adam's moments
//! and the EMA are device tensors, the parameters are updated where they live, and a step moves
//! nothing across the bus but the per-parameter squared gradient norms (one small read, for
//! clipping and the log). The arithmetic is the host path's (`host.rs`), operation for
//! operation, so the two agree to rounding.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

/// Adam's moments (and the EMA when kept) as flat device tensors, one per parameter in visit
/// order.
pub(super) struct DeviceState {
    pub m: Vec<Tensor<1>>,
    pub v: Vec<Tensor<1>>,
    pub ema: Option<Vec<Tensor<1>>>,
}

/// Host vectors onto `device` as flat tensors.
pub(super) fn upload(vals: Vec<Vec<f32>>, device: &Device) -> Vec<Tensor<1>> {
    vals.into_iter()
        .map(|v| {
            let n = v.len();
            Tensor::<1>::from_data(TensorData::new(v, [n]), device)
        })
        .collect()
}

/// Flat device tensors back to host vectors (checkpoints).
pub(super) fn download(ts: &[Tensor<1>]) -> Vec<Vec<f32>> {
    ts.iter().map(|t| crate::network::params::host(t.clone())).collect()
}

/// Every float parameter, flat, on the inner (non-autodiff) device.
struct Flat(Vec<Tensor<1>>);
impl ModuleVisitor for Flat {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        let t = p.val().inner();
        let n = t.shape().num_elements();
        self.0.push(t.reshape([n]));
    }
}

/// The parameters of `m` as flat inner tensors (no copy on the device).
pub(super) fn flat<M: Module>(m: &M) -> Vec<Tensor<1>> {
    let mut v = Flat(Vec::new());
    m.visit(&mut v);
    v.0
}

/// The gradient of every parameter, flat (zeros where a parameter got none, as on the host).
struct FlatGrads<'a> {
    grads: &'a GradientsParams,
    out: Vec<Tensor<1>>,
}
impl ModuleVisitor for FlatGrads<'_> {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        let t = p.val();
        let n = t.shape().num_elements();
        let g = match self.grads.get::<D>(p.id) {
            Some(g) => g.reshape([n]),
            None => Tensor::<1>::zeros([n], &t.inner().device()),
        };
        self.out.push(g);
    }
}

/// Adam's update of every parameter with its (clipped) flat gradient.
struct Update<'a> {
    grads: std::vec::IntoIter<Tensor<1>>,
    state: &'a mut DeviceState,
    i: usize,
    scale: Option<f32>,
    b1: f32,
    b2: f32,
    step: f32,
    eps: f32,
}
impl ModuleMapper for Update<'_> {
    fn map_float<const D: usize>(&mut self, p: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, t, mapper) = p.consume();
        let autodiff = t.is_autodiff();
        // A data-parallel replica's parameters stay marked for Burn's gradient all-reduce.
        let distributed = autodiff && t.is_distributed();
        let shape = t.shape();
        let n = shape.num_elements();
        let mut g = self.grads.next().expect("one gradient per parameter");
        if let Some(s) = self.scale {
            g = g.mul_scalar(s);
        }
        let i = self.i;
        self.i += 1;
        // The host loop's expressions in its order: m = b1 m + (1 - b1) g;
        // v = b2 v + ((1 - b2) g) g; p -= (step m) / (sqrt(v) + eps).
        let m =
            self.state.m[i].clone().mul_scalar(self.b1).add(g.clone().mul_scalar(1.0 - self.b1));
        let v = self.state.v[i]
            .clone()
            .mul_scalar(self.b2)
            .add(g.clone().mul_scalar(1.0 - self.b2).mul(g));
        let delta = m.clone().mul_scalar(self.step).div(v.clone().sqrt().add_scalar(self.eps));
        self.state.m[i] = m;
        self.state.v[i] = v;
        let mut new = t.inner().reshape([n]).sub(delta).reshape(shape);
        if autodiff {
            new = Tensor::from_inner(new).require_grad();
        }
        if distributed {
            new = new.set_distributed(id);
        }
        Param::from_mapped_value(id, new, mapper)
    }
}

/// One step on the device after the backward pass: global-norm clipping and Adam (moments at
/// step `t`, 1-based, already counted). Returns the model and the gradient norm before clipping.
#[allow(clippy::too_many_arguments)]
pub(super) fn descend<M: Module>(
    model: M,
    grads: GradientsParams,
    frozen: &[bool],
    state: &mut DeviceState,
    t: u64,
    (beta1, beta2, eps): (f64, f64, f64),
    clip: f64,
    lr: f64,
) -> (M, f64) {
    let mut g = {
        let mut fg = FlatGrads { grads: &grads, out: Vec::new() };
        model.visit(&mut fg);
        fg.out
    };
    for (g, _) in g.iter_mut().zip(frozen).filter(|(_, &f)| f) {
        *g = g.zeros_like();
    }
    drop(grads);
    // Per-parameter sums of squares in one read; added in f64 on the host like the host path.
    let sums = Tensor::cat(g.iter().map(|g| g.clone().square().sum()).collect(), 0);
    let norm = crate::network::params::host(sums).iter().map(|&s| s as f64).sum::<f64>().sqrt();
    let scale = (clip > 0.0 && norm > clip).then(|| (clip / norm) as f32);
    let c1 = 1.0 - beta1.powi(t as i32);
    let c2 = 1.0 - beta2.powi(t as i32);
    let mut up = Update {
        grads: g.into_iter(),
        state,
        i: 0,
        scale,
        b1: beta1 as f32,
        b2: beta2 as f32,
        step: (lr * c2.sqrt() / c1) as f32,
        eps: (eps * c2.sqrt()) as f32,
    };
    let model = model.map(&mut up);
    (model, norm)
}

/// ema = decay * ema + (1 - decay) * params, on the device.
pub(super) fn ema_update(ema: &mut [Tensor<1>], params: Vec<Tensor<1>>, decay: f64) {
    let d = decay as f32;
    for (e, p) in ema.iter_mut().zip(params) {
        *e = e.clone().mul_scalar(d).add(p.mul_scalar(1.0 - d));
    }
}

//! The optimiser of every trainer here: Adam with global-norm gradient clipping, a warm-up /
//! cosine learning-rate schedule and an EMA of the weights. Its state lives where the training
//! device computes ([`StateLocation`]): host vectors for the CPU backends, device tensors for the GPU
//! backends. Checkpoints see the same [`Snapshot`] from either, so a run may resume on the other.

mod device;
mod host;

use std::borrow::Cow;

use burn::module::Module;
use burn::optim::GradientsParams;
use burn::prelude::*;

pub use host::{clip_grad_norm, ema_update, Adam};

/// Where the optimiser's state (moments, EMA, and for the host the weights' master copy) lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StateLocation {
    /// Host vectors updated in one fused multithreaded pass; weights are read out of and loaded
    /// into the model every step, which costs nothing where device memory is host memory.
    Host,
    /// Device tensors updated by tensor operations; the weights never leave the device.
    Device,
}

impl StateLocation {
    /// Host for the CPU backends (flex, ndarray), the device for the rest.
    pub fn for_device(device: &Device) -> StateLocation {
        let d = device.clone().inner();
        #[cfg(feature = "ndarray")]
        #[allow(deprecated)]
        if d == Device::ndarray() {
            return StateLocation::Host;
        }
        if d == Device::flex() {
            StateLocation::Host
        } else {
            StateLocation::Device
        }
    }
}

impl std::str::FromStr for StateLocation {
    type Err = diffkfc_data::UnknownChoice;
    fn from_str(s: &str) -> Result<StateLocation, Self::Err> {
        match s {
            "host" => Ok(StateLocation::Host),
            "device" => Ok(StateLocation::Device),
            _ => Err(diffkfc_data::UnknownChoice {
                what: "optimiser state location",
                given: s.into(),
                choices: "host or device",
            }),
        }
    }
}

/// The optimiser's state on the host: what a checkpoint stores.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// The weights (visit order).
    pub model: Vec<Vec<f32>>,
    pub ema: Option<Vec<Vec<f32>>>,
    /// Adam steps taken.
    pub step: u64,
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
}

enum State {
    Host { vals: Vec<Vec<f32>>, adam: Adam, ema: Option<Vec<Vec<f32>>> },
    Device { adam: (f64, f64, f64), step: u64, state: device::DeviceState },
}

/// Adam, clipping and the EMA for one model, its state at its [`StateLocation`].
pub struct Optimiser {
    state: State,
    /// Per parameter (visit order): true where training leaves it as it is
    /// (`training.trainable`); empty = every parameter trains.
    frozen: Vec<bool>,
}

impl Optimiser {
    /// A fresh optimiser for `model` (zero moments; the EMA, when `ema`, starts at the weights).
    pub fn new<M: Module>(model: &M, home: StateLocation, ema: bool) -> Optimiser {
        let vals: Vec<Vec<f32>> =
            crate::network::params::values(model).into_iter().map(|(_, v)| v).collect();
        let zeros = || vals.iter().map(|v| vec![0.0; v.len()]).collect::<Vec<_>>();
        let snap = Snapshot {
            ema: ema.then(|| vals.clone()),
            step: 0,
            m: zeros(),
            v: zeros(),
            model: Vec::new(),
        };
        Optimiser::from_snapshot(Snapshot { model: vals, ..snap }, home, model)
    }

    /// The optimiser of a checkpoint, and `model` with its weights.
    pub fn restore<M: Module>(model: M, snap: Snapshot, home: StateLocation) -> (M, Optimiser) {
        let model = crate::network::params::load(model, &snap.model);
        let o = Optimiser::from_snapshot(snap, home, &model);
        (model, o)
    }

    fn from_snapshot<M: Module>(snap: Snapshot, home: StateLocation, model: &M) -> Optimiser {
        let hyper = Adam::new(&[]);
        let state = match home {
            StateLocation::Host => State::Host {
                vals: snap.model,
                adam: Adam { step: snap.step, m: snap.m, v: snap.v, ..hyper },
                ema: snap.ema,
            },
            StateLocation::Device => {
                let dev = device::flat(model).first().map(|t| t.device()).unwrap_or_default();
                State::Device {
                    adam: (hyper.beta1, hyper.beta2, hyper.eps),
                    step: snap.step,
                    state: device::DeviceState {
                        m: device::upload(snap.m, &dev),
                        v: device::upload(snap.v, &dev),
                        ema: snap.ema.map(|e| device::upload(e, &dev)),
                    },
                }
            }
        };
        Optimiser { state, frozen: Vec::new() }
    }

    /// The optimiser with the parameters marked in `frozen` (visit order) held fixed: their
    /// gradients count as zero, so Adam's moments stay zero and its update is exactly zero.
    pub fn with_frozen(self, frozen: Vec<bool>) -> Optimiser {
        Optimiser { frozen, ..self }
    }

    pub fn home(&self) -> StateLocation {
        match self.state {
            State::Host { .. } => StateLocation::Host,
            State::Device { .. } => StateLocation::Device,
        }
    }

    /// One optimiser step: backward of `loss`, global-norm clipping at `clip` (<= 0: off), Adam
    /// at learning rate `lr`. Returns the updated model and the gradient norm before clipping.
    pub fn descend<M: Module>(
        &mut self,
        model: M,
        loss: Tensor<1>,
        clip: f64,
        lr: f64,
    ) -> (M, f64) {
        let (m, norm, _) = self.descend_timed(model, loss, clip, lr);
        (m, norm)
    }

    /// `descend`, also returning the seconds of the backward pass and of the update: the
    /// benchmark's breakdown of a step.
    pub fn descend_timed<M: Module>(
        &mut self,
        model: M,
        loss: Tensor<1>,
        clip: f64,
        lr: f64,
    ) -> (M, f64, [f64; 2]) {
        let t0 = std::time::Instant::now();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        let t1 = std::time::Instant::now();
        let (model, norm) = self.apply(model, grads, clip, lr);
        (model, norm, [(t1 - t0).as_secs_f64(), t1.elapsed().as_secs_f64()])
    }

    /// The update of `descend` from gradients already computed (a data-parallel replica's,
    /// summed over the replicas).
    pub fn apply<M: Module>(
        &mut self,
        model: M,
        grads: GradientsParams,
        clip: f64,
        lr: f64,
    ) -> (M, f64) {
        match &mut self.state {
            State::Host { vals, adam, .. } => {
                host::descend(model, grads, &self.frozen, vals, adam, clip, lr)
            }
            State::Device { adam, step, state } => {
                *step += 1;
                device::descend(model, grads, &self.frozen, state, *step, *adam, clip, lr)
            }
        }
    }

    /// ema = decay * ema + (1 - decay) * weights of `model` (nothing when no EMA is kept).
    pub fn update_ema<M: Module>(&mut self, model: &M, decay: f64) {
        match &mut self.state {
            State::Host { vals, ema: Some(e), .. } => ema_update(e, vals, decay),
            State::Device { state: device::DeviceState { ema: Some(e), .. }, .. } => {
                device::ema_update(e, device::flat(model), decay)
            }
            _ => {}
        }
    }

    /// The weights to evaluate: the EMA when kept, else the model's (host vectors).
    pub fn eval_weights<M: Module>(&self, model: &M) -> Cow<'_, [Vec<f32>]> {
        match &self.state {
            State::Host { vals, ema, .. } => Cow::Borrowed(ema.as_deref().unwrap_or(vals)),
            State::Device { state, .. } => Cow::Owned(match &state.ema {
                Some(e) => device::download(e),
                None => device::download(&device::flat(model)),
            }),
        }
    }

    /// The state on the host, for a checkpoint.
    pub fn snapshot<M: Module>(&self, model: &M) -> Snapshot {
        match &self.state {
            State::Host { vals, adam, ema } => Snapshot {
                model: vals.clone(),
                ema: ema.clone(),
                step: adam.step,
                m: adam.m.clone(),
                v: adam.v.clone(),
            },
            State::Device { step, state, .. } => Snapshot {
                model: device::download(&device::flat(model)),
                ema: state.ema.as_deref().map(device::download),
                step: *step,
                m: device::download(&state.m),
                v: device::download(&state.v),
            },
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule() {
        assert_eq!(learning_rate(1.0, 0, 10, false, 100), 0.1);
        assert!((learning_rate(1.0, 55, 10, true, 100) - 0.5).abs() < 1e-9);
    }
}

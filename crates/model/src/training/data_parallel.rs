//! Data-parallel training on several devices (`diffkfc train --devices cuda:0,cuda:1`): one
//! replica of the model and its optimiser per device, each on its own thread, each taking a
//! shard of the step's batch (samples `[k B / K, (k + 1) B / K)`, with that slice of the step's
//! timesteps, noise and dropout masks, so K devices see exactly the one-device step's draws).
//! Each shard's loss terms are weighted by its share of the batch's counts
//! (`parallel::shard_objective`), so the sum of the shards' gradients is the one-device gradient.
//!
//! The sum is Burn 0.22's own: every parameter of a replica is marked distributed, and `backward`
//! all-reduces its gradient across the devices (NCCL, CUDA only in Burn 0.22). The replicas then
//! take the same clipped Adam step from the same gradient, so they stay identical; replica 0's
//! weights, EMA and moments are what validation reads and checkpoints store, in the one-device
//! format. The CPU backends have no all-reduce; there the tests run this whole path with the
//! gradients summed through host memory instead (`GradSum::Host`).

use std::ops::Range;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Barrier, Mutex};

use burn::module::{ModuleMapper, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::distributed::{DistributedConfig, DistributedContext, ReduceOperation};
use diffkfc_data::dataset::batch::Batch;

use crate::error::{ModelError, Result};
use crate::network::params;
use crate::run::config::RunConfig;
use crate::training::optim::{Optimiser, StateLocation};
use crate::training::parallel::Counts;
use crate::Denoiser;

/// How the replicas' gradients are summed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GradSum {
    /// Parameters marked distributed: Burn sums every gradient across the devices during
    /// `backward` (Burn 0.22: CUDA, through NCCL).
    Burn,
    /// Gradients summed through host memory after `backward`: the stand-in the tests use on the
    /// CPU, where Burn has no all-reduce. Not offered by the command line.
    #[doc(hidden)]
    Host,
}

/// The devices of a data-parallel run and how their gradients are summed.
#[derive(Clone, Debug)]
pub struct DataParallel {
    devices: Vec<Device>,
    sum: GradSum,
}

/// Whether Burn 0.22 can all-reduce gradients on `device` (CUDA only; its wgpu and CPU backends
/// have no collective operations).
pub fn supports_all_reduce(device: &Device) -> bool {
    #[cfg(feature = "cuda")]
    if let burn::backend::DispatchDevice::Cube(d) = device.as_dispatch().clone().inner() {
        return matches!(d, burn::cubecl::Device::Cuda(_));
    }
    let _ = device;
    false
}

impl DataParallel {
    /// The devices named by `--devices`: two or more, each one Burn can all-reduce on, none twice.
    pub fn new(devices: Vec<Device>) -> Result<DataParallel> {
        let dp = DataParallel { devices, sum: GradSum::Burn };
        dp.check_count()?;
        for (i, d) in dp.devices.iter().enumerate() {
            if !supports_all_reduce(d) {
                return Err(ModelError::Config(format!(
                    "device {} ({d:?}) cannot all-reduce gradients: Burn 0.22 implements data-parallel training for CUDA devices only (a build with --features cuda); train on one device with --device",
                    i + 1
                )));
            }
            if dp.devices[..i].contains(d) {
                return Err(ModelError::Config(format!("device {} ({d:?}) is named twice", i + 1)));
            }
        }
        Ok(dp)
    }

    /// Replicas on any backend, the same device allowed more than once, with their gradients
    /// summed on the host (tests only).
    #[doc(hidden)]
    pub fn host_sum(devices: Vec<Device>) -> Result<DataParallel> {
        let dp = DataParallel { devices, sum: GradSum::Host };
        dp.check_count()?;
        Ok(dp)
    }

    fn check_count(&self) -> Result<()> {
        if self.devices.len() < 2 {
            return Err(ModelError::Config(
                "data-parallel training needs two or more devices (for one, use --device)".into(),
            ));
        }
        Ok(())
    }

    pub fn devices(&self) -> &[Device] {
        &self.devices
    }

    pub fn sum(&self) -> GradSum {
        self.sum
    }

    /// One replica per device, each with `snap`'s weights and optimiser state on its device
    /// (marked distributed for Burn's all-reduce), and the communication context that must
    /// outlive them.
    pub(crate) fn replicas(
        &self,
        cfg: &RunConfig,
        snap: crate::training::optim::Snapshot,
    ) -> (Vec<Replica>, Option<DistributedContext>) {
        let ctx = (self.sum == GradSum::Burn).then(|| {
            let config = DistributedConfig { all_reduce_op: ReduceOperation::Sum };
            DistributedContext::init(self.devices.clone(), config)
        });
        let reps = self
            .devices
            .iter()
            .map(|d| {
                let device = d.clone().autodiff();
                let init = cfg.model.init(&device);
                let (mut model, optim) =
                    Optimiser::restore(init, snap.clone(), StateLocation::Device);
                if self.sum == GradSum::Burn {
                    model = model.map(&mut MarkDistributed);
                }
                Replica::new(device, model, optim)
            })
            .collect();
        (reps, ctx)
    }
}

/// Marks every parameter distributed: `backward` then all-reduces its gradient.
struct MarkDistributed;
impl ModuleMapper for MarkDistributed {
    fn map_float<const D: usize>(&mut self, p: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, t, mapper) = p.consume();
        Param::from_mapped_value(id, t.set_distributed(id), mapper)
    }
}

/// The samples of each of `shards` shards of a `batch`-sample batch (the last may be shorter).
pub fn shard_ranges(batch: usize, shards: usize) -> Vec<Range<usize>> {
    let per = batch.div_ceil(shards.max(1)).max(1);
    (0..batch).step_by(per).map(|s| s..(s + per).min(batch)).collect()
}

/// A model and its optimiser on one (autodiff) device.
pub(crate) struct Replica {
    pub device: Device,
    model: Option<Denoiser>,
    pub optim: Optimiser,
}

impl Replica {
    pub fn new(device: Device, model: Denoiser, optim: Optimiser) -> Replica {
        Replica { device, model: Some(model), optim }
    }

    pub fn model(&self) -> &Denoiser {
        self.model.as_ref().expect("a replica holds its model between steps")
    }

    /// Backward of `objective`, the gradients summed over the replicas by `host` (None: not at
    /// all, or by Burn inside `backward`), clipping and Adam, then the EMA at `decay` when the
    /// gradient norm is finite. Returns the norm before clipping.
    pub fn descend(
        &mut self,
        objective: Tensor<1>,
        (clip, lr, decay): (f64, f64, f64),
        host: Option<&HostSum>,
    ) -> f64 {
        let model = self.model.take().expect("a replica holds its model between steps");
        let (model, norm) = match host {
            None => self.optim.descend(model, objective, clip, lr),
            Some(h) => {
                let own = GradientsParams::from_grads(objective.backward(), &model);
                let total = h.sum(params::grads(&model, &own));
                let grads = params::gradients(&model, &total);
                self.optim.apply(model, grads, clip, lr)
            }
        };
        if norm.is_finite() {
            self.optim.update_ema(&model, decay);
        }
        self.model = Some(model);
        norm
    }
}

/// Gradients summed through host memory, once per step by every replica (`GradSum::Host`).
pub(crate) struct HostSum {
    total: Mutex<Vec<Vec<f32>>>,
    barrier: Barrier,
}

impl HostSum {
    pub fn new(replicas: usize) -> HostSum {
        HostSum { total: Mutex::new(Vec::new()), barrier: Barrier::new(replicas) }
    }

    /// Adds this replica's gradients and, once every replica has, returns the sum.
    fn sum(&self, own: Vec<Vec<f32>>) -> Vec<Vec<f32>> {
        {
            let mut t = self.total.lock().expect("no replica panics holding the sum");
            if t.is_empty() {
                *t = own;
            } else {
                t.iter_mut()
                    .zip(own)
                    .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x += y));
            }
        }
        self.barrier.wait();
        self.total.lock().expect("no replica panics holding the sum").clone()
    }
}

/// One shard of a step: its samples, timesteps and noise, and its counts beside the batch's.
pub(crate) struct Shard<'a> {
    pub batch: Batch,
    pub first: usize,
    pub t: &'a [usize],
    pub noise: &'a [f32],
    pub mine: Counts,
    pub all: Counts,
    pub shards: usize,
}

/// The shards of a step's batch `b` with timesteps `t` and noise `noise` ([B * N * D]).
pub(crate) fn shards<'a>(b: &Batch, t: &'a [usize], noise: &'a [f32], k: usize) -> Vec<Shard<'a>> {
    let per_sample = b.frames * b.dim;
    let ranges = shard_ranges(b.batch_size, k);
    let parts: Vec<Batch> = ranges.iter().map(|r| b.shard(r.clone())).collect();
    let counts: Vec<Counts> = parts.iter().map(Counts::of).collect();
    let all = Counts::sum(&counts);
    let shards = ranges.len();
    parts
        .into_iter()
        .zip(ranges)
        .zip(counts)
        .map(|((batch, r), mine)| Shard {
            batch,
            first: r.start,
            t: &t[r.clone()],
            noise: &noise[r.start * per_sample..r.end * per_sample],
            mine,
            all,
            shards,
        })
        .collect()
}

/// Runs `forward` on every replica's thread with its shard; when every replica's loss is finite
/// (all wait for all), `descend` follows on the same threads. Returns each replica's forward
/// result and, where it descended, its gradient norm. A replica that panics in `forward` stops
/// every replica before the backward pass and is reported as an error.
pub(crate) fn on_replicas<T: Send>(
    reps: &mut [Replica],
    shards: &[Shard],
    forward: &(dyn Fn(&Replica, &Shard) -> (Tensor<1>, T, bool) + Sync),
    descend: &(dyn Fn(&mut Replica, Tensor<1>) -> f64 + Sync),
) -> Result<Vec<(T, Option<f64>)>> {
    if shards.len() != reps.len() {
        return Err(ModelError::Config(format!(
            "a batch of {} shards for {} devices: training.batch_size must be at least the number of devices",
            shards.len(),
            reps.len()
        )));
    }
    let go = AtomicBool::new(true);
    let barrier = Barrier::new(reps.len());
    let outs: Vec<Option<(T, Option<f64>)>> = std::thread::scope(|s| {
        let handles: Vec<_> = reps
            .iter_mut()
            .zip(shards)
            .map(|(r, shard)| {
                let (go, barrier) = (&go, &barrier);
                s.spawn(move || {
                    let fwd = catch_unwind(AssertUnwindSafe(|| forward(r, shard)));
                    if !matches!(fwd, Ok((_, _, true))) {
                        go.store(false, Ordering::SeqCst);
                    }
                    barrier.wait();
                    let (obj, out, _) = fwd.ok()?;
                    let norm = go.load(Ordering::SeqCst).then(|| descend(r, obj));
                    Some((out, norm))
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().ok().flatten()).collect()
    });
    outs.into_iter().collect::<Option<Vec<_>>>().ok_or_else(|| {
        ModelError::Config("a data-parallel replica failed in its forward pass".into())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_the_batch_in_order() {
        assert_eq!(shard_ranges(12, 3), vec![0..4, 4..8, 8..12]);
        assert_eq!(shard_ranges(5, 2), vec![0..3, 3..5]);
        assert_eq!(shard_ranges(2, 4), vec![0..1, 1..2]);
    }

    #[test]
    fn the_cpu_backends_are_refused() {
        let one = DataParallel::new(vec![Device::flex()]).unwrap_err().to_string();
        assert!(one.contains("two or more devices"), "{one}");
        let cpu = DataParallel::new(vec![Device::flex(), Device::flex()]).unwrap_err().to_string();
        assert!(cpu.contains("device 1") && cpu.contains("CUDA devices only"), "{cpu}");
        assert!(DataParallel::host_sum(vec![Device::flex(), Device::flex()]).is_ok());
    }
}

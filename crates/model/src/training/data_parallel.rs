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
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Barrier, Mutex};

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
pub(crate) struct Shard {
    pub batch: Batch,
    pub first: usize,
    t: Arc<Vec<usize>>,
    noise: Arc<Vec<f32>>,
    pub mine: Counts,
    pub all: Counts,
    pub shards: usize,
}

impl Shard {
    pub fn t(&self) -> &[usize] {
        &self.t[self.first..self.first + self.batch.batch_size]
    }

    /// [b * N * D]
    pub fn noise(&self) -> &[f32] {
        let per = self.batch.frames * self.batch.dim;
        &self.noise[self.first * per..(self.first + self.batch.batch_size) * per]
    }
}

/// The `k` shards of a step's batch `b` with its timesteps `t` and noise ([B * N * D]); one
/// shard is the batch itself, not a copy.
pub(crate) fn shards(b: Batch, t: Vec<usize>, noise: Vec<f32>, k: usize) -> Vec<Shard> {
    let ranges = shard_ranges(b.batch_size, k);
    let parts: Vec<Batch> = if ranges.len() == 1 {
        vec![b]
    } else {
        ranges.iter().map(|r| b.shard(r.clone())).collect()
    };
    let counts: Vec<Counts> = parts.iter().map(Counts::of).collect();
    let all = Counts::sum(&counts);
    let (t, noise, shards) = (Arc::new(t), Arc::new(noise), ranges.len());
    parts
        .into_iter()
        .zip(ranges)
        .zip(counts)
        .map(|((batch, r), mine)| Shard {
            batch,
            first: r.start,
            t: t.clone(),
            noise: noise.clone(),
            mine,
            all,
            shards,
        })
        .collect()
}

/// What the replicas of one step share: whether every forward pass gave a finite loss (no
/// replica starts its backward pass before all know), and the host sum of `GradSum::Host`.
pub(crate) struct StepSync {
    go: AtomicBool,
    barrier: Barrier,
    pub host: Option<HostSum>,
}

impl StepSync {
    pub fn new(replicas: usize, host_sum: bool) -> StepSync {
        StepSync {
            go: AtomicBool::new(true),
            barrier: Barrier::new(replicas),
            host: host_sum.then(|| HostSum::new(replicas)),
        }
    }

    /// This replica's forward pass went well or not; once every replica has said, whether all did.
    pub fn arrive(&self, ok: bool) -> bool {
        if !ok {
            self.go.store(false, Ordering::SeqCst);
        }
        self.barrier.wait();
        self.go.load(Ordering::SeqCst)
    }
}

/// One replica's part of a step: Some((its forward's result, its gradient norm when every
/// replica descended)), None when its forward pass panicked.
pub(crate) type ReplicaPart<T> = Option<(T, Option<f64>)>;

type ReplicaJob<'s> = Box<dyn FnOnce(&mut Replica) + Send + 's>;

/// What `Workers::each` runs on every replica.
pub(crate) type EachFn<'s, P, T> = Arc<dyn Fn(&mut Replica, P) -> T + Send + Sync + 's>;

/// The replicas of a run, each owned by its own thread for the whole run (CubeCL keeps a stream
/// per thread: a replica's tensors stay on one), running the jobs sent to them.
pub(crate) struct Workers<'s> {
    jobs: Vec<mpsc::Sender<ReplicaJob<'s>>>,
}

impl<'s> Workers<'s> {
    pub fn spawn<'e>(scope: &'s std::thread::Scope<'s, 'e>, reps: Vec<Replica>) -> Workers<'s> {
        let jobs = reps
            .into_iter()
            .map(|mut r| {
                let (tx, rx) = mpsc::channel::<ReplicaJob<'s>>();
                scope.spawn(move || rx.into_iter().for_each(|job| job(&mut r)));
                tx
            })
            .collect();
        Workers { jobs }
    }

    pub fn len(&self) -> usize {
        self.jobs.len()
    }

    /// `f(replica, payload)` on every replica's thread, payload k to replica k; the results in
    /// replica order, or an error when a replica's thread is gone.
    pub fn each<P, T>(&self, payloads: Vec<P>, f: EachFn<'s, P, T>) -> Result<Vec<T>>
    where
        P: Send + 's,
        T: Send + 's,
    {
        let (tx, rx) = mpsc::channel();
        for (k, (jobs, p)) in self.jobs.iter().zip(payloads).enumerate() {
            let (tx, f) = (tx.clone(), f.clone());
            let job: ReplicaJob<'s> = Box::new(move |r| {
                let _ = tx.send((k, f(r, p)));
            });
            jobs.send(job).map_err(|_| gone())?;
        }
        drop(tx);
        let mut out: Vec<(usize, T)> = rx.iter().collect();
        if out.len() != self.jobs.len() {
            return Err(gone());
        }
        out.sort_by_key(|(k, _)| *k);
        Ok(out.into_iter().map(|(_, t)| t).collect())
    }

    /// `f(replica 0)` on its thread (validation and checkpoints read replica 0).
    pub fn first<T: Send + 's>(&self, f: impl FnOnce(&mut Replica) -> T + Send + 's) -> Result<T> {
        let (tx, rx) = mpsc::channel();
        let job: ReplicaJob<'s> = Box::new(move |r| {
            let _ = tx.send(f(r));
        });
        self.jobs[0].send(job).map_err(|_| gone())?;
        rx.recv().map_err(|_| gone())
    }
}

fn gone() -> ModelError {
    ModelError::Config("a data-parallel replica's thread stopped (it panicked)".into())
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

//! Training: the loop (`trainer`), batches as tensors, the losses and the differentiable
//! kinematics they read, the optimiser and EMA, data-parallel training (replicas, the shard loss
//! weighting), memory estimates and device memory, the reconstruction terms' weights, and warm starts from another run's weights.

pub(crate) mod batch;
pub mod data_parallel;
pub(crate) mod kinematics;
pub(crate) mod losses;
pub mod memory;
pub mod optim;
pub mod parallel;
pub mod rollout;
pub(crate) mod run_files;
pub mod trainer;
pub(crate) mod warm_start;
pub mod weighting;

//! Test support shared by the crates' tests: the real-data fixtures, a bounded fuzzer, all-pairs covers for combination tests and the foot post-processes' motions and checks.

pub mod feet;
pub mod fixtures;
pub mod fuzz;
pub mod pairwise;

//! Test support shared by the crates' tests: the real-data fixtures, a bounded fuzzer and all-pairs covers for combination tests.

pub mod fixtures;
pub mod fuzz;
pub mod pairwise;

//! Test support shared by the crates' tests: the real-data fixtures and a bounded fuzzer.

pub mod fixtures;
pub mod fuzz;

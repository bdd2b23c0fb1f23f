pub mod bench;
pub mod data;
pub mod eval;
pub mod model;
pub mod render;
pub mod sample;
pub mod serve;
pub mod train;

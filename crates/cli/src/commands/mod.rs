pub mod data;
pub mod model;
pub mod render;
pub mod train;

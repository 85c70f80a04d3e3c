pub mod engine;
pub mod frame;
pub mod geometry;

pub mod can;
pub mod decision;
pub mod engine;
pub mod frame;
pub mod geometry;

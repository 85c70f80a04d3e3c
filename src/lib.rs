pub mod geometry;
pub mod mock;

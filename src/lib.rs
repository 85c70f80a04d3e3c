pub mod can;
pub mod geometry;

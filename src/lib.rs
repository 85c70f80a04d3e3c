pub mod can;
pub mod decision;
pub mod geometry;

pub mod calib;
pub mod dataset;
pub mod geometry;

pub mod calib;
pub mod geometry;

pub mod calib;
pub mod can;
pub mod dataset;
pub mod decision;
pub mod engine;
pub mod frame;
pub mod geometry;
pub mod source;

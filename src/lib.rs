pub mod bench;
pub mod calib;
pub mod can;
pub mod capture;
pub mod config;
pub mod daemon;
pub mod dataset;
pub mod decision;
pub mod engine;
pub mod frame;
pub mod geometry;
pub mod isa;
pub mod logging;
pub mod mock;
pub mod replay;
pub mod source;
#[cfg(test)]
mod test_support;

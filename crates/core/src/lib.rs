//! flyd's pure core: everything that takes values and returns values.
//!
//! Camera geometry and calibration files, prepared frames, the Fly Algorithm engine, the
//! CLEAR/SLOW/STOP decision and the CAN protocol (encoding, E2E protection, the DBC contract).
//! No device, thread, socket or service manager: this crate's dependencies hold none (the
//! runtime crate, `flyd`, brings them), so the engine and the decision are testable and
//! reproducible without hardware. Time comes in as values or through an injected [`clock::Clock`].

#[macro_use]
mod macros;

pub mod calib;
pub mod can;
pub mod chain;
pub mod clock;
pub mod dataset;
pub mod decision;
pub mod engine;
pub mod faults;
pub mod frame;
pub mod frame_step;
pub mod geometry;
pub mod isa;
pub mod kinematics;
pub mod pairing;
pub mod path;
pub mod perception;
pub mod policy;
pub mod rectification;
pub mod road_plane;
pub mod sensor;
pub mod status;
#[cfg(any(test, feature = "test-support"))]
pub mod test_support;
pub mod textfile;
pub mod toml_key;

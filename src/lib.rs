//! flyd's runtime: the threaded daemon and its edges (V4L2 cameras, SocketCAN, systemd, logs),
//! the hw-mock hardware, and the commands (`replay`, `bench`). The pure logic it drives (engine,
//! decision, CAN protocol, geometry) is the `flyd_core` crate; the `flyd` binary is glue.

pub mod bench;
pub mod bus;
pub mod capture;
pub mod config;
pub mod daemon;
pub mod eval;
pub mod logging;
pub mod mock;
pub mod os_clock;
pub mod path_bench;
pub mod record;
pub mod replay;
pub mod source;
pub mod thread;

//! What the recorder is asked to do (the resolved `[record]` and `[live]` tables) and how it
//! fails to start: shared by the writer thread, the MCAP files and the live server.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// Where and how to record (the resolved `[record]` and `[live]` tables).
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The MCAP file (`None`: the live view only).
    pub path: Option<PathBuf>,
    pub rotate_bytes: Option<u64>,
    pub rotate_after: Option<Duration>,
    pub compression: bool,
    pub live: Option<LiveOptions>,
    /// Attached as `config.toml`.
    pub config_text: Option<String>,
    /// flyd's metadata record.
    pub metadata: BTreeMap<String, String>,
}

/// The live view (`[live]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveOptions {
    pub listen: SocketAddr,
    /// At most one image per camera, and one population, this often.
    pub image_period: Duration,
    pub flies_period: Duration,
}

#[derive(Debug, thiserror::Error)]
pub enum WriterError {
    #[error("recording {path}")]
    Open {
        path: String,
        #[source]
        error: mcap::McapError,
    },
    #[error("recording {path}")]
    Create {
        path: String,
        #[source]
        error: std::io::Error,
    },
    #[error("live view on {listen}")]
    Live {
        listen: SocketAddr,
        #[source]
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("cannot start thread flyd-record")]
    Spawn(#[source] std::io::Error),
}

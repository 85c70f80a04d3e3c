//! The raw `[record]` and `[live]` tables: the recording's file, rotation and compression, the
//! Foxglove live server's address.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use super::{Invalid, bad};
use crate::config::{LiveConfig, RecordConfig};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawRecord {
    path: Option<PathBuf>,
    rotate_mb: f64,
    rotate_s: f64,
    images: bool,
    flies_every: u64,
    queue: usize,
    compression: RawCompression,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RawCompression {
    Zstd,
    None,
}

impl Default for RawRecord {
    fn default() -> Self {
        let d = RecordConfig::default();
        Self {
            path: None,
            rotate_mb: 0.0,
            rotate_s: 0.0,
            images: d.images,
            flies_every: d.flies_every,
            queue: d.queue,
            compression: RawCompression::Zstd,
        }
    }
}

impl RawRecord {
    pub(super) fn resolve(self, base: &Path) -> Result<RecordConfig, Invalid> {
        let optional = |key: &str, v: f64, lo: f64, hi: f64| -> Result<Option<f64>, Invalid> {
            if v == 0.0 {
                Ok(None)
            } else if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(Some(v))
            } else {
                bad(
                    key,
                    format!("must be 0 (never) or within {lo}..={hi}, got {v}"),
                )
            }
        };
        let rotate_mb = optional("record.rotate_mb", self.rotate_mb, 16.0, 1e6)?;
        let rotate_s = optional("record.rotate_s", self.rotate_s, 10.0, 86_400.0)?;
        if !(1..=10_000).contains(&self.flies_every) {
            return bad("record.flies_every", "must be within 1..=10000 generations");
        }
        if !(16..=65_536).contains(&self.queue) {
            return bad("record.queue", "must be within 16..=65536 records");
        }
        if let Some(path) = &self.path
            && path.as_os_str().is_empty()
        {
            return bad("record.path", "must name a file");
        }
        Ok(RecordConfig {
            path: self
                .path
                .map(|p| if p.is_absolute() { p } else { base.join(p) }),
            rotate_bytes: rotate_mb.map(|mb| (mb * 1e6) as u64),
            rotate_after: rotate_s.map(Duration::from_secs_f64),
            images: self.images,
            flies_every: self.flies_every,
            queue: self.queue,
            compression: self.compression == RawCompression::Zstd,
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawLive {
    listen: Option<String>,
    image_hz: f64,
    flies_hz: f64,
}

impl Default for RawLive {
    fn default() -> Self {
        let d = LiveConfig::default();
        Self {
            listen: None,
            image_hz: d.image_hz,
            flies_hz: d.flies_hz,
        }
    }
}

impl RawLive {
    pub(super) fn resolve(self) -> Result<LiveConfig, Invalid> {
        for (key, hz) in [
            ("live.image_hz", self.image_hz),
            ("live.flies_hz", self.flies_hz),
        ] {
            if !(hz.is_finite() && (0.1..=30.0).contains(&hz)) {
                return bad(key, format!("must be within 0.1..=30 per second, got {hz}"));
            }
        }
        let listen = match self.listen {
            None => None,
            Some(text) => match text.parse::<std::net::SocketAddr>() {
                Ok(addr) => Some(addr),
                Err(_) => {
                    return bad(
                        "live.listen",
                        format!(
                            "must be an address and port such as \"127.0.0.1:8765\", got \"{}\"",
                            text.escape_debug()
                        ),
                    );
                }
            },
        };
        Ok(LiveConfig {
            listen,
            image_hz: self.image_hz,
            flies_hz: self.flies_hz,
        })
    }
}

//! Reading a recording back (`flyd replay --mcap`): its configuration, its events and its
//! frames.
//!
//! The file is read into memory once (a recording's parts keep it bounded: `record.rotate_mb`);
//! events are collected in one pass ([`Recording::events`]), frames streamed in file order in
//! another ([`Recording::frames`]), so only a few decoded frames are alive at a time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use foxglove::Decode;
use foxglove::schemas::RawImage;

use super::topics::{CanEvent, DecisionEvent, PairEvent, PerceptionEvent, Topic};
use crate::daemon::pairer::Side;
use flyd_core::frame::PixelFormat;

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        error: std::io::Error,
    },
    #[error("{path}: not a readable MCAP recording")]
    Mcap {
        path: PathBuf,
        #[source]
        error: mcap::McapError,
    },
    #[error("{path}: message {sequence} on {topic} does not decode")]
    Json {
        path: PathBuf,
        topic: &'static str,
        sequence: u32,
        #[source]
        error: serde_json::Error,
    },
    #[error("{path}: image {sequence} on {topic} does not decode")]
    Image {
        path: PathBuf,
        topic: &'static str,
        sequence: u32,
        #[source]
        error: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// A control-thread event, in the thread's order ([`ControlEvent::seq`]).
#[derive(Debug, Clone, PartialEq)]
pub enum ControlEvent {
    Perception(PerceptionEvent),
    Decision(DecisionEvent),
    Received(CanEvent),
}

impl ControlEvent {
    pub fn seq(&self) -> u64 {
        match self {
            ControlEvent::Perception(e) => e.seq,
            ControlEvent::Decision(e) => e.seq,
            ControlEvent::Received(e) => e.seq,
        }
    }
}

/// Everything but the images, in order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Events {
    /// By generation.
    pub pairs: Vec<PairEvent>,
    /// By control-thread sequence number.
    pub control: Vec<ControlEvent>,
    /// Frames sent, in order.
    pub sent: Vec<CanEvent>,
    /// Images per camera.
    pub images: [u64; 2],
}

/// A recorded frame: what the capture thread prepared.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub side: Side,
    pub timestamp_ns: u64,
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

pub struct Recording {
    path: PathBuf,
    data: Vec<u8>,
}

impl Recording {
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let data = std::fs::read(path).map_err(|error| ReadError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            data,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn mcap_err(&self, error: mcap::McapError) -> ReadError {
        ReadError::Mcap {
            path: self.path.clone(),
            error,
        }
    }

    fn summary(&self) -> Result<mcap::Summary, ReadError> {
        mcap::Summary::read(&self.data)
            .map_err(|e| self.mcap_err(e))?
            .ok_or_else(|| self.mcap_err(mcap::McapError::UnexpectedEof))
    }

    /// The configuration the daemon ran with (`config.toml` attachment).
    pub fn config_text(&self) -> Result<Option<String>, ReadError> {
        let summary = self.summary()?;
        for index in &summary.attachment_indexes {
            if index.name == "config.toml" {
                let a = mcap::read::attachment(&self.data, index).map_err(|e| self.mcap_err(e))?;
                return Ok(Some(String::from_utf8_lossy(&a.data).into_owned()));
            }
        }
        Ok(None)
    }

    /// flyd's metadata record.
    pub fn metadata(&self) -> Result<BTreeMap<String, String>, ReadError> {
        let summary = self.summary()?;
        for index in &summary.metadata_indexes {
            if index.name == "flyd" {
                let m = mcap::read::metadata(&self.data, index).map_err(|e| self.mcap_err(e))?;
                return Ok(m.metadata);
            }
        }
        Ok(BTreeMap::new())
    }

    fn messages(&self) -> Result<mcap::MessageStream<'_>, ReadError> {
        mcap::MessageStream::new(&self.data).map_err(|e| self.mcap_err(e))
    }

    /// Every event but the images.
    pub fn events(&self) -> Result<Events, ReadError> {
        let mut events = Events::default();
        for message in self.messages()? {
            let message = message.map_err(|e| self.mcap_err(e))?;
            let Some(topic) = Topic::from_name(&message.channel.topic) else {
                continue;
            };
            let data = &message.data[..];
            match topic {
                Topic::LeftImage => events.images[0] += 1,
                Topic::RightImage => events.images[1] += 1,
                Topic::Pair => events.pairs.push(self.decode(topic, &message, data)?),
                Topic::Perception => events.control.push(ControlEvent::Perception(
                    self.decode(topic, &message, data)?,
                )),
                Topic::Decision => events
                    .control
                    .push(ControlEvent::Decision(self.decode(topic, &message, data)?)),
                Topic::CanRx => events
                    .control
                    .push(ControlEvent::Received(self.decode(topic, &message, data)?)),
                Topic::CanTx => events.sent.push(self.decode(topic, &message, data)?),
                _ => {}
            }
        }
        events.pairs.sort_by_key(|p| p.generation);
        events.control.sort_by_key(ControlEvent::seq);
        events.sent.sort_by_key(|e| e.seq);
        Ok(events)
    }

    fn decode<T: serde::de::DeserializeOwned>(
        &self,
        topic: Topic,
        message: &mcap::Message<'_>,
        data: &[u8],
    ) -> Result<T, ReadError> {
        serde_json::from_slice(data).map_err(|error| ReadError::Json {
            path: self.path.clone(),
            topic: topic.name(),
            sequence: message.sequence,
            error,
        })
    }

    /// The recorded frames, in file order (capture order per camera).
    pub fn frames(&self) -> Result<impl Iterator<Item = Result<Frame, ReadError>> + '_, ReadError> {
        Ok(self.messages()?.filter_map(move |message| {
            let message = match message {
                Ok(m) => m,
                Err(e) => return Some(Err(self.mcap_err(e))),
            };
            let (topic, side) = match Topic::from_name(&message.channel.topic) {
                Some(t @ Topic::LeftImage) => (t, Side::Left),
                Some(t @ Topic::RightImage) => (t, Side::Right),
                _ => return None,
            };
            Some(self.frame(topic, side, &message))
        }))
    }

    fn frame(
        &self,
        topic: Topic,
        side: Side,
        message: &mcap::Message<'_>,
    ) -> Result<Frame, ReadError> {
        let bad = |error: Box<dyn std::error::Error + Send + Sync>| ReadError::Image {
            path: self.path.clone(),
            topic: topic.name(),
            sequence: message.sequence,
            error,
        };
        let image = RawImage::decode(&message.data[..]).map_err(|e| bad(e.into()))?;
        let format = match image.encoding.as_str() {
            "rgb8" => PixelFormat::Rgb8,
            "mono8" => PixelFormat::Grey8,
            other => {
                return Err(bad(
                    format!("encoding {other}: flyd records rgb8 or mono8").into()
                ));
            }
        };
        let expected = image.width as usize * image.height as usize * format.bytes_per_pixel();
        if image.data.len() != expected || image.step as usize * image.height as usize != expected {
            return Err(bad(format!(
                "{} bytes for {}x{} {}",
                image.data.len(),
                image.width,
                image.height,
                image.encoding
            )
            .into()));
        }
        Ok(Frame {
            side,
            timestamp_ns: message.log_time,
            format,
            width: image.width,
            height: image.height,
            pixels: image.data.to_vec(),
        })
    }
}

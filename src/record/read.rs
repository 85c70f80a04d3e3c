//! Reading a recording back (`flyd replay --mcap`): its configuration, its events and its
//! frames.
//!
//! The file is mapped, not read into memory (a drive's recording is tens of GB); events are
//! collected in one pass ([`Recording::events`]), frames streamed in file order in another
//! ([`Recording::frames`]), so only a few decoded frames are alive at a time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use foxglove::Decode;

use foxglove::schemas::{CompressedImage, RawImage};

use super::topics::{CanEvent, DecisionEvent, PairEvent, PerceptionEvent, Topic};
use crate::source::Side;
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
    /// The packed pixels' format; `None`: `pixels` is an MJPEG camera's JPEG.
    pub format: Option<PixelFormat>,
    pub pixels: Vec<u8>,
}

pub struct Recording {
    path: PathBuf,
    data: memmap2::Mmap,
}

impl Recording {
    /// Maps the file: a recording of a whole drive is larger than memory, and is read once,
    /// front to back, per pass.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let io = |error| ReadError::Io {
            path: path.to_path_buf(),
            error,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        // SAFETY: the map is only read. A recording is a finished file; were another process
        // to truncate it while it is replayed, reads past the new end would fault (SIGBUS),
        // which is why replay is run on recordings, never on the file a daemon writes.
        let data = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
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

    /// Whether the file ends as an MCAP file must (its footer and end magic): `false` for a
    /// recording cut short, which is read up to where it was cut.
    pub fn complete(&self) -> bool {
        mcap::read::footer(&self.data).is_ok()
    }

    /// The first record `pick` takes, in a linear scan from the start (where the writer puts
    /// the metadata and the attachment).
    fn scan<T>(&self, mut pick: impl FnMut(mcap::records::Record<'_>) -> Option<T>) -> Option<T> {
        let reader = mcap::read::LinearReader::new_with_options(
            &self.data,
            mcap::read::Options::IgnoreEndMagic.into(),
        )
        .ok()?;
        reader.map_while(Result::ok).find_map(&mut pick)
    }

    /// The configuration the daemon ran with (`config.toml` attachment).
    pub fn config_text(&self) -> Result<Option<String>, ReadError> {
        Ok(self.scan(|record| match record {
            mcap::records::Record::Attachment { header, data, .. }
                if header.name == "config.toml" =>
            {
                Some(String::from_utf8_lossy(&data).into_owned())
            }
            _ => None,
        }))
    }

    /// flyd's metadata record.
    pub fn metadata(&self) -> Result<BTreeMap<String, String>, ReadError> {
        Ok(self
            .scan(|record| match record {
                mcap::records::Record::Metadata(m) if m.name == "flyd" => Some(m.metadata),
                _ => None,
            })
            .unwrap_or_default())
    }

    fn messages(&self) -> Result<mcap::MessageStream<'_>, ReadError> {
        // A file cut short (a full disk, a killed daemon) is read as far as it goes: no end
        // magic or summary needed, and a torn last chunk ends the messages.
        mcap::MessageStream::new_with_options(
            &self.data,
            mcap::read::Options::IgnoreEndMagic.into(),
        )
        .map_err(|e| self.mcap_err(e))
    }

    /// A message error: the end of a recording cut short (`None`), or an error.
    fn cut_or(&self, error: mcap::McapError) -> Option<ReadError> {
        (self.complete()).then(|| self.mcap_err(error))
    }

    /// Every event but the images.
    pub fn events(&self) -> Result<Events, ReadError> {
        let mut events = Events::default();
        for message in self.messages()? {
            let message = match message {
                Ok(m) => m,
                Err(e) => match self.cut_or(e) {
                    Some(error) => return Err(error),
                    None => break,
                },
            };
            let Some(topic) = Topic::from_name(&message.channel.topic) else {
                continue;
            };
            let data = &message.data[..];
            match topic {
                Topic::LeftImage | Topic::LeftCompressed => events.images[0] += 1,
                Topic::RightImage | Topic::RightCompressed => events.images[1] += 1,
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
        let mut ended = false;
        Ok(self.messages()?.filter_map(move |message| {
            if ended {
                return None;
            }
            let message = match message {
                Ok(m) => m,
                Err(e) => {
                    // The end of a recording cut short, or an error (reported, then the end).
                    ended = true;
                    return self.cut_or(e).map(Err);
                }
            };
            let (topic, side) = match Topic::from_name(&message.channel.topic) {
                Some(t @ (Topic::LeftImage | Topic::LeftCompressed)) => (t, Side::Left),
                Some(t @ (Topic::RightImage | Topic::RightCompressed)) => (t, Side::Right),
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
        if matches!(topic, Topic::LeftCompressed | Topic::RightCompressed) {
            let image = CompressedImage::decode(&message.data[..]).map_err(|e| bad(e.into()))?;
            if image.format != "jpeg" {
                return Err(bad(
                    format!("format {}: flyd records jpeg", image.format).into()
                ));
            }
            return Ok(Frame {
                side,
                timestamp_ns: message.log_time,
                format: None,
                pixels: image.data.to_vec(),
            });
        }
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
            format: Some(format),
            pixels: image.data.to_vec(),
        })
    }
}

//! One MCAP file of a recording: opened with its channels, schemas, attachment and metadata,
//! written message by message, finished; and the name of each part after a rotation.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::options::{RecordOptions, WriterError};
use super::topics::{Encoding, Topic, foxglove_schema};

/// `drive.mcap` -> `drive.1.mcap`.
pub(super) fn part_path(base: &Path, part: u32) -> PathBuf {
    let stem = base.file_stem().map_or_else(
        || "recording".to_string(),
        |s| s.to_string_lossy().into_owned(),
    );
    base.with_file_name(format!("{stem}.{part}.mcap"))
}

/// One open MCAP file.
pub(super) struct McapFile {
    pub(super) path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    channels: [u16; Topic::ALL.len()],
    sequence: [u32; Topic::ALL.len()],
    /// Calibrations written in this file (each file carries them).
    calibrated: [bool; 2],
    pub(super) bytes: u64,
    pub(super) opened: Instant,
}

impl McapFile {
    pub(super) fn create(path: PathBuf, options: &RecordOptions) -> Result<Self, WriterError> {
        let shown = path.display().to_string();
        let open = |error| WriterError::Open {
            path: shown.clone(),
            error,
        };
        let file = File::create(&path).map_err(|error| WriterError::Create {
            path: shown.clone(),
            error,
        })?;
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .library(format!("flyd {}", env!("CARGO_PKG_VERSION")))
            .compression(options.compression.then_some(mcap::Compression::Zstd))
            .compression_level(1)
            .chunk_size(Some(4 << 20))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(open)?;
        let mut channels = [0; Topic::ALL.len()];
        for (i, topic) in Topic::ALL.into_iter().enumerate() {
            let (name, encoding, data, message_encoding) = match topic.encoding() {
                Encoding::Foxglove => {
                    let schema = foxglove_schema(topic);
                    (
                        schema.name,
                        schema.encoding,
                        schema.data.into_owned(),
                        "protobuf",
                    )
                }
                Encoding::Json => {
                    let (name, text) = topic.json_schema().unwrap_or(("", String::new()));
                    (
                        name.to_string(),
                        "jsonschema".to_string(),
                        text.into_bytes(),
                        "json",
                    )
                }
            };
            let schema = writer.add_schema(&name, &encoding, &data).map_err(open)?;
            channels[i] = writer
                .add_channel(schema, topic.name(), message_encoding, &BTreeMap::new())
                .map_err(open)?;
        }
        writer
            .write_metadata(&mcap::records::Metadata {
                name: "flyd".into(),
                metadata: options.metadata.clone(),
            })
            .map_err(open)?;
        if let Some(text) = &options.config_text {
            writer
                .attach(&mcap::Attachment {
                    log_time: 0,
                    create_time: 0,
                    name: "config.toml".into(),
                    media_type: "application/toml".into(),
                    data: std::borrow::Cow::Borrowed(text.as_bytes()),
                })
                .map_err(open)?;
        }
        Ok(Self {
            path,
            writer,
            channels,
            sequence: [0; Topic::ALL.len()],
            calibrated: [false; 2],
            bytes: 0,
            opened: Instant::now(),
        })
    }

    /// Whether this file still lacks the calibration of `topic`'s camera.
    pub(super) fn needs(&self, topic: Topic) -> bool {
        match topic {
            Topic::LeftCalibration => !self.calibrated[0],
            Topic::RightCalibration => !self.calibrated[1],
            _ => false,
        }
    }

    pub(super) fn write(
        &mut self,
        topic: Topic,
        t: u64,
        data: &[u8],
    ) -> Result<(), mcap::McapError> {
        let i = index(topic);
        self.sequence[i] = self.sequence[i].wrapping_add(1);
        self.writer.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: self.channels[i],
                sequence: self.sequence[i],
                log_time: t,
                publish_time: t,
            },
            data,
        )?;
        match topic {
            Topic::LeftCalibration => self.calibrated[0] = true,
            Topic::RightCalibration => self.calibrated[1] = true,
            _ => {}
        }
        self.bytes += data.len() as u64;
        Ok(())
    }

    pub(super) fn finish(mut self) -> Result<(), mcap::McapError> {
        self.writer.finish()?;
        let mut inner = self.writer.into_inner();
        std::io::Write::flush(&mut inner)?;
        inner
            .into_inner()
            .map_err(|e| mcap::McapError::Io(e.into_error()))?
            .sync_all()?;
        Ok(())
    }
}

pub(super) fn index(topic: Topic) -> usize {
    Topic::ALL.iter().position(|t| *t == topic).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_are_numbered_beside_the_first_file() {
        assert_eq!(
            part_path(Path::new("/var/lib/flyd/drive.mcap"), 2),
            PathBuf::from("/var/lib/flyd/drive.2.mcap")
        );
    }
}

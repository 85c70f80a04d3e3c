//! The daemon's recorder: started when `[record]` has a path or `[live]` listens, finished
//! (its writer joined) when the daemon ends.

use super::{DaemonError, RecordingReport};
use crate::config::DaemonConfig;

/// A running recorder: the handle the threads clone, and the writer thread.
pub(super) struct Recording {
    pub(super) recorder: crate::record::Recorder,
    writer: crate::record::writer::Writer,
}

impl Recording {
    pub(super) fn finish(self) -> Result<RecordingReport, DaemonError> {
        let Recording { recorder, writer } = self;
        let counters = recorder.counters().clone();
        drop(recorder);
        let report = writer.handle.join().map_err(|_| DaemonError::Panicked {
            thread: "flyd-record",
        })?;
        Ok(RecordingReport {
            writer: report,
            dropped: counters.dropped(),
            live: writer.live_addr,
        })
    }
}

/// Starts the recorder when `[record]` has a path or `[live]` listens.
pub(super) fn start_recording(
    config: &DaemonConfig,
    rig: &flyd_core::geometry::StereoRig,
) -> Result<Option<Recording>, DaemonError> {
    let (record, live) = (&config.record, &config.live);
    if record.path.is_none() && live.listen.is_none() {
        return Ok(None);
    }
    let (recorder, rx, returns) = crate::record::channel(crate::record::RecorderSizes {
        queue: record.queue,
        width: config.cameras.width,
        height: config.cameras.height,
        flies: config.engine.flies,
        images: record.images,
        flies_every: record.flies_every,
        fps: config.cameras.fps,
    });
    let config_text = config
        .file
        .as_deref()
        .and_then(|p| flyd_core::textfile::read(p).ok());
    let mut metadata = std::collections::BTreeMap::new();
    metadata.insert("flyd_version".into(), env!("CARGO_PKG_VERSION").into());
    metadata.insert("seed".into(), config.engine.seed.to_string());
    metadata.insert("flies".into(), config.engine.flies.to_string());
    metadata.insert("flies_every".into(), record.flies_every.to_string());
    metadata.insert("images".into(), record.images.to_string());
    if let Some(file) = &config.file {
        metadata.insert("config_path".into(), file.display().to_string());
    }
    let options = crate::record::RecordOptions {
        path: record.path.clone(),
        rotate_bytes: record.rotate_bytes,
        rotate_after: record.rotate_after,
        compression: record.compression,
        live: live.listen.map(|listen| crate::record::LiveOptions {
            listen,
            image_period: std::time::Duration::from_secs_f64(1.0 / live.image_hz),
            flies_period: std::time::Duration::from_secs_f64(1.0 / live.flies_hz),
        }),
        config_text,
        metadata,
    };
    let counters = recorder.counters().clone();
    let writer = crate::record::spawn_writer(options, rig, rx, returns, counters)?;
    if let Some(path) = &record.path {
        tracing::info!(file = %path.display(), images = record.images, "recording");
    }
    Ok(Some(Recording { recorder, writer }))
}

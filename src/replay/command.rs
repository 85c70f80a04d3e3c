//! `flyd replay`'s work once the command line is read: a prepared replay run into its output
//! folder (and, with `--record`, a recording of what it saw and decided), and a daemon's
//! recording replayed (`--mcap`, with `--record` a recording of the replay). `src/main.rs`
//! only turns the arguments into these calls and prints what they return.

use std::path::Path;

use flyd_core::geometry::StereoRig;

use super::recorded::{self, RecordedSummary};
use super::request::Prepared;
use super::{ReplayError, Summary, write_outputs};
use crate::config::{DaemonConfig, RecordConfig};
use crate::record::{OfflineRecorder, RecorderSizes, WriterError};

/// Runs `prepared` (its settings from `config`), writes its outputs to `out` and returns its
/// summary; with `record`, also a recording of the replay (`config_file`, the configuration it
/// came from, attached to it).
pub fn replay_to(
    mut prepared: Prepared,
    config: &DaemonConfig,
    out: &Path,
    record: Option<&Path>,
    config_file: Option<&Path>,
) -> Result<Summary, ReplayError> {
    let recorder = match record {
        Some(path) => Some(offline_recorder(
            path,
            prepared.feed.rig(),
            prepared.settings.params.flies,
            config_file,
            &[
                ("source", "flyd replay"),
                ("seed", &prepared.settings.params.seed.to_string()),
            ],
        )?),
        None => None,
    };
    prepared.settings.record = recorder.as_ref().map(|r| r.recorder.clone());
    let (run, reaction) = prepared.run(config)?;
    if let Some(recorder) = recorder {
        let report = recorder.finish()?;
        tracing::debug!(messages = report.messages, "replay recorded");
    }
    write_outputs(out, &run)?;
    Ok(Summary::of(&run, out, reaction))
}

/// The recorder of `flyd replay --record FILE`.
fn offline_recorder(
    path: &Path,
    rig: &StereoRig,
    flies: usize,
    config: Option<&Path>,
    metadata: &[(&str, &str)],
) -> Result<OfflineRecorder, WriterError> {
    let sizes = RecorderSizes {
        queue: 1024,
        width: rig.left.width().max(rig.right.width()),
        height: rig.left.height().max(rig.right.height()),
        flies,
        images: true,
        flies_every: RecordConfig::default().flies_every,
        fps: 30.0,
    };
    let config_text = config.and_then(|p| flyd_core::textfile::read(p).ok());
    let metadata = metadata
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    OfflineRecorder::start(path, rig, sizes, config_text, metadata)
}

/// `flyd replay --mcap PATH [--config C] [--seed S] [--record OUT]`: the recording replayed
/// ([`recorded::replay`]); with `record`, the replay recorded to that file.
pub fn replay_recording(
    path: &Path,
    config: Option<&Path>,
    seed: Option<u64>,
    record: Option<&Path>,
) -> Result<RecordedSummary, ReplayError> {
    let mut offline: Option<OfflineRecorder> = None;
    let mut start = |rig: &StereoRig, config: &DaemonConfig| {
        let Some(out) = record else {
            return Err(WriterError::Spawn(std::io::Error::other("no --record")));
        };
        let sizes = RecorderSizes {
            queue: 1024,
            width: config.cameras.width,
            height: config.cameras.height,
            flies: config.engine.flies,
            images: true,
            flies_every: config.record.flies_every,
            fps: config.cameras.fps,
        };
        let text = config
            .file
            .as_deref()
            .and_then(|p| flyd_core::textfile::read(p).ok());
        let metadata = [
            (
                "source".to_string(),
                format!("flyd replay --mcap {}", path.display()),
            ),
            ("seed".to_string(), config.engine.seed.to_string()),
        ]
        .into_iter()
        .collect();
        let r = OfflineRecorder::start(out, rig, sizes, text, metadata)?;
        let handle = r.recorder.clone();
        offline = Some(r);
        Ok(handle)
    };
    let start: Option<recorded::StartRecording<'_>> = record.is_some().then_some(&mut start as _);
    let summary = recorded::replay(path, config, seed, start)?;
    if let Some(r) = offline {
        r.finish()?;
    }
    Ok(summary)
}

//! The live view: a Foxglove WebSocket server on its own one-thread runtime (`flyd-live`),
//! the recording's channels, images and flies throttled; a slow client loses messages in the
//! server's bounded backlog, never stalls the writer.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use foxglove::{Encode, PartialMetadata};

use super::nanos;
use super::options::{LiveOptions, WriterError};
use super::topics::{Encoding, Topic, foxglove_schema};

/// The live view: a Foxglove WebSocket server and its channels.
pub(super) struct Live {
    runtime: tokio::runtime::Runtime,
    /// Holds the channels and the server's sinks (the channels only weakly refer to it).
    _context: Arc<foxglove::Context>,
    server: foxglove::WebSocketServerHandle,
    pub(super) addr: SocketAddr,
    channels: Vec<(Topic, Arc<foxglove::RawChannel>)>,
    options: LiveOptions,
    /// Last log time sent on the throttled topics: left, right, flies.
    last: [Option<u64>; 3],
}

impl Live {
    pub(super) fn start(options: LiveOptions) -> Result<Self, WriterError> {
        let listen = options.listen;
        let err =
            |error: Box<dyn std::error::Error + Send + Sync>| WriterError::Live { listen, error };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .max_blocking_threads(1)
            .thread_name("flyd-live")
            .enable_all()
            .build()
            .map_err(|e| err(e.into()))?;
        let context = foxglove::Context::new();
        let mut channels = Vec::new();
        for topic in Topic::ALL {
            let builder = context.channel_builder(topic.name());
            let builder = match topic.encoding() {
                Encoding::Foxglove => builder
                    .message_encoding("protobuf")
                    .schema(foxglove_schema(topic)),
                Encoding::Json => {
                    let (name, text) = topic.json_schema().unwrap_or(("", String::new()));
                    builder
                        .message_encoding("json")
                        .schema(foxglove::Schema::new(name, "jsonschema", text.into_bytes()))
                }
            };
            channels.push((topic, builder.build_raw().map_err(|e| err(e.into()))?));
        }
        let server = foxglove::WebSocketServer::new()
            .name(format!("flyd {}", env!("CARGO_PKG_VERSION")))
            .bind(listen.ip().to_string(), listen.port())
            .context(&context)
            .tokio_runtime(runtime.handle());
        let server = runtime
            .block_on(server.start())
            .map_err(|e| err(e.into()))?;
        let addr = SocketAddr::new(listen.ip(), server.port());
        if !listen.ip().is_loopback() {
            tracing::warn!(
                listen = %addr,
                "live view listens beyond this machine (live.listen is not a loopback \
                 address): anyone on that network sees the cameras"
            );
        }
        tracing::info!(listen = %addr, "live view: open ws://{addr} in Foxglove");
        Ok(Self {
            runtime,
            _context: context,
            server,
            addr,
            channels,
            options,
            last: [None; 3],
        })
    }

    /// Whether a throttled topic may send at `t` (and, if so, counts it as sent).
    pub(super) fn due(&mut self, topic: Topic, t: u64) -> bool {
        let (i, period) = match topic {
            Topic::LeftImage | Topic::LeftCompressed => (0, self.options.image_period),
            Topic::RightImage | Topic::RightCompressed => (1, self.options.image_period),
            Topic::Flies => (2, self.options.flies_period),
            _ => return true,
        };
        let period = nanos(period);
        match self.last[i] {
            Some(last) if t.saturating_sub(last) < period && t >= last => false,
            _ => {
                self.last[i] = Some(t);
                true
            }
        }
    }

    pub(super) fn channel(&self, topic: Topic) -> Option<&Arc<foxglove::RawChannel>> {
        self.channels
            .iter()
            .find(|(t, _)| *t == topic)
            .map(|(_, c)| c)
    }

    pub(super) fn log<T: Encode>(&self, topic: Topic, t: u64, msg: &T) {
        let Some(channel) = self.channel(topic) else {
            return;
        };
        if !channel.has_sinks() {
            return;
        }
        let mut data = Vec::new();
        if msg.encode(&mut data).is_ok() {
            self.log_bytes(topic, t, &data);
        }
    }

    pub(super) fn log_bytes(&self, topic: Topic, t: u64, data: &[u8]) {
        if let Some(channel) = self.channel(topic)
            && channel.has_sinks()
        {
            channel.log_with_meta(data, PartialMetadata { log_time: Some(t) });
        }
    }

    pub(super) fn stop(self) {
        let Live {
            runtime, server, ..
        } = self;
        runtime.block_on(server.stop().wait());
        runtime.shutdown_timeout(Duration::from_millis(500));
    }
}

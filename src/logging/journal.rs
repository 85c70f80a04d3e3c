//! The systemd journal's native protocol: one datagram an entry, every field its own.
//!
//! An entry holds `PRIORITY` (ERROR 3, WARN 4, INFO 6, DEBUG and TRACE 7), `MESSAGE` (the
//! event's sentence followed by its fields as `name=value`, as the terminal shows it: what
//! `journalctl -u flyd` prints), `SYSLOG_IDENTIFIER=flyd`, `TARGET`, `CODE_FILE`,
//! `CODE_LINE`, `FLYD_THREAD` (the named thread), and every field of the event as
//! `FLYD_<NAME>` (`journalctl -u flyd FLYD_DEVICE=/dev/video1`).
//!
//! Written here rather than with `tracing-journald`, which puts only the `message` field in
//! `MESSAGE` (`journalctl -u flyd` would show "stats" and "decision changed" without a figure),
//! has no thread name, and sends on a blocking socket: a stalled journald would stall the
//! control thread. This socket never blocks: an entry the journal cannot take now is counted
//! and the count is written with the next entry it takes. If the socket disappears (journald
//! stopped), entries go to the fallback writer (JSON lines on stdout), which says so once.
//!
//! [`stream_is_journal`] tells whether stdout or stderr is the stream systemd connected to the
//! journal (`$JOURNAL_STREAM`, "device:inode", as `sd_journal_stream_fd` users compare it).

use std::cell::RefCell;
use std::fmt;
use std::io::{self, Write as _};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_core::callsite::Callsite;
use tracing_core::field::Value;
use tracing_subscriber::layer::{Context, Layer};

/// Where journald listens for native entries.
pub const SOCKET: &str = "/run/systemd/journal/socket";

/// The prefix of flyd's own journal fields.
pub const FIELD_PREFIX: &str = "FLYD_";

/// Whether `journal_stream` (the value of `$JOURNAL_STREAM`) names the file `dev`:`ino`.
pub fn stream_is_journal(journal_stream: Option<&str>, dev: u64, ino: u64) -> bool {
    let Some((d, i)) = journal_stream.and_then(|s| s.trim().split_once(':')) else {
        return false;
    };
    d.parse() == Ok(dev) && i.parse() == Ok(ino)
}

/// Whether `fd` (stdout or stderr) is the stream systemd connected to the journal.
pub fn fd_is_journal(fd: std::os::fd::BorrowedFd<'_>) -> bool {
    use std::os::unix::fs::MetadataExt;
    let Ok(env) = std::env::var("JOURNAL_STREAM") else {
        return false;
    };
    let Ok(owned) = fd.try_clone_to_owned() else {
        return false;
    };
    std::fs::File::from(owned)
        .metadata()
        .is_ok_and(|m| stream_is_journal(Some(&env), m.dev(), m.ino()))
}

/// The journal writer, with `F` (JSON lines on stdout) for when the journal is gone.
pub struct Journal<F> {
    socket: UnixDatagram,
    path: PathBuf,
    fallback: F,
    /// Entries the journal did not take (busy), not yet reported.
    dropped: AtomicU64,
    /// The socket went away: everything goes to the fallback from then on.
    gone: AtomicBool,
}

thread_local! {
    /// The entry being encoded: reused, so that a line costs no allocation once warm.
    static ENTRY: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
}

impl<F> Journal<F> {
    /// Connects to journald at [`SOCKET`]; fails if nothing listens there.
    pub fn connect(fallback: F) -> io::Result<Self> {
        Self::connect_to(Path::new(SOCKET), fallback)
    }

    /// Connects to a journal socket at `path` (a test's own).
    pub fn connect_to(path: &Path, fallback: F) -> io::Result<Self> {
        let socket = UnixDatagram::unbound()?;
        socket.set_nonblocking(true)?;
        // journald discards an empty datagram; an error here means nobody listens.
        socket.send_to(&[], path)?;
        Ok(Self {
            socket,
            path: path.to_path_buf(),
            fallback,
            dropped: AtomicU64::new(0),
            gone: AtomicBool::new(false),
        })
    }

    fn send(&self, entry: &[u8]) -> io::Result<()> {
        self.socket.send_to(entry, &self.path).map(|_| ())
    }

    /// Writes the count of entries the journal did not take, if any, before the next one.
    fn report_dropped(&self) {
        let n = self.dropped.swap(0, Ordering::AcqRel);
        if n == 0 {
            return;
        }
        let mut entry = Vec::new();
        put(&mut entry, "PRIORITY", b"4");
        put(&mut entry, "SYSLOG_IDENTIFIER", b"flyd");
        put(&mut entry, "TARGET", b"flyd::logging");
        let message = format!("{n} log entries not written: the journal was busy");
        put(&mut entry, "MESSAGE", message.as_bytes());
        put(&mut entry, "FLYD_DROPPED", n.to_string().as_bytes());
        if self.send(&entry).is_err() {
            self.dropped.fetch_add(n, Ordering::AcqRel);
        }
    }
}

impl<S, F> Layer<S> for Journal<F>
where
    S: Subscriber,
    F: Layer<S>,
{
    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        if self.gone.load(Ordering::Acquire) {
            self.fallback.on_event(event, ctx);
            return;
        }
        let sent = ENTRY.with(|cell| {
            let Ok(mut entry) = cell.try_borrow_mut() else {
                return Ok(()); // re-entered from within an encoding: nothing to write
            };
            entry.clear();
            encode(&mut entry, event);
            self.send(&entry)
        });
        match sent {
            Ok(()) => self.report_dropped(),
            Err(e)
                if e.kind() == io::ErrorKind::WouldBlock
                    || e.raw_os_error() == Some(libc::ENOBUFS)
                    || e.raw_os_error() == Some(libc::EMSGSIZE) =>
            {
                self.dropped.fetch_add(1, Ordering::AcqRel);
            }
            Err(e) => {
                // The socket is gone (journald stopped, ENOENT / ECONNREFUSED): JSON lines on
                // stdout from now on, saying so once.
                if !self.gone.swap(true, Ordering::AcqRel) {
                    let text = format!(
                        "journal socket {} unavailable ({e}): logging JSON lines to stdout",
                        self.path.display()
                    );
                    let values: [Option<&dyn Value>; 1] = [Some(&text.as_str() as &dyn Value)];
                    let meta = FALLBACK.metadata();
                    self.fallback.on_event(
                        &Event::new(meta, &meta.fields().value_set_all(&values)),
                        ctx.clone(),
                    );
                }
                self.fallback.on_event(event, ctx);
            }
        }
    }

    forward_layer!(fallback);
}

own_callsite!(Fallback, FALLBACK, FALLBACK_META, Level::WARN, &["message"]);

/// journald's priority of a level (syslog's: err, warning, info, debug).
pub fn priority(level: Level) -> u8 {
    match level {
        Level::ERROR => 3,
        Level::WARN => 4,
        Level::INFO => 6,
        _ => 7,
    }
}

/// Encodes `event` as one native-protocol entry into `entry`.
pub fn encode(entry: &mut Vec<u8>, event: &Event<'_>) {
    let meta = event.metadata();
    put(entry, "PRIORITY", &[b'0' + priority(*meta.level())]);
    put(entry, "SYSLOG_IDENTIFIER", b"flyd");
    put(entry, "TARGET", meta.target().as_bytes());
    if let Some(file) = meta.file() {
        put(entry, "CODE_FILE", file.as_bytes());
    }
    if let Some(line) = meta.line() {
        put_with(entry, "CODE_LINE", |e| {
            let _ = write!(e, "{line}");
        });
    }
    let thread = std::thread::current();
    put(
        entry,
        "FLYD_THREAD",
        thread.name().unwrap_or("unnamed").as_bytes(),
    );
    // MESSAGE: the sentence then `name=value` for each field, as a terminal shows the event.
    put_name(entry, "MESSAGE");
    let start = open_value(entry);
    event.record(&mut MessageText {
        entry,
        start,
        message: true,
    });
    event.record(&mut MessageText {
        entry,
        start,
        message: false,
    });
    close_value(entry, start);
    event.record(&mut FieldVisitor { entry });
}

/// Writes into the `MESSAGE` value (begun at `start`) the message field (`message`) or the
/// other fields as `name=value`.
struct MessageText<'a> {
    entry: &'a mut Vec<u8>,
    start: usize,
    message: bool,
}

impl Visit for MessageText<'_> {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        match (self.message, field.name() == "message") {
            (true, true) => {
                let _ = write!(self.entry, "{value:?}");
            }
            (false, false) => {
                if self.entry.len() > self.start {
                    self.entry.push(b' ');
                }
                let _ = write!(self.entry, "{}={value:?}", field.name());
            }
            _ => {}
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        self.record_debug(field, &format_args!("{value}"));
    }
}

/// Writes each field but the message as `FLYD_<NAME>`.
struct FieldVisitor<'a> {
    entry: &'a mut Vec<u8>,
}

impl Visit for FieldVisitor<'_> {
    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() != "message" {
            put_field(self.entry, field.name(), |e| {
                let _ = write!(e, "{value:?}");
            });
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() != "message" {
            put_field(self.entry, field.name(), |e| {
                e.extend_from_slice(value.as_bytes())
            });
        }
    }
}

/// `FLYD_` and `name` upper-cased, anything but A-Z, 0-9 and `_` as `_` (journal field names).
fn put_field(entry: &mut Vec<u8>, name: &str, value: impl FnOnce(&mut Vec<u8>)) {
    entry.extend_from_slice(FIELD_PREFIX.as_bytes());
    entry.extend(name.bytes().map(|c| {
        if c.is_ascii_alphanumeric() {
            c.to_ascii_uppercase()
        } else {
            b'_'
        }
    }));
    entry.push(b'\n');
    let start = open_value(entry);
    value(entry);
    close_value(entry, start);
}

fn put(entry: &mut Vec<u8>, name: &str, value: &[u8]) {
    put_with(entry, name, |e| e.extend_from_slice(value));
}

fn put_with(entry: &mut Vec<u8>, name: &str, value: impl FnOnce(&mut Vec<u8>)) {
    put_name(entry, name);
    let start = open_value(entry);
    value(entry);
    close_value(entry, start);
}

fn put_name(entry: &mut Vec<u8>, name: &str) {
    entry.extend_from_slice(name.as_bytes());
    entry.push(b'\n');
}

/// Every value is written in the protocol's binary-safe form: its length as 8 bytes (little
/// endian), the bytes, a newline. The length is filled in by [`close_value`].
fn open_value(entry: &mut Vec<u8>) -> usize {
    entry.extend_from_slice(&[0; 8]);
    entry.len()
}

fn close_value(entry: &mut Vec<u8>, start: usize) {
    let len = (entry.len() - start) as u64;
    entry[start - 8..start].copy_from_slice(&len.to_le_bytes());
    entry.push(b'\n');
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use std::fmt::Write as _;
    use std::sync::{Arc, Mutex};
    use tracing_subscriber::layer::SubscriberExt;

    /// Decodes one native-protocol entry (both the `NAME=value` and the binary form).
    fn decode(mut b: &[u8]) -> BTreeMap<String, String> {
        let mut out = BTreeMap::new();
        while !b.is_empty() {
            let nl = b.iter().position(|&c| c == b'\n').expect("newline");
            let line = &b[..nl];
            if let Some(eq) = line.iter().position(|&c| c == b'=') {
                out.insert(
                    String::from_utf8_lossy(&line[..eq]).into(),
                    String::from_utf8_lossy(&line[eq + 1..]).into(),
                );
                b = &b[nl + 1..];
            } else {
                let name = String::from_utf8_lossy(line).into_owned();
                let rest = &b[nl + 1..];
                let len = u64::from_le_bytes(rest[..8].try_into().expect("8 bytes")) as usize;
                out.insert(name, String::from_utf8_lossy(&rest[8..8 + len]).into());
                assert_eq!(rest[8 + len], b'\n');
                b = &rest[8 + len + 1..];
            }
        }
        out
    }

    #[derive(Clone, Default)]
    struct Lines(Arc<Mutex<Vec<String>>>);

    impl<S: Subscriber> Layer<S> for Lines {
        fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
            let mut text = String::new();
            struct T<'a>(&'a mut String);
            impl Visit for T<'_> {
                fn record_debug(&mut self, f: &Field, v: &dyn fmt::Debug) {
                    let _ = write!(self.0, "{}={v:?};", f.name());
                }
            }
            event.record(&mut T(&mut text));
            if let Ok(mut l) = self.0.lock() {
                l.push(text);
            }
        }
    }

    #[test]
    fn an_event_is_one_entry_with_its_priority_message_thread_and_fields() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("socket");
        let server = UnixDatagram::bind(&path).expect("bind");
        let fallback = Lines::default();
        let journal = Journal::connect_to(&path, fallback.clone()).expect("connect");
        let mut buf = vec![0u8; 65536];
        let n = server.recv(&mut buf).expect("the empty probe");
        assert_eq!(n, 0);
        let subscriber = tracing_subscriber::registry().with(journal);
        let handle = std::thread::Builder::new()
            .name("evolution".into())
            .spawn(move || {
                tracing::subscriber::with_default(subscriber, || {
                    tracing::warn!(
                        device = "/dev/video1",
                        fps = 29.5,
                        frames = 3u64,
                        multi = "a\nb",
                        "camera error"
                    );
                    tracing::error!("plain");
                    tracing::info!(generations_per_sec = 98.0, "stats");
                    tracing::debug!("detail");
                })
            })
            .expect("thread");
        handle.join().expect("join");
        let mut entries = Vec::new();
        for _ in 0..4 {
            let n = server.recv(&mut buf).expect("an entry");
            entries.push(decode(&buf[..n]));
        }
        let e = &entries[0];
        assert_eq!(e["PRIORITY"], "4");
        assert_eq!(e["SYSLOG_IDENTIFIER"], "flyd");
        assert_eq!(
            e["MESSAGE"],
            "camera error device=/dev/video1 fps=29.5 frames=3 multi=a\nb"
        );
        assert_eq!(e["FLYD_DEVICE"], "/dev/video1");
        assert_eq!(e["FLYD_FPS"], "29.5");
        assert_eq!(e["FLYD_FRAMES"], "3");
        assert_eq!(e["FLYD_MULTI"], "a\nb");
        assert_eq!(e["FLYD_THREAD"], "evolution");
        assert!(e["TARGET"].starts_with("flyd::logging"), "{e:?}");
        assert!(e["CODE_FILE"].ends_with("journal.rs"), "{e:?}");
        assert!(e["CODE_LINE"].parse::<u32>().is_ok(), "{e:?}");
        assert_eq!(entries[1]["PRIORITY"], "3");
        assert_eq!(entries[1]["MESSAGE"], "plain");
        assert_eq!(entries[2]["PRIORITY"], "6");
        assert_eq!(entries[2]["MESSAGE"], "stats generations_per_sec=98.0");
        assert_eq!(entries[2]["FLYD_GENERATIONS_PER_SEC"], "98.0");
        assert_eq!(entries[3]["PRIORITY"], "7");
        assert!(fallback.0.lock().map(|l| l.is_empty()).unwrap_or(false));
    }

    #[test]
    fn a_journal_that_goes_away_falls_back_to_stdout_and_says_so_once() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("socket");
        let server = UnixDatagram::bind(&path).expect("bind");
        let fallback = Lines::default();
        let journal = Journal::connect_to(&path, fallback.clone()).expect("connect");
        drop(server);
        std::fs::remove_file(&path).expect("socket gone");
        let subscriber = tracing_subscriber::registry().with(journal);
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!("one");
            tracing::warn!("two");
        });
        let lines = fallback.0.lock().map(|l| l.clone()).unwrap_or_default();
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(
            lines[0].contains("unavailable") && lines[0].contains("logging JSON lines to stdout"),
            "{lines:?}"
        );
        assert!(lines[1].contains("one") && lines[2].contains("two"));
    }

    #[test]
    fn nobody_listening_is_an_error_at_connect() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert!(Journal::connect_to(&dir.path().join("none"), ()).is_err());
    }

    #[test]
    fn journal_stream_names_device_and_inode() {
        assert!(stream_is_journal(Some("8:12345"), 8, 12345));
        assert!(!stream_is_journal(Some("8:12345"), 8, 12346));
        assert!(!stream_is_journal(Some("junk"), 8, 12345));
        assert!(!stream_is_journal(None, 8, 12345));
    }
}

//! candump -L logs decoded with the project's DBC (config/flyd.dbc, parsed by can-dbc): every
//! signal's position, scaling and value names come from the DBC, none from this file.

use std::collections::BTreeMap;

use crate::dbc_signals::{raw_value, value_table};
use can_dbc::{AttributeValue, Dbc, Message};
use flyd_core::can::crc::e2e_crc;

/// One frame of the log, decoded.
#[derive(Debug, Clone)]
pub struct Frame {
    /// candump's timestamp (CLOCK_REALTIME seconds).
    pub time: f64,
    // In failure messages (Debug), with the decoded values.
    #[allow(dead_code)]
    pub id: u32,
    #[allow(dead_code)]
    pub data: [u8; 8],
    /// The DBC message name (FLYD_Command, FLYD_Status, FLYD_Obstacle; VCU_Motion, sent to
    /// flyd by a scenario).
    pub message: String,
    /// Physical value of each signal.
    pub values: BTreeMap<String, f64>,
    /// Value-table name of each signal that has one for its raw value.
    pub labels: BTreeMap<String, String>,
    /// The DLC is the DBC's and byte 0 equals the E2E CRC over its Data ID and bytes 1..7.
    pub crc_ok: bool,
}

impl Frame {
    pub fn value(&self, signal: &str) -> f64 {
        *self
            .values
            .get(signal)
            .unwrap_or_else(|| panic!("{} has no signal {signal}", self.message))
    }

    /// The value-table name of a signal ("STOP", "RUNNING", ...).
    pub fn label(&self, signal: &str) -> &str {
        self.labels
            .get(signal)
            .unwrap_or_else(|| panic!("{}.{signal} has no value name: {self:?}", self.message))
    }

    pub fn counter(&self) -> u8 {
        self.value("AliveCounter") as u8
    }
}

pub struct Decoder {
    dbc: Dbc,
}

impl Decoder {
    pub fn new() -> Decoder {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/flyd.dbc");
        let text = std::fs::read_to_string(path).expect("config/flyd.dbc is readable");
        Decoder {
            dbc: Dbc::try_from(text.as_str()).expect("config/flyd.dbc parses"),
        }
    }

    fn message(&self, id: u32) -> Option<&Message> {
        self.dbc.messages.iter().find(|m| m.id.raw() == id)
    }

    /// The DBC's cycle time of a message, milliseconds.
    pub fn cycle_ms(&self, name: &str) -> u64 {
        let msg = self
            .dbc
            .messages
            .iter()
            .find(|m| m.name == name)
            .unwrap_or_else(|| panic!("no message {name} in the DBC"));
        attr_u64(self.dbc.message_attribute(msg.id, "GenMsgCycleTime"))
    }

    /// Every line of a `candump -L` log: `(SECONDS) IFACE ID#DATA`. Panics on a line that is not
    /// one, or on an ID the DBC does not define (flyd sends nothing else on the bus).
    pub fn decode_log(&self, log: &str) -> Vec<Frame> {
        log.lines()
            .filter(|l| !l.trim().is_empty())
            .map(|line| self.decode_line(line))
            .collect()
    }

    fn decode_line(&self, line: &str) -> Frame {
        fn bad<T>(line: &str) -> T {
            panic!("not a candump -L line: {line:?}")
        }
        let mut words = line.split_whitespace();
        let time = words
            .next()
            .and_then(|t| t.strip_prefix('(')?.strip_suffix(')')?.parse().ok())
            .unwrap_or_else(|| bad(line));
        let _iface = words.next().unwrap_or_else(|| bad(line));
        let (id, hex) = words
            .next()
            .and_then(|f| f.split_once('#'))
            .unwrap_or_else(|| bad(line));
        let id = u32::from_str_radix(id, 16).unwrap_or_else(|_| bad(line));
        let bytes: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap_or_else(|_| bad(line)))
            .collect();
        let msg = self
            .message(id)
            .unwrap_or_else(|| panic!("ID {id:#x} is not in config/flyd.dbc: {line:?}"));
        // flyd's own frames must have the DBC's DLC; a frame sent to flyd may not (a test's
        // bad input): it is kept, with `crc_ok` false.
        let from_flyd = msg.transmitter.as_deref() == Some("FLYD");
        let dlc_ok = bytes.len() as u64 == msg.size;
        assert!(dlc_ok || !from_flyd, "DLC of {}: {line:?}", msg.name);
        let mut data = [0u8; 8];
        let n = bytes.len().min(8);
        data[..n].copy_from_slice(&bytes[..n]);
        let mut values = BTreeMap::new();
        let mut labels = BTreeMap::new();
        for sig in &msg.signals {
            let raw = raw_value(sig, &data);
            values.insert(sig.name.clone(), raw as f64 * sig.factor + sig.offset);
            if let Some((_, l)) = value_table(&self.dbc, msg, &sig.name)
                .into_iter()
                .find(|(v, _)| *v == raw)
            {
                labels.insert(sig.name.clone(), l);
            }
        }
        let data_id = u16::try_from(attr_u64(
            self.dbc.message_attribute(msg.id, "FlydE2EDataID"),
        ))
        .expect("Data ID fits 16 bits");
        let crc_sig = msg
            .signals
            .iter()
            .find(|s| s.name == "CRC8")
            .expect("every flyd message has CRC8");
        let crc_ok =
            dlc_ok && raw_value(crc_sig, &data) == i64::from(e2e_crc(data_id, &data[1..8]));
        Frame {
            time,
            id,
            data,
            message: msg.name.clone(),
            values,
            labels,
            crc_ok,
        }
    }
}

fn attr_u64(value: Option<&AttributeValue>) -> u64 {
    match value {
        Some(AttributeValue::Uint(v)) => *v,
        Some(AttributeValue::Int(v)) => u64::try_from(*v).expect("non-negative"),
        Some(AttributeValue::Double(v)) if v.fract() == 0.0 && *v >= 0.0 => *v as u64,
        other => panic!("expected an integer attribute, got {other:?}"),
    }
}

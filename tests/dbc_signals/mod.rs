//! Reading signals out of CAN frames by the DBC's definition (start bit, size, byte order,
//! sign, value tables), shared by the DBC test (tests/dbc.rs) and the candump decoder
//! (tests/vm/can_log.rs) that tests/can_input.rs and the VM suite use.

use can_dbc::{ByteOrder, Dbc, Message, Signal, ValueDescription, ValueType};

/// Raw value of `sig` in an 8-byte frame, from the DBC's start bit, size, byte order and sign.
pub fn raw_value(sig: &Signal, data: &[u8; 8]) -> i64 {
    assert_eq!(
        sig.byte_order,
        ByteOrder::LittleEndian,
        "{}: the contract is Intel only",
        sig.name
    );
    assert!(
        sig.size >= 1 && sig.start_bit + sig.size <= 64,
        "{}: outside 8 bytes",
        sig.name
    );
    let word = u64::from_le_bytes(*data);
    let mask = if sig.size == 64 {
        u64::MAX
    } else {
        (1u64 << sig.size) - 1
    };
    let raw = (word >> sig.start_bit) & mask;
    match sig.value_type {
        ValueType::Unsigned => raw as i64,
        ValueType::Signed => {
            let sign = 1u64 << (sig.size - 1);
            if raw & sign != 0 {
                (raw | !mask) as i64
            } else {
                raw as i64
            }
        }
    }
}

/// The DBC's value table (VAL_) of a signal, empty when it has none.
pub fn value_table(dbc: &Dbc, msg: &Message, signal: &str) -> Vec<(i64, String)> {
    dbc.value_descriptions
        .iter()
        .find_map(|vd| match vd {
            ValueDescription::Signal {
                message_id,
                name,
                value_descriptions,
            } if *message_id == msg.id && name == signal => Some(
                value_descriptions
                    .iter()
                    .map(|d| (d.id, d.description.clone()))
                    .collect(),
            ),
            _ => None,
        })
        .unwrap_or_default()
}

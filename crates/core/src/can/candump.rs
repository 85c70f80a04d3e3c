//! can-utils `candump -l` log lines: writing them (so a flyd log replays with `canplayer`) and
//! reading them back (tests, offline tools).
//!
//! Format: `(<secs>.<micros>) <iface> <ID>#<DATA>`, e.g. `(1700000000.123456) vcan0 120#0102AB`,
//! hex in upper case; a standard ID is 3 hex digits, an extended one 8.
//!
//! IDs use the Linux `canid_t` convention throughout flyd: bit 31 ([`CAN_EFF_FLAG`]) marks a
//! 29-bit extended ID, otherwise the ID is an 11-bit standard one.

use std::fmt::Write as _;
use std::time::Duration;

use thiserror::Error;

/// Bit 31 of an ID: the ID is a 29-bit extended one (Linux `CAN_EFF_FLAG`).
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// Largest standard (11-bit) ID.
pub const CAN_SFF_MAX: u32 = 0x7FF;
/// Largest extended (29-bit) ID, without the flag.
pub const CAN_EFF_MAX: u32 = 0x1FFF_FFFF;
/// Classic CAN payload limit.
pub const CAN_MAX_DLEN: usize = 8;

/// Why a candump line could not be read.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CandumpParseError {
    #[error("expected '(<timestamp>)' at the start of the line")]
    MissingTimestamp,
    #[error("bad timestamp {0:?}")]
    BadTimestamp(String),
    #[error("missing interface name")]
    MissingInterface,
    #[error("missing '<id>#<data>' frame")]
    MissingFrame,
    #[error("bad CAN ID {0:?} (3 hex digits for standard, 8 for extended)")]
    BadId(String),
    #[error("bad data {0:?} (pairs of hex digits, at most 8 bytes)")]
    BadData(String),
    #[error("unsupported frame {0:?} (remote and CAN FD frames are not flyd's)")]
    Unsupported(String),
    #[error("unexpected trailing text {0:?}")]
    Trailing(String),
}

/// One `candump -l` line (without newline) for a frame at `timestamp` (since the Unix epoch,
/// as candump prints it; any epoch replays, canplayer only uses the differences).
pub fn format_candump_line(timestamp: Duration, iface: &str, id: u32, data: &[u8]) -> String {
    let mut line = String::with_capacity(40 + iface.len());
    // Writing to a String cannot fail; the results are ignored on purpose.
    let _ = write!(
        line,
        "({}.{:06}) {} ",
        timestamp.as_secs(),
        timestamp.subsec_micros(),
        iface
    );
    if id & CAN_EFF_FLAG != 0 {
        let _ = write!(line, "{:08X}#", id & CAN_EFF_MAX);
    } else {
        let _ = write!(line, "{:03X}#", id & CAN_SFF_MAX);
    }
    for b in data {
        let _ = write!(line, "{b:02X}");
    }
    line
}

/// Parses one `candump -l` line into (timestamp in seconds, interface, ID, data).
///
/// The ID follows the [`CAN_EFF_FLAG`] convention. A trailing direction flag (`T`/`R`, written
/// by newer can-utils with `-x`) is accepted and ignored; remote (`#R`) and CAN FD (`##`) frames
/// are rejected.
pub fn parse_candump_line(line: &str) -> Result<(f64, String, u32, Vec<u8>), CandumpParseError> {
    let line = line.trim();
    let rest = line
        .strip_prefix('(')
        .ok_or(CandumpParseError::MissingTimestamp)?;
    let (ts, rest) = rest
        .split_once(')')
        .ok_or(CandumpParseError::MissingTimestamp)?;
    let timestamp: f64 = ts
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| CandumpParseError::BadTimestamp(ts.to_owned()))?;

    let mut tokens = rest.split_whitespace();
    let iface = tokens.next().ok_or(CandumpParseError::MissingInterface)?;
    let frame = tokens.next().ok_or(CandumpParseError::MissingFrame)?;
    match tokens.next() {
        None | Some("T" | "R") => {}
        Some(other) => return Err(CandumpParseError::Trailing(other.to_owned())),
    }
    if let Some(extra) = tokens.next() {
        return Err(CandumpParseError::Trailing(extra.to_owned()));
    }

    let (id_hex, data_hex) = frame
        .split_once('#')
        .ok_or(CandumpParseError::MissingFrame)?;
    if data_hex.starts_with('#') || data_hex.starts_with('R') || data_hex.starts_with('r') {
        return Err(CandumpParseError::Unsupported(frame.to_owned()));
    }

    let bad_id = || CandumpParseError::BadId(id_hex.to_owned());
    if !id_hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(bad_id());
    }
    let id = match id_hex.len() {
        3 => {
            let id = u32::from_str_radix(id_hex, 16).map_err(|_| bad_id())?;
            if id > CAN_SFF_MAX {
                return Err(bad_id());
            }
            id
        }
        8 => {
            let id = u32::from_str_radix(id_hex, 16).map_err(|_| bad_id())?;
            if id > CAN_EFF_MAX {
                return Err(bad_id());
            }
            id | CAN_EFF_FLAG
        }
        _ => return Err(bad_id()),
    };

    let bad_data = || CandumpParseError::BadData(data_hex.to_owned());
    if data_hex.len() % 2 != 0
        || data_hex.len() / 2 > CAN_MAX_DLEN
        || !data_hex.bytes().all(|b| b.is_ascii_hexdigit())
    {
        return Err(bad_data());
    }
    let data = (0..data_hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&data_hex[i..i + 2], 16).map_err(|_| bad_data()))
        .collect::<Result<Vec<u8>, _>>()?;

    Ok((timestamp, iface.to_owned(), id, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_like_candump_l() {
        let ts = Duration::new(1_700_000_000, 123_456_789);
        assert_eq!(
            format_candump_line(ts, "vcan0", 0x120, &[1, 2, 3, 4, 5, 6, 7, 8]),
            "(1700000000.123456) vcan0 120#0102030405060708"
        );
        assert_eq!(
            format_candump_line(Duration::from_micros(5), "can1", 0x7, &[0xAB]),
            "(0.000005) can1 007#AB"
        );
        assert_eq!(
            format_candump_line(ts, "can0", 0x1234_5678 | CAN_EFF_FLAG, &[]),
            "(1700000000.123456) can0 12345678#"
        );
    }

    #[test]
    fn parses_what_it_formats() {
        let ts = Duration::new(1_700_000_000, 123_456_000);
        for (id, data) in [
            (0x120, vec![1u8, 2, 3, 4, 5, 6, 7, 8]),
            (0x7FF, vec![]),
            (0x1ABC_DEF0 | CAN_EFF_FLAG, vec![0xFF, 0x00]),
        ] {
            let line = format_candump_line(ts, "vcan0", id, &data);
            let (t, iface, pid, pdata) = parse_candump_line(&line).expect("parses");
            assert!((t - 1_700_000_000.123456).abs() < 1e-6, "{t}");
            assert_eq!((iface.as_str(), pid, pdata), ("vcan0", id, data));
        }
    }

    #[test]
    fn parses_real_candump_output() {
        // As written by `candump -l` (lower/upper case hex both occur in the wild), with and
        // without the -x direction flag.
        let (t, iface, id, data) =
            parse_candump_line("(1436509052.249713) vcan0 044#2A366C2BBA\n").expect("parses");
        assert_eq!(
            (t, iface.as_str(), id, data),
            (
                1436509052.249713,
                "vcan0",
                0x044,
                vec![0x2A, 0x36, 0x6C, 0x2B, 0xBA]
            )
        );
        let (_, _, id, data) =
            parse_candump_line("(1436509052.249713) can0 1f334455#1122 T").expect("parses");
        assert_eq!((id, data), (0x1F33_4455 | CAN_EFF_FLAG, vec![0x11, 0x22]));
    }

    #[test]
    fn rejects_malformed_lines() {
        use CandumpParseError::*;
        let cases: [(&str, CandumpParseError); 10] = [
            ("vcan0 120#00", MissingTimestamp),
            ("(12.5 vcan0 120#00", MissingTimestamp),
            ("(abc) vcan0 120#00", BadTimestamp("abc".into())),
            ("(1.0)", MissingInterface),
            ("(1.0) vcan0", MissingFrame),
            ("(1.0) vcan0 12#00", BadId("12".into())),
            ("(1.0) vcan0 800#00", BadId("800".into())),
            ("(1.0) vcan0 120#001", BadData("001".into())),
            ("(1.0) vcan0 120#R", Unsupported("120#R".into())),
            ("(1.0) vcan0 120##1AA", Unsupported("120##1AA".into())),
        ];
        for (line, want) in cases {
            assert_eq!(parse_candump_line(line), Err(want), "{line}");
        }
        assert!(matches!(
            parse_candump_line("(1.0) vcan0 120#000102030405060708"),
            Err(BadData(_))
        ));
        assert!(matches!(
            parse_candump_line("(1.0) vcan0 120#00 junk"),
            Err(Trailing(_))
        ));
    }

    #[test]
    fn damaged_lines_are_errors_never_a_panic() {
        use crate::test_support::damage_each;
        let line = "(1700000000.123456) vcan0 12345678#0102030405060708";
        let check = |(ts, _, _, data): &(f64, String, u32, Vec<u8>), label: &str| {
            assert!(ts.is_finite() && data.len() <= 64, "{label}: {ts} {data:?}");
        };
        let (parsed, refused) = damage_each(line, 0..5_000, "", parse_candump_line, check);
        println!("damaged candump lines: {parsed} parsed, {refused} refused");
        assert!(
            parsed > 50 && refused > 2000,
            "{parsed} parsed, {refused} refused"
        );
    }
}

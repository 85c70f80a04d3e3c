//! CRC-8 SAE J1850, as used by AUTOSAR E2E profiles 1 and 2.
//!
//! Parameters (Rocksoft model): width 8, poly `0x1D`, init `0xFF`, no reflection, xorout `0xFF`;
//! the check value (CRC of ASCII `"123456789"`) is `0x4B`.
//!
//! # What flyd protects with it
//! Every flyd frame carries, in byte 0,
//! `crc8_j1850(DataID.lo, DataID.hi, byte1, byte2, ..., byte7)`: one CRC computation over the
//! 16-bit Data ID of the message, low byte first, followed by payload bytes 1..=7 (byte 1 holds the
//! alive counter, so the counter is protected too). The Data ID is never sent: it is a shared
//! secret-free "what message is this" key that both ends configure, so a frame that arrives on
//! the wrong CAN ID (misrouting, an ID reconfigured on one side only, another ECU's frame) fails
//! its CRC instead of being read with the wrong layout. See [`super::messages`] for the defaults.

/// The 256-entry lookup table, built at compile time from the polynomial so that it cannot drift
/// from the bitwise definition.
const TABLE: [u8; 256] = build_table(POLY);

/// SAE J1850 generator polynomial x^8 + x^4 + x^3 + x^2 + 1 (the x^8 term implied).
pub const POLY: u8 = 0x1D;
/// Register value before the first byte.
pub const INIT: u8 = 0xFF;
/// Value XORed into the register after the last byte.
pub const XOR_OUT: u8 = 0xFF;
/// CRC of the ASCII string `"123456789"`, the catalogue check value for this CRC.
pub const CHECK: u8 = 0x4B;

const fn build_table(poly: u8) -> [u8; 256] {
    let mut table = [0u8; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ poly
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

/// Incremental CRC-8 SAE J1850, for data that is not contiguous (Data ID + frame bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crc8 {
    reg: u8,
}

impl Default for Crc8 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc8 {
    pub const fn new() -> Self {
        Self { reg: INIT }
    }

    /// Feeds bytes; can be called any number of times.
    #[must_use]
    pub fn update(mut self, bytes: &[u8]) -> Self {
        for &b in bytes {
            self.reg = TABLE[usize::from(self.reg ^ b)];
        }
        self
    }

    /// The CRC of everything fed so far.
    pub const fn finish(self) -> u8 {
        self.reg ^ XOR_OUT
    }
}

/// CRC-8 SAE J1850 of `bytes` in one go.
pub fn crc8_j1850(bytes: &[u8]) -> u8 {
    Crc8::new().update(bytes).finish()
}

/// The CRC that flyd puts in byte 0 of a frame: over the Data ID (low byte, then high byte)
/// followed by `payload` (frame bytes 1..=7).
pub fn e2e_crc(data_id: u16, payload: &[u8]) -> u8 {
    Crc8::new()
        .update(&data_id.to_le_bytes())
        .update(payload)
        .finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straight from the definition, one bit at a time: the reference the table is checked
    /// against.
    fn crc8_bitwise(bytes: &[u8]) -> u8 {
        let mut crc = INIT;
        for &b in bytes {
            crc ^= b;
            for _ in 0..8 {
                crc = if crc & 0x80 != 0 {
                    (crc << 1) ^ POLY
                } else {
                    crc << 1
                };
            }
        }
        crc ^ XOR_OUT
    }

    #[test]
    fn check_value() {
        assert_eq!(crc8_j1850(b"123456789"), CHECK);
        assert_eq!(crc8_bitwise(b"123456789"), CHECK);
    }

    /// Published AUTOSAR CRC library examples for CRC8 SAE J1850 (Specification of CRC
    /// Routines, "8-bit SAE J1850 CRC Calculation" table).
    #[test]
    fn autosar_examples() {
        let cases: [(&[u8], u8); 7] = [
            (&[0x00, 0x00, 0x00, 0x00], 0x59),
            (&[0xF2, 0x01, 0x83], 0x37),
            (&[0x0F, 0xAA, 0x00, 0x55], 0x79),
            (&[0x00, 0xFF, 0x55, 0x11], 0xB8),
            (
                &[0x33, 0x22, 0x55, 0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF],
                0xCB,
            ),
            (&[0x92, 0x6B, 0x55], 0x8C),
            (&[0xFF, 0xFF, 0xFF, 0xFF], 0x74),
        ];
        for (data, want) in cases {
            assert_eq!(crc8_j1850(data), want, "data {data:02X?}");
        }
    }

    #[test]
    fn table_matches_bitwise_reference() {
        // Every single byte, plus a deterministic pseudo-random spread of longer inputs.
        for b in 0..=255u8 {
            assert_eq!(crc8_j1850(&[b]), crc8_bitwise(&[b]), "byte {b:#04x}");
        }
        let mut next = crate::test_support::xorshift32(0x1234_5678);
        for len in 0..64 {
            let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            assert_eq!(crc8_j1850(&data), crc8_bitwise(&data), "len {len}");
        }
    }

    #[test]
    fn incremental_equals_one_shot() {
        let data = b"the quick brown fox";
        for split in 0..=data.len() {
            let (a, b) = data.split_at(split);
            assert_eq!(Crc8::new().update(a).update(b).finish(), crc8_j1850(data));
        }
    }

    #[test]
    fn e2e_crc_covers_data_id_low_byte_first() {
        let payload = [1, 2, 3, 4, 5, 6, 7];
        let mut joined = vec![0x20, 0x01];
        joined.extend_from_slice(&payload);
        assert_eq!(e2e_crc(0x0120, &payload), crc8_bitwise(&joined));
        // A different Data ID must change the CRC for the same payload.
        assert_ne!(e2e_crc(0x0120, &payload), e2e_crc(0x0121, &payload));
    }
}

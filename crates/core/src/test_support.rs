//! Helpers shared by the unit tests of several modules.

/// Deterministic byte-level damage to a valid file: what an editor, a truncated copy or a bad
/// merge does. xorshift, so the cases are the same on every run.
pub fn damaged(text: &str, seed: u64) -> String {
    let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move |n: usize| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x % n.max(1) as u64) as usize
    };
    let mut bytes = text.as_bytes().to_vec();
    const TOKENS: [&str; 15] = [
        "nan", "inf", "-inf", "1e999", "-0", "0", "-1", "1e-320", "\"\"", "[", "=", "\n", "é", "€",
        "\u{feff}",
    ];
    for _ in 0..1 + next(4) {
        let len = bytes.len();
        let at = next(len + 1);
        match next(5) {
            // Overwrite a byte with printable noise.
            0 if len > 0 => bytes[at.min(len - 1)] = b' ' + next(95) as u8,
            // Cut a stretch out (a truncated copy when it reaches the end).
            1 => {
                let end = (at + 1 + next(40)).min(len);
                bytes.drain(at.min(end)..end);
            }
            // Swap a number for a hostile token.
            2 => {
                let token = TOKENS[next(TOKENS.len())].as_bytes();
                let end = (at + next(6)).min(len);
                bytes.splice(at.min(end)..end, token.iter().copied());
            }
            // Duplicate a stretch (a key given twice, a line pasted twice).
            3 => {
                let end = (at + 1 + next(60)).min(len);
                let piece: Vec<u8> = bytes[at.min(end)..end].to_vec();
                bytes.splice(at.min(end)..at.min(end), piece);
            }
            _ => bytes.truncate(at),
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

//! The dotted key (`table.key`) at a byte offset of a TOML text: what an error message blames
//! when the TOML parser or serde reports a position (the configuration and the rig files).

/// The dotted key (`table.key`) in force at byte `offset`: the last table header and the last
/// `key =` line at or before it (continuation lines of a multi-line array keep their key). A
/// best effort for error messages, good for the flat layout of rig and configuration files.
pub fn key_at(text: &str, offset: usize) -> String {
    let mut table = "";
    let mut key: Option<&str> = None;
    let mut start = 0;
    for line in text.split_inclusive('\n') {
        if start > offset {
            break;
        }
        start += line.len();
        let line = line.trim();
        if line.starts_with('#') {
            continue;
        }
        if let Some(header) = table_header(line) {
            table = header;
            key = None;
        } else if let Some((k, _)) = line.split_once('=')
            && is_key(k.trim())
        {
            key = Some(k.trim());
        }
    }
    match (table, key) {
        ("", None) => String::new(),
        ("", Some(key)) => key.to_string(),
        (table, None) => table.to_string(),
        (table, Some(key)) => format!("{table}.{key}"),
    }
}

/// The name in a `[table]` or `[[array]]` header line; `None` for other lines, including the
/// continuation lines of a multi-line array such as `[0.0, 1.0, 0.0],`.
fn table_header(line: &str) -> Option<&str> {
    let inner = line.strip_prefix('[')?;
    let inner = inner.strip_prefix('[').unwrap_or(inner);
    let (name, rest) = inner.split_once(']')?;
    let rest = rest.strip_prefix(']').unwrap_or(rest).trim_start();
    (is_key(name.trim()) && (rest.is_empty() || rest.starts_with('#'))).then_some(name.trim())
}

fn is_key(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-. \"'".contains(c))
}

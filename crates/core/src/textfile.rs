//! Reading the small text files flyd is configured with (configuration, calibration), with a
//! size limit checked before anything is parsed: a path to `/dev/zero`, a FIFO or a 100 MB file
//! is an error naming the limit, not gigabytes of memory and a start that never returns.

use std::io::{self, Read};
use std::path::Path;

/// Largest configuration or calibration file flyd reads (the shipped ones are under 20 kB).
pub const MAX_TEXT_FILE: u64 = 1 << 20;

/// The UTF-8 text of `path`: a regular file of at most [`MAX_TEXT_FILE`] bytes.
pub fn read(path: &Path) -> io::Result<String> {
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "not a regular file (a device, FIFO or directory cannot be a configuration)",
        ));
    }
    let too_large = || {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "larger than the {MAX_TEXT_FILE}-byte limit of a configuration or calibration file"
            ),
        )
    };
    if meta.len() > MAX_TEXT_FILE {
        return Err(too_large());
    }
    // The file may grow between the check and the read: read one byte past the limit at most.
    let mut text = String::new();
    file.take(MAX_TEXT_FILE + 1).read_to_string(&mut text)?;
    if text.len() as u64 > MAX_TEXT_FILE {
        return Err(too_large());
    }
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_large_files_are_refused_before_reading() {
        let dir = tempfile::tempdir().expect("tempdir");
        let e = read(Path::new("/dev/zero")).expect_err("a device");
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert!(read(dir.path()).is_err());
        let big = dir.path().join("big.toml");
        std::fs::write(&big, vec![b'#'; MAX_TEXT_FILE as usize + 1]).expect("write");
        let e = read(&big).expect_err("too large");
        assert!(e.to_string().contains("1048576-byte limit"), "{e}");
        let ok = dir.path().join("ok.toml");
        std::fs::write(&ok, "a = 1\n").expect("write");
        assert_eq!(read(&ok).expect("small"), "a = 1\n");
    }
}

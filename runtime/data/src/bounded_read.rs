//! Reading a whole input file with a size limit, so a path that is not a regular file
//! (`/dev/zero`, a FIFO fed forever) or a file far larger than any input stops with an error
//! instead of growing memory without bound.

use std::io::Read;
use std::path::Path;

use thiserror::Error;

/// Models, parameter files and fit reports (`.kin`, `params`, `FIT.json`): 64 MiB, hundreds of
/// times the largest model written by hand or by `kin diagnose --apply`.
pub const MAX_TEXT_BYTES: u64 = 64 << 20;

/// Measurement files that are not regular files (a pipe, a device): 1 GiB. A regular file is
/// read whatever its size: its length is known before reading and memory follows it.
pub const MAX_STREAM_BYTES: u64 = 1 << 30;

#[derive(Debug, Error)]
pub enum BoundedReadError {
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error("larger than {} MiB, the most kin reads from such a file", .limit >> 20)]
    TooLarge { limit: u64 },
}

/// The bytes of `path`, at most `limit` of them: more is [`BoundedReadError::TooLarge`].
pub fn read(path: &Path, limit: u64) -> Result<Vec<u8>, BoundedReadError> {
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    // One byte past the limit tells a file of exactly `limit` bytes from a longer one.
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(BoundedReadError::TooLarge { limit });
    }
    Ok(bytes)
}

/// As [`read`], with no limit for a regular file and `limit` for anything else.
pub fn read_unless_regular(path: &Path, limit: u64) -> Result<Vec<u8>, BoundedReadError> {
    let regular = std::fs::metadata(path)?.is_file();
    read(path, if regular { u64::MAX } else { limit })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_that_never_ends_stops_at_the_limit() {
        let zero = Path::new("/dev/zero");
        if !zero.exists() {
            return;
        }
        assert!(matches!(
            read(zero, 1024),
            Err(BoundedReadError::TooLarge { limit: 1024 })
        ));
        assert!(matches!(
            read_unless_regular(zero, 4096),
            Err(BoundedReadError::TooLarge { limit: 4096 })
        ));
    }

    #[test]
    fn a_file_of_exactly_the_limit_reads() {
        let dir = std::env::temp_dir().join(format!("kin-bounded-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("f.txt");
        std::fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read(&path, 10).unwrap(), b"0123456789");
        assert!(matches!(
            read(&path, 9),
            Err(BoundedReadError::TooLarge { .. })
        ));
        assert_eq!(read_unless_regular(&path, 1).unwrap().len(), 10);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

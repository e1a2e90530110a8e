//! Reading the files a user names: only regular files (a device such as `/dev/zero` or a FIFO
//! would be read until memory runs out, or block forever), and no more than a size limit, so
//! that no input can exhaust memory before its parser has seen it.

use std::fs::File;
use std::io::Read;
use std::path::Path;

/// Largest input file read whole (audio, heads, models, marker tracks).
pub const MAX_INPUT_BYTES: u64 = 1 << 30;

#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a regular file")]
    NotRegular { path: String },
    #[error("{path}: {size} bytes, larger than the {limit} bytes an input may have")]
    TooLarge { path: String, size: u64, limit: u64 },
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> InputError + '_ {
    move |source| InputError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// Opens a regular file of at most `limit` bytes and returns it with its size. Checked before
/// opening (opening a FIFO blocks) and again on the open file (the path may have changed).
pub fn open(path: &Path, limit: u64) -> Result<(File, u64), InputError> {
    let check = |meta: std::fs::Metadata| {
        if !meta.is_file() {
            return Err(InputError::NotRegular {
                path: path.display().to_string(),
            });
        }
        if meta.len() > limit {
            return Err(InputError::TooLarge {
                path: path.display().to_string(),
                size: meta.len(),
                limit,
            });
        }
        Ok(meta.len())
    };
    check(std::fs::metadata(path).map_err(io_error(path))?)?;
    let file = File::open(path).map_err(io_error(path))?;
    let size = check(file.metadata().map_err(io_error(path))?)?;
    Ok((file, size))
}

/// Reads a whole regular file of at most `limit` bytes (a file growing while it is read is cut
/// off at the limit and refused).
pub fn read(path: &Path, limit: u64) -> Result<Vec<u8>, InputError> {
    let (file, size) = open(path, limit)?;
    let mut bytes = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    file.take(limit.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io_error(path))?;
    if bytes.len() as u64 > limit {
        return Err(InputError::TooLarge {
            path: path.display().to_string(),
            size: bytes.len() as u64,
            limit,
        });
    }
    Ok(bytes)
}

/// [`read`] for text: UTF-8 or an error.
pub fn read_to_string(path: &Path, limit: u64) -> Result<String, InputError> {
    String::from_utf8(read(path, limit)?).map_err(|_| InputError::Io {
        path: path.display().to_string(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_and_directories_are_refused_before_reading() {
        for path in ["/dev/zero", "/dev/null", "/"] {
            let e = read(Path::new(path), MAX_INPUT_BYTES).unwrap_err();
            assert!(matches!(e, InputError::NotRegular { .. }), "{path}: {e}");
        }
    }

    #[test]
    fn a_file_over_the_limit_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.bin");
        std::fs::write(&path, [7u8; 100]).unwrap();
        assert_eq!(read(&path, 100).unwrap().len(), 100);
        let e = read(&path, 99).unwrap_err();
        assert!(e.to_string().contains("100 bytes"), "{e}");
        let e = read(&dir.path().join("missing"), 99).unwrap_err();
        assert!(matches!(e, InputError::Io { .. }), "{e}");
    }
}

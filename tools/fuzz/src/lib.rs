//! What several fuzz targets share: reading a sequence of operations out of the fuzzer's bytes,
//! and handing path-only readers a file.

use std::io::Write;
use std::path::PathBuf;

/// The fuzzer's bytes read front to back; reads past the end give zeros and empty slices.
pub struct Input<'a> {
    data: &'a [u8],
}

impl<'a> Input<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    pub fn u8(&mut self) -> u8 {
        let (&first, rest) = self.data.split_first().unwrap_or((&0, &[]));
        self.data = rest;
        first
    }

    pub fn u16(&mut self) -> u16 {
        u16::from_be_bytes([self.u8(), self.u8()])
    }

    pub fn bytes(&mut self, len: usize) -> &'a [u8] {
        let (taken, rest) = self.data.split_at(len.min(self.data.len()));
        self.data = rest;
        taken
    }

    /// A record of a 1-byte length and that many bytes (what the packet-stream seeds hold).
    pub fn short_record(&mut self) -> &'a [u8] {
        let len = usize::from(self.u8());
        self.bytes(len)
    }

    /// A record of a 2-byte big-endian length and that many bytes.
    pub fn record(&mut self) -> &'a [u8] {
        let len = usize::from(self.u16());
        self.bytes(len)
    }

    pub fn rest(&mut self) -> &'a [u8] {
        self.bytes(self.data.len())
    }
}

/// A file holding `bytes`, removed when dropped, for readers that take only a path. One per
/// process (the fuzzer runs one input at a time), in memory where `/dev/shm` exists.
pub struct ScratchFile {
    path: PathBuf,
}

impl ScratchFile {
    pub fn new(extension: &str, bytes: &[u8]) -> Self {
        let dir = std::path::Path::new("/dev/shm");
        let dir = if dir.is_dir() {
            dir.to_owned()
        } else {
            std::env::temp_dir()
        };
        let path = dir.join(format!("lipcall-fuzz-{}.{extension}", std::process::id()));
        let mut file = std::fs::File::create(&path).expect("scratch file");
        file.write_all(bytes).expect("scratch file written");
        Self { path }
    }

    pub fn path(&self) -> &std::path::Path {
        &self.path
    }
}

impl Drop for ScratchFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

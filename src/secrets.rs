//! Secrets the process holds (a SIP password, and the digest state ezk derives from it): out of
//! core dumps, and read from where other users cannot see them (a file, not the arguments).

use std::path::Path;

use zeroize::Zeroizing;

use crate::input::{self, InputError};

/// The largest password file read.
const MAX_SECRET_BYTES: u64 = 4096;

/// Turns core dumps off for the rest of the process's life: no core file (RLIMIT_CORE 0) and
/// not dumpable (PR_SET_DUMPABLE 0, which also keeps other processes of the same user from
/// attaching to it or reading its memory). Through rustix's safe calls; a failure is a warning,
/// the secret is still used.
pub fn forbid_core_dumps() {
    use rustix::process::{DumpableBehavior, Resource, Rlimit, set_dumpable_behavior, setrlimit};
    let none = Rlimit {
        current: Some(0),
        maximum: Some(0),
    };
    let done = setrlimit(Resource::Core, none)
        .and_then(|()| set_dumpable_behavior(DumpableBehavior::NotDumpable));
    if let Err(e) = done {
        tracing::warn!("cannot turn core dumps off while holding a password: {e}");
    }
}

/// A password kept in a file: its first line (a trailing newline is not part of it).
pub fn read_password_file(path: &Path) -> Result<Zeroizing<String>, InputError> {
    let mut text = Zeroizing::new(input::read_to_string(path, MAX_SECRET_BYTES)?);
    let line = text.lines().next().unwrap_or("").len();
    text.truncate(line);
    Ok(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_password_file_gives_its_first_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pw");
        for (text, password) in [
            ("s3cret\n", "s3cret"),
            ("s3 cret\r\n", "s3 cret"),
            ("x", "x"),
        ] {
            std::fs::write(&path, text).unwrap();
            assert_eq!(read_password_file(&path).unwrap().as_str(), password);
        }
        std::fs::write(&path, vec![b'x'; 5000]).unwrap();
        assert!(read_password_file(&path).is_err(), "too large");
        assert!(read_password_file(&dir.path().join("none")).is_err());
    }
}

//! Secrets the process holds (SIP, Mumble and TURN passwords, room passphrases and SRTP keys,
//! a Janus's API secret and token): out of core dumps, and read from where other users cannot
//! see them (an environment variable or a file, never the arguments).

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
fn read_password_file(path: &Path) -> Result<Zeroizing<String>, InputError> {
    let mut text = Zeroizing::new(input::read_to_string(path, MAX_SECRET_BYTES)?);
    let line = text.lines().next().unwrap_or("").len();
    text.truncate(line);
    Ok(text)
}

/// Where one secret is read from: a `--X-file PATH` flag, else an environment variable.
#[derive(Debug, Clone, Copy)]
pub struct SecretSource {
    /// The flag naming a file (`--password-file`), for messages.
    pub flag: &'static str,
    /// The environment variable read without the flag (`LIPCALL_SIP_PASSWORD`).
    pub variable: &'static str,
}

/// A secret that could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SecretError {
    #[error("{flag}: {source}")]
    File {
        flag: &'static str,
        source: InputError,
    },
    #[error("{flag} {path}: its first line is empty")]
    EmptyFile { flag: &'static str, path: String },
    #[error("{variable} does not hold valid UTF-8")]
    NotText { variable: &'static str },
}

impl SecretSource {
    /// The secret from `file` (its first line) or, without one, from the environment variable
    /// (unset or empty: none). Core dumps are off from the moment one is held.
    pub fn read(&self, file: Option<&Path>) -> Result<Option<Zeroizing<String>>, SecretError> {
        let secret = match file {
            Some(path) => {
                let secret = read_password_file(path).map_err(|source| SecretError::File {
                    flag: self.flag,
                    source,
                })?;
                if secret.is_empty() {
                    return Err(SecretError::EmptyFile {
                        flag: self.flag,
                        path: path.display().to_string(),
                    });
                }
                secret
            }
            None => match std::env::var(self.variable) {
                Ok(value) => Zeroizing::new(value),
                Err(std::env::VarError::NotPresent) => return Ok(None),
                Err(std::env::VarError::NotUnicode(_)) => {
                    return Err(SecretError::NotText {
                        variable: self.variable,
                    });
                }
            },
        };
        if secret.is_empty() {
            return Ok(None);
        }
        forbid_core_dumps();
        Ok(Some(secret))
    }

    /// How to give it, for a message that says it is missing.
    pub fn how_to_give(&self) -> String {
        format!("set {} or give {} FILE", self.variable, self.flag)
    }
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

    #[test]
    fn a_secret_comes_from_its_file_before_its_variable() {
        let dir = tempfile::tempdir().unwrap();
        let source = SecretSource {
            flag: "--test-secret-file",
            variable: "LIPCALL_TEST_SECRET_NEVER_SET",
        };
        assert!(source.read(None).unwrap().is_none());
        let path = dir.path().join("secret");
        std::fs::write(&path, "from the file\nsecond line").unwrap();
        let secret = source.read(Some(&path)).unwrap().unwrap();
        assert_eq!(secret.as_str(), "from the file");
        std::fs::write(&path, "\nsecond line").unwrap();
        let why = source.read(Some(&path)).unwrap_err().to_string();
        assert!(
            why.contains("--test-secret-file") && why.contains("empty"),
            "{why}"
        );
        let why = source.read(Some(&dir.path().join("none"))).unwrap_err();
        assert!(why.to_string().starts_with("--test-secret-file"), "{why}");
    }
}

//! Who we are to Mumble servers and whom we trust: a client certificate made once and kept
//! (servers tell users apart by it, and registered names are bound to it), and each server's
//! certificate trusted on first use (its SHA-256 fingerprint kept beside ours; a server that
//! later shows another is refused, as SSH does).
//!
//! Both live in `$XDG_CONFIG_HOME/lipcall/mumble/` (else `~/.config/lipcall/mumble/`).

use std::fs;
use std::path::{Path, PathBuf};

use openssl::asn1::Asn1Time;
use openssl::bn::{BigNum, MsbOption};
use openssl::hash::MessageDigest;
use openssl::pkey::{PKey, Private};
use openssl::rsa::Rsa;
use openssl::x509::{X509, X509NameBuilder};

use super::MumbleError;

const CERTIFICATE: &str = "client.pem";
const KNOWN: &str = "known_servers";

fn identity_error(what: &str, e: impl std::fmt::Display) -> MumbleError {
    MumbleError::Identity(format!("{what}: {e}"))
}

/// The folder our certificate and the known servers are kept in.
pub fn default_dir() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(base.join("lipcall").join("mumble"))
}

/// Our client certificate and its key.
pub struct Identity {
    pub certificate: X509,
    pub key: PKey<Private>,
}

impl std::fmt::Debug for Identity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Identity").finish_non_exhaustive()
    }
}

impl Identity {
    /// The certificate kept in `dir`, made (and kept) on first use.
    pub fn load_or_create(dir: &Path) -> Result<Self, MumbleError> {
        let path = dir.join(CERTIFICATE);
        if path.exists() {
            let pem =
                fs::read(&path).map_err(|e| identity_error(&path.display().to_string(), e))?;
            let certificate = X509::from_pem(&pem)
                .map_err(|e| identity_error(&format!("{} (certificate)", path.display()), e))?;
            let key = PKey::private_key_from_pem(&pem)
                .map_err(|e| identity_error(&format!("{} (key)", path.display()), e))?;
            return Ok(Self { certificate, key });
        }
        let identity = Self::generate().map_err(|e| identity_error("making a certificate", e))?;
        fs::create_dir_all(dir).map_err(|e| identity_error(&dir.display().to_string(), e))?;
        let mut pem = identity
            .key
            .private_key_to_pem_pkcs8()
            .map_err(|e| identity_error("encoding the key", e))?;
        pem.extend(
            identity
                .certificate
                .to_pem()
                .map_err(|e| identity_error("encoding the certificate", e))?,
        );
        write_private(&path, &pem).map_err(|e| identity_error(&path.display().to_string(), e))?;
        Ok(identity)
    }

    fn generate() -> Result<Self, openssl::error::ErrorStack> {
        let key = PKey::from_rsa(Rsa::generate(2048)?)?;
        let mut name = X509NameBuilder::new()?;
        name.append_entry_by_text("CN", "lipcall")?;
        let name = name.build();
        let mut serial = BigNum::new()?;
        serial.rand(64, MsbOption::MAYBE_ZERO, false)?;
        let mut builder = X509::builder()?;
        builder.set_version(2)?;
        let serial = serial.to_asn1_integer()?;
        builder.set_serial_number(&serial)?;
        builder.set_subject_name(&name)?;
        builder.set_issuer_name(&name)?;
        builder.set_pubkey(&key)?;
        let (from, until) = (
            Asn1Time::days_from_now(0)?,
            Asn1Time::days_from_now(20 * 365)?,
        );
        builder.set_not_before(&from)?;
        builder.set_not_after(&until)?;
        builder.sign(&key, MessageDigest::sha256())?;
        Ok(Self {
            certificate: builder.build(),
            key,
        })
    }
}

#[cfg(unix)]
fn write_private(path: &Path, data: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)?;
    f.write_all(data)
}

#[cfg(not(unix))]
fn write_private(path: &Path, data: &[u8]) -> std::io::Result<()> {
    fs::write(path, data)
}

/// A certificate's SHA-256 fingerprint, as `AB:CD:...`.
pub fn fingerprint(certificate: &X509) -> Result<String, MumbleError> {
    let digest = certificate
        .digest(MessageDigest::sha256())
        .map_err(|e| identity_error("fingerprint", e))?;
    Ok(digest
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(":"))
}

/// How a server's certificate stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Trust {
    /// Seen before, the same.
    Known,
    /// First seen now, and kept.
    New,
}

/// The servers' fingerprints trusted so far (`HOST:PORT FINGERPRINT` per line).
#[derive(Debug)]
pub struct KnownServers {
    path: PathBuf,
}

impl KnownServers {
    pub fn new(dir: &Path) -> Self {
        Self {
            path: dir.join(KNOWN),
        }
    }

    /// Checks `server`'s fingerprint against the one kept; an unknown server's is kept now.
    pub fn check(&self, server: &str, seen: &str) -> Result<Trust, MumbleError> {
        let text = match fs::read_to_string(&self.path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(e) => return Err(identity_error(&self.path.display().to_string(), e)),
        };
        let known = text.lines().find_map(|line| {
            let (who, print) = line.trim().split_once(' ')?;
            (who == server).then(|| print.trim().to_string())
        });
        match known {
            Some(k) if k == seen => Ok(Trust::Known),
            Some(k) => Err(MumbleError::CertificateChanged {
                server: server.to_string(),
                known: k,
                seen: seen.to_string(),
                file: self.path.display().to_string(),
            }),
            None => {
                if let Some(dir) = self.path.parent() {
                    fs::create_dir_all(dir)
                        .map_err(|e| identity_error(&dir.display().to_string(), e))?;
                }
                let mut f = fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(&self.path)
                    .map_err(|e| identity_error(&self.path.display().to_string(), e))?;
                use std::io::Write;
                writeln!(f, "{server} {seen}")
                    .map_err(|e| identity_error(&self.path.display().to_string(), e))?;
                Ok(Trust::New)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_certificate_is_made_once_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let a = Identity::load_or_create(dir.path()).unwrap();
        let b = Identity::load_or_create(dir.path()).unwrap();
        assert_eq!(
            fingerprint(&a.certificate).unwrap(),
            fingerprint(&b.certificate).unwrap()
        );
    }

    #[test]
    fn a_changed_server_certificate_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let known = KnownServers::new(dir.path());
        assert_eq!(known.check("h:1", "AA:BB").unwrap(), Trust::New);
        assert_eq!(known.check("h:1", "AA:BB").unwrap(), Trust::Known);
        assert_eq!(known.check("h:2", "CC").unwrap(), Trust::New);
        let err = known.check("h:1", "AA:CC").unwrap_err().to_string();
        assert!(err.contains("changed") && err.contains("AA:BB"), "{err}");
    }
}

//! Mumble servers (murmur): the voice chat of gaming communities. A Mumble server forwards
//! each speaker's Opus stream unmixed, tagged with the speaker's session, so every speaker
//! stays a peer of its own with its own lip sync.
//!
//! A client keeps a TLS connection for control messages ([`messages`]: protobuf, framed by
//! type and length) and sends voice ([`voice`]: Mumble's legacy packet format) by UDP,
//! encrypted with OCB2-AES128 ([`crypt`]), or inside the TLS stream when UDP does not get
//! through. [`client`] is the protocol without I/O ([`presence`]: its channels and users); [`connection`] drives it (the TLS thread
//! and the UDP socket thread) and reconnects when the server goes away; [`identity`] keeps
//! our client certificate and the servers' certificates trusted on first use.
//!
//! Voice is encrypted hop by hop: the server decrypts and could listen.

pub mod client;
pub mod connection;
pub mod crypt;
pub mod events;
pub mod identity;
pub mod messages;
pub mod presence;
pub mod speakers;
pub mod voice;

/// Everything a Mumble connection can fail with.
#[derive(Debug, thiserror::Error)]
pub enum MumbleError {
    #[error("cannot reach the Mumble server {server}: {reason}")]
    Unreachable { server: String, reason: String },
    #[error("TLS with {server}: {reason}")]
    Tls { server: String, reason: String },
    #[error(
        "the certificate of {server} changed: it was {known}, it is now {seen}. If the server's \
         owner replaced it, remove its line from {file} to trust the new one"
    )]
    CertificateChanged {
        server: String,
        known: String,
        seen: String,
        file: String,
    },
    #[error("the Mumble server refused us: {0}")]
    Rejected(String),
    #[error("{0}")]
    Timeout(String),
    #[error("malformed Mumble data: {0}")]
    Malformed(String),
    #[error("not connected to the Mumble server")]
    NotConnected,
    #[error("client identity: {0}")]
    Identity(String),
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

#[cfg(test)]
mod tests;

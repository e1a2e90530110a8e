//! SRTP and SRTCP with AES_CM_128_HMAC_SHA1_80 (RFC 3711), over RustCrypto's AES, HMAC and
//! SHA-1, written against the RFC's test vectors: the project's one SRTP (direct calls, relay
//! rooms, SIP's SDES). docs/transport.md ("SRTP") says why no crate took its place.
//!
//! Two keying schemes share the transform ([`KeyScheme`]):
//! - RFC 3711 as other stacks speak it (a raw master key): one set of session keys for every
//!   stream, told apart by SSRC in the keystream IV (RFC 3711 section 9.1). A static key has no
//!   notion of a call: a recording of one replays into any later one.
//! - Per session (a room passphrase, lipcall to lipcall, with no handshake): every sender picks
//!   a random 32-bit session id when it starts, and its keys come from the master key, its SSRC
//!   and that id (RFC 3711's key derivation with both in its input). Each packet carries a
//!   session field before its tag: the id and the sender's clock (Unix seconds), both
//!   authenticated. A receiver takes up a stream (SSRC, id) it does not know only if that clock
//!   is within its tolerance of its own, so a recorded call replayed later is refused; a stream
//!   it knows is replay-checked for as long as the receiver lives, whether its peer comes and
//!   goes. What it cannot refuse: a recording replayed within the tolerance to a receiver that
//!   never saw that stream.
//!
//! Replay state is kept per stream (at most [`MAX_STREAMS`], the least recently used forgotten
//! first). The key derivation rate is 0 (session keys derived once per stream).

use std::collections::HashMap;
use std::time::{SystemTime, UNIX_EPOCH};

use aes::Aes128;
use aes::cipher::{BlockCipherEncrypt, KeyInit};
use hmac::{Hmac, Mac};
use sha1::Sha1;

/// Bytes of the truncated HMAC-SHA1 tag.
pub const TAG_LEN: usize = 10;
/// Bytes of the SRTCP E-flag + index word.
const SRTCP_INDEX_LEN: usize = 4;
/// Bytes of the per-session field (session id, sender's Unix seconds) before the tag.
pub const SESSION_FIELD_LEN: usize = 8;
/// Master key and master salt lengths.
pub const MASTER_KEY_LEN: usize = 16;
pub const MASTER_SALT_LEN: usize = 14;
/// PBKDF2-HMAC-SHA256 rounds for turning a passphrase into a master key.
pub const KDF_ROUNDS: u32 = 100_000;
/// Inbound streams whose replay state is kept; beyond, the least recently used is forgotten.
pub const MAX_STREAMS: usize = 256;
/// How far (seconds) a new stream's sender clock may be from ours, either way, by default.
pub const DEFAULT_CLOCK_TOLERANCE: u32 = 30;
const REPLAY_WINDOW: u64 = 64;
/// Set in the label of per-session key derivations, apart from RFC 3711's labels 0..=7.
const PER_SESSION_LABEL: u8 = 0x80;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SrtpError {
    #[error("packet too short for SRTP")]
    TooShort,
    #[error("malformed packet header")]
    Malformed,
    #[error("authentication failed")]
    AuthFailed,
    #[error("replayed or too old packet")]
    Replay,
    #[error(
        "a new SRTP stream stamped too far from our clock: a replay of an earlier call, or \
         clocks apart by more than the tolerance"
    )]
    Stale,
    #[error("a master key is 30 bytes (60 hex digits)")]
    KeyFormat,
}

/// How a master key becomes the keys of each stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeyScheme {
    /// RFC 3711 as is (libsrtp, GStreamer's srtpenc): the same keys for every stream and call.
    Rfc3711,
    /// Keys per sender session, announced and bound in every packet (lipcall to lipcall).
    PerSession,
}

/// The 30-byte SRTP master key + salt that every member of a room shares.
#[derive(Clone, PartialEq, Eq)]
pub struct MasterKey {
    pub key: [u8; MASTER_KEY_LEN],
    pub salt: [u8; MASTER_SALT_LEN],
    pub scheme: KeyScheme,
}

impl std::fmt::Debug for MasterKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MasterKey({:?}, ..)", self.scheme)
    }
}

impl MasterKey {
    /// A raw master key + salt, for other SRTP stacks: [`KeyScheme::Rfc3711`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, SrtpError> {
        if bytes.len() != MASTER_KEY_LEN + MASTER_SALT_LEN {
            return Err(SrtpError::KeyFormat);
        }
        let mut key = [0; MASTER_KEY_LEN];
        let mut salt = [0; MASTER_SALT_LEN];
        key.copy_from_slice(&bytes[..MASTER_KEY_LEN]);
        salt.copy_from_slice(&bytes[MASTER_KEY_LEN..]);
        Ok(Self {
            key,
            salt,
            scheme: KeyScheme::Rfc3711,
        })
    }

    pub fn from_hex(hex: &str) -> Result<Self, SrtpError> {
        let hex = hex.trim();
        if !hex.is_ascii() || !hex.len().is_multiple_of(2) {
            return Err(SrtpError::KeyFormat);
        }
        let bytes = (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).map_err(|_| SrtpError::KeyFormat))
            .collect::<Result<Vec<u8>, _>>()?;
        Self::from_bytes(&bytes)
    }

    pub fn to_hex(&self) -> String {
        self.key
            .iter()
            .chain(&self.salt)
            .map(|b| format!("{b:02x}"))
            .collect()
    }

    /// PBKDF2-HMAC-SHA256 over the passphrase, salted with the room name, so that the same
    /// passphrase gives different keys in different rooms. Keys are per sender session
    /// ([`KeyScheme::PerSession`]): only lipcall speaks it.
    pub fn from_passphrase(passphrase: &str, room: &str) -> Self {
        let salt = format!("lipcall-srtp-v1:{room}");
        let out = pbkdf2::pbkdf2_hmac_array::<sha2::Sha256, 30>(
            passphrase.as_bytes(),
            salt.as_bytes(),
            KDF_ROUNDS,
        );
        let mut key = [0; MASTER_KEY_LEN];
        let mut master_salt = [0; MASTER_SALT_LEN];
        key.copy_from_slice(&out[..MASTER_KEY_LEN]);
        master_salt.copy_from_slice(&out[MASTER_KEY_LEN..]);
        Self {
            key,
            salt: master_salt,
            scheme: KeyScheme::PerSession,
        }
    }
}

/// AES in counter mode as RFC 3711 4.1.1 defines it: block j is AES(iv + j).
fn aes_cm(cipher: &Aes128, iv: [u8; 16], data: &mut [u8]) {
    let base = u128::from_be_bytes(iv);
    for (j, chunk) in data.chunks_mut(16).enumerate() {
        let mut block = base.wrapping_add(j as u128).to_be_bytes().into();
        cipher.encrypt_block(&mut block);
        for (d, k) in chunk.iter_mut().zip(block.iter()) {
            *d ^= k;
        }
    }
}

/// A sender's stream under a per-session key: its SSRC and session id.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct StreamId {
    ssrc: u32,
    session: u32,
}

/// The key derivation function of RFC 3711 4.3.1 with a key derivation rate of 0.
struct Kdf {
    cipher: Aes128,
    salt: [u8; MASTER_SALT_LEN],
}

impl Kdf {
    fn new(master: &MasterKey) -> Self {
        Self {
            cipher: Aes128::new(&master.key.into()),
            salt: master.salt,
        }
    }

    /// key_id = label || r (48 bits, 0 here) is XORed into the salt's low 56 bits. A
    /// per-session stream also puts its SSRC above the key id and its session id in r, with
    /// `PER_SESSION_LABEL` set in the label: inputs RFC 3711 never uses.
    fn derive(&self, label: u8, stream: Option<StreamId>, out: &mut [u8]) {
        let mut iv = [0u8; 16];
        iv[..MASTER_SALT_LEN].copy_from_slice(&self.salt);
        iv[7] ^= label;
        if let Some(stream) = stream {
            iv[7] ^= PER_SESSION_LABEL;
            for (i, b) in stream.ssrc.to_be_bytes().iter().enumerate() {
                iv[3 + i] ^= b;
            }
            for (i, b) in stream.session.to_be_bytes().iter().enumerate() {
                iv[8 + i] ^= b;
            }
        }
        out.fill(0);
        aes_cm(&self.cipher, iv, out);
    }

    fn session_keys(&self, first_label: u8, stream: Option<StreamId>) -> SessionKeys {
        let mut key = [0u8; 16];
        let mut auth = [0u8; 20];
        let mut salt = [0u8; MASTER_SALT_LEN];
        self.derive(first_label, stream, &mut key);
        self.derive(first_label + 1, stream, &mut auth);
        self.derive(first_label + 2, stream, &mut salt);
        SessionKeys {
            cipher: Aes128::new(&key.into()),
            // HMAC accepts keys of any length.
            mac: <Hmac<Sha1> as KeyInit>::new_from_slice(&auth)
                .unwrap_or_else(|_| unreachable!("HMAC takes any key length")),
            salt,
        }
    }

    /// SRTP and SRTCP keys of one stream (`None`: RFC 3711's, for every stream).
    fn stream_keys(&self, stream: Option<StreamId>) -> StreamKeys {
        StreamKeys {
            rtp: self.session_keys(0, stream),
            rtcp: self.session_keys(3, stream),
        }
    }
}

#[derive(Clone)]
struct SessionKeys {
    cipher: Aes128,
    mac: Hmac<Sha1>,
    salt: [u8; MASTER_SALT_LEN],
}

#[derive(Clone)]
struct StreamKeys {
    rtp: SessionKeys,
    rtcp: SessionKeys,
}

impl SessionKeys {
    /// IV = (k_s * 2^16) XOR (SSRC * 2^64) XOR (index * 2^16).
    fn iv(&self, ssrc: u32, index: u64) -> [u8; 16] {
        let mut iv = [0u8; 16];
        iv[..MASTER_SALT_LEN].copy_from_slice(&self.salt);
        for (i, b) in ssrc.to_be_bytes().iter().enumerate() {
            iv[4 + i] ^= b;
        }
        for (i, b) in index.to_be_bytes()[2..].iter().enumerate() {
            iv[8 + i] ^= b;
        }
        iv
    }

    fn tag(&self, parts: &[&[u8]]) -> [u8; TAG_LEN] {
        let mut mac = self.mac.clone();
        for p in parts {
            mac.update(p);
        }
        let full = mac.finalize().into_bytes();
        let mut tag = [0u8; TAG_LEN];
        tag.copy_from_slice(&full[..TAG_LEN]);
        tag
    }

    fn verify(&self, parts: &[&[u8]], tag: &[u8]) -> bool {
        let mut mac = self.mac.clone();
        for p in parts {
            mac.update(p);
        }
        mac.verify_truncated_left(tag).is_ok()
    }
}

/// A sliding window over the highest index seen (RFC 3711 3.3.2).
#[derive(Debug, Clone, Copy, Default)]
struct ReplayWindow {
    highest: u64,
    seen: u64,
    started: bool,
}

impl ReplayWindow {
    fn check(&self, index: u64) -> Result<(), SrtpError> {
        if !self.started || index > self.highest {
            return Ok(());
        }
        let age = self.highest - index;
        if age >= REPLAY_WINDOW || self.seen & (1 << age) != 0 {
            return Err(SrtpError::Replay);
        }
        Ok(())
    }

    fn accept(&mut self, index: u64) {
        if !self.started {
            *self = Self {
                highest: index,
                seen: 1,
                started: true,
            };
        } else if index > self.highest {
            let shift = index - self.highest;
            self.seen = if shift >= REPLAY_WINDOW {
                0
            } else {
                self.seen << shift
            } | 1;
            self.highest = index;
        } else {
            self.seen |= 1 << (self.highest - index);
        }
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct InboundRtp {
    roc: u32,
    highest_seq: u16,
    replay: ReplayWindow,
}

impl InboundRtp {
    /// Guesses the packet index from its sequence number (RFC 3711 appendix A).
    fn estimate(&self, seq: u16) -> Option<(u32, u64)> {
        if !self.replay.started {
            return Some((self.roc, index(self.roc, seq)));
        }
        let s_l = i64::from(self.highest_seq);
        let s = i64::from(seq);
        let roc = i64::from(self.roc);
        let v = if s_l < 32768 {
            if s - s_l > 32768 { roc - 1 } else { roc }
        } else if s_l - 32768 > s {
            roc + 1
        } else {
            roc
        };
        let v = u32::try_from(v).ok()?;
        Some((v, index(v, seq)))
    }
}

fn index(roc: u32, seq: u16) -> u64 {
    (u64::from(roc) << 16) | u64::from(seq)
}

/// Length of an RTP header including CSRCs and extension, checked against the packet.
fn rtp_header_len(packet: &[u8]) -> Result<usize, SrtpError> {
    let parsed = rtp_types::RtpPacket::parse(packet).map_err(|_| SrtpError::Malformed)?;
    Ok(parsed.payload_offset())
}

/// Our streams: per SSRC, its keys, the rollover counter and SRTCP index.
struct Outbound {
    keys: StreamKeys,
    roc: u32,
    last_seq: u16,
    started: bool,
    rtcp_index: u32,
}

/// A remote stream: its keys and replay state, and when it was last used.
struct Inbound {
    keys: StreamKeys,
    rtp: InboundRtp,
    rtcp: ReplayWindow,
    last_used: u64,
}

/// The current time in Unix seconds, as the session field carries it.
fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// One end's SRTP state for a room: keys and counters of our stream(s), keys and replay
/// windows of every remote stream.
pub struct Srtp {
    scheme: KeyScheme,
    kdf: Kdf,
    /// RFC 3711's keys, which every stream uses under that scheme.
    shared: StreamKeys,
    /// Our session id (per-session scheme).
    session: u32,
    clock_tolerance: u32,
    outbound: HashMap<u32, Outbound>,
    inbound: HashMap<StreamId, Inbound>,
    /// Packets accepted so far: the clock of least-recently-used eviction.
    uses: u64,
}

impl std::fmt::Debug for Srtp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Srtp")
            .field("scheme", &self.scheme)
            .field("inbound_streams", &self.inbound.len())
            .finish_non_exhaustive()
    }
}

impl Srtp {
    /// A fresh end of a call; under the per-session scheme with a random session id of its own.
    pub fn new(master: &MasterKey) -> Result<Self, getrandom::Error> {
        let session = match master.scheme {
            KeyScheme::Rfc3711 => 0,
            KeyScheme::PerSession => getrandom::u32()?,
        };
        Ok(Self::with_session(master, session))
    }

    fn with_session(master: &MasterKey, session: u32) -> Self {
        let kdf = Kdf::new(master);
        Self {
            scheme: master.scheme,
            shared: kdf.stream_keys(None),
            kdf,
            session,
            clock_tolerance: DEFAULT_CLOCK_TOLERANCE,
            outbound: HashMap::new(),
            inbound: HashMap::new(),
            uses: 0,
        }
    }

    /// How far (seconds, either way) a new stream's sender clock may be from ours (per-session
    /// scheme); at least 1, as the clocks are read in whole seconds.
    pub fn set_clock_tolerance(&mut self, seconds: u32) {
        self.clock_tolerance = seconds.max(1);
    }

    fn field_len(&self) -> usize {
        match self.scheme {
            KeyScheme::Rfc3711 => 0,
            KeyScheme::PerSession => SESSION_FIELD_LEN,
        }
    }

    fn keys_for(&self, stream: StreamId) -> StreamKeys {
        match self.scheme {
            KeyScheme::Rfc3711 => self.shared.clone(),
            KeyScheme::PerSession => self.kdf.stream_keys(Some(stream)),
        }
    }

    fn outbound(&mut self, ssrc: u32, seq: u16) -> &mut Outbound {
        if !self.outbound.contains_key(&ssrc) {
            let keys = self.keys_for(StreamId {
                ssrc,
                session: self.session,
            });
            self.outbound.insert(
                ssrc,
                Outbound {
                    keys,
                    roc: 0,
                    last_seq: seq,
                    started: false,
                    rtcp_index: 0,
                },
            );
        }
        self.outbound
            .get_mut(&ssrc)
            .unwrap_or_else(|| unreachable!("inserted above"))
    }

    /// Our session field: the session id and the time now.
    fn session_field(&self, now: u64) -> [u8; SESSION_FIELD_LEN] {
        let mut field = [0u8; SESSION_FIELD_LEN];
        field[..4].copy_from_slice(&self.session.to_be_bytes());
        field[4..].copy_from_slice(&(now as u32).to_be_bytes());
        field
    }

    /// The stream a packet belongs to and the sender's clock, from its session field (the
    /// `SESSION_FIELD_LEN` bytes of `field`, empty under RFC 3711).
    fn stream_of(ssrc: u32, field: &[u8]) -> (StreamId, Option<u32>) {
        match field {
            [a, b, c, d, t0, t1, t2, t3] => (
                StreamId {
                    ssrc,
                    session: u32::from_be_bytes([*a, *b, *c, *d]),
                },
                Some(u32::from_be_bytes([*t0, *t1, *t2, *t3])),
            ),
            _ => (StreamId { ssrc, session: 0 }, None),
        }
    }

    /// A stream not seen before is taken up only when its sender's clock is near ours.
    fn check_fresh(&self, sent_at: Option<u32>, now: u64) -> Result<(), SrtpError> {
        let Some(sent_at) = sent_at else {
            return Ok(());
        };
        let apart = (now as u32).wrapping_sub(sent_at) as i32;
        if apart.unsigned_abs() > self.clock_tolerance {
            return Err(SrtpError::Stale);
        }
        Ok(())
    }

    /// Files a remote stream's new state; a new stream beyond `MAX_STREAMS` takes the place of
    /// the least recently used.
    fn keep(
        &mut self,
        stream: StreamId,
        new_keys: Option<StreamKeys>,
        update: impl FnOnce(&mut Inbound),
    ) {
        self.uses += 1;
        let uses = self.uses;
        if let Some(keys) = new_keys {
            if self.inbound.len() >= MAX_STREAMS
                && let Some(oldest) = self
                    .inbound
                    .iter()
                    .min_by_key(|(_, s)| s.last_used)
                    .map(|(&id, _)| id)
            {
                self.inbound.remove(&oldest);
            }
            self.inbound.insert(
                stream,
                Inbound {
                    keys,
                    rtp: InboundRtp::default(),
                    rtcp: ReplayWindow::default(),
                    last_used: uses,
                },
            );
        }
        if let Some(state) = self.inbound.get_mut(&stream) {
            state.last_used = uses;
            update(state);
        }
    }

    /// Encrypts an RTP packet in place and appends its authentication tag (after the session
    /// field, per session).
    pub fn protect_rtp(&mut self, packet: &mut Vec<u8>) -> Result<(), SrtpError> {
        self.protect_rtp_at(packet, unix_now())
    }

    fn protect_rtp_at(&mut self, packet: &mut Vec<u8>, now: u64) -> Result<(), SrtpError> {
        let header_len = rtp_header_len(packet)?;
        let ssrc = u32::from_be_bytes([packet[8], packet[9], packet[10], packet[11]]);
        let seq = u16::from_be_bytes([packet[2], packet[3]]);
        let field = self.session_field(now);
        let per_session = self.scheme == KeyScheme::PerSession;
        let out = self.outbound(ssrc, seq);
        if out.started && seq < out.last_seq && out.last_seq - seq > 32768 {
            out.roc = out.roc.wrapping_add(1);
        }
        out.last_seq = seq;
        out.started = true;
        let roc = out.roc;
        let keys = &out.keys.rtp;
        let iv = keys.iv(ssrc, index(roc, seq));
        aes_cm(&keys.cipher, iv, &mut packet[header_len..]);
        if per_session {
            packet.extend_from_slice(&field);
        }
        let tag = keys.tag(&[packet, &roc.to_be_bytes()]);
        packet.extend_from_slice(&tag);
        Ok(())
    }

    /// Authenticates, replay-checks and decrypts an SRTP packet in place (the session field and
    /// tag are removed).
    pub fn unprotect_rtp(&mut self, packet: &mut Vec<u8>) -> Result<(), SrtpError> {
        self.unprotect_rtp_at(packet, unix_now())
    }

    fn unprotect_rtp_at(&mut self, packet: &mut Vec<u8>, now: u64) -> Result<(), SrtpError> {
        let field_len = self.field_len();
        if packet.len() < 12 + field_len + TAG_LEN {
            return Err(SrtpError::TooShort);
        }
        let body_len = packet.len() - TAG_LEN;
        let plain_len = body_len - field_len;
        let header_len = rtp_header_len(&packet[..plain_len])?;
        let ssrc = u32::from_be_bytes([packet[8], packet[9], packet[10], packet[11]]);
        let seq = u16::from_be_bytes([packet[2], packet[3]]);
        let (stream, sent_at) = Self::stream_of(ssrc, &packet[plain_len..body_len]);
        let mut new_keys = None;
        let (keys, mut state, new) = match self.inbound.get(&stream) {
            Some(s) => (&s.keys, s.rtp, false),
            None => (
                &*new_keys.insert(self.keys_for(stream)),
                InboundRtp::default(),
                true,
            ),
        };
        let (roc, idx) = state.estimate(seq).ok_or(SrtpError::Replay)?;
        state.replay.check(idx)?;
        let (body, tag) = packet.split_at(body_len);
        if !keys.rtp.verify(&[body, &roc.to_be_bytes()], tag) {
            return Err(SrtpError::AuthFailed);
        }
        if new {
            self.check_fresh(sent_at, now)?;
        }
        let iv = keys.rtp.iv(ssrc, idx);
        packet.truncate(plain_len);
        aes_cm(&keys.rtp.cipher, iv, &mut packet[header_len..]);
        if !state.replay.started || roc > state.roc {
            state.roc = roc;
            state.highest_seq = seq;
        } else if roc == state.roc && seq > state.highest_seq {
            state.highest_seq = seq;
        }
        state.replay.accept(idx);
        self.keep(stream, new_keys, |s| s.rtp = state);
        Ok(())
    }

    /// Encrypts a compound RTCP packet in place, then appends E-flag + index, the session field
    /// (per session) and the tag.
    pub fn protect_rtcp(&mut self, packet: &mut Vec<u8>) -> Result<(), SrtpError> {
        self.protect_rtcp_at(packet, unix_now())
    }

    fn protect_rtcp_at(&mut self, packet: &mut Vec<u8>, now: u64) -> Result<(), SrtpError> {
        if packet.len() < 8 {
            return Err(SrtpError::TooShort);
        }
        let ssrc = u32::from_be_bytes([packet[4], packet[5], packet[6], packet[7]]);
        let field = self.session_field(now);
        let per_session = self.scheme == KeyScheme::PerSession;
        let out = self.outbound(ssrc, 0);
        let idx = out.rtcp_index & 0x7fff_ffff;
        out.rtcp_index = (idx + 1) & 0x7fff_ffff;
        let keys = &out.keys.rtcp;
        let iv = keys.iv(ssrc, u64::from(idx));
        aes_cm(&keys.cipher, iv, &mut packet[8..]);
        packet.extend_from_slice(&(idx | 0x8000_0000).to_be_bytes());
        if per_session {
            packet.extend_from_slice(&field);
        }
        let tag = keys.tag(&[packet]);
        packet.extend_from_slice(&tag);
        Ok(())
    }

    /// Authenticates, replay-checks and decrypts an SRTCP packet in place.
    pub fn unprotect_rtcp(&mut self, packet: &mut Vec<u8>) -> Result<(), SrtpError> {
        self.unprotect_rtcp_at(packet, unix_now())
    }

    fn unprotect_rtcp_at(&mut self, packet: &mut Vec<u8>, now: u64) -> Result<(), SrtpError> {
        let field_len = self.field_len();
        if packet.len() < 8 + SRTCP_INDEX_LEN + field_len + TAG_LEN {
            return Err(SrtpError::TooShort);
        }
        let body_len = packet.len() - TAG_LEN;
        let index_end = body_len - field_len;
        let ssrc = u32::from_be_bytes([packet[4], packet[5], packet[6], packet[7]]);
        let (stream, sent_at) = Self::stream_of(ssrc, &packet[index_end..body_len]);
        let mut new_keys = None;
        let (keys, mut window, new) = match self.inbound.get(&stream) {
            Some(s) => (&s.keys, s.rtcp, false),
            None => (
                &*new_keys.insert(self.keys_for(stream)),
                ReplayWindow::default(),
                true,
            ),
        };
        let e_index = u32::from_be_bytes([
            packet[index_end - 4],
            packet[index_end - 3],
            packet[index_end - 2],
            packet[index_end - 1],
        ]);
        let idx = u64::from(e_index & 0x7fff_ffff);
        window.check(idx)?;
        let (body, tag) = packet.split_at(body_len);
        if !keys.rtcp.verify(&[body], tag) {
            return Err(SrtpError::AuthFailed);
        }
        if new {
            self.check_fresh(sent_at, now)?;
        }
        let iv = keys.rtcp.iv(ssrc, idx);
        packet.truncate(index_end - SRTCP_INDEX_LEN);
        if e_index & 0x8000_0000 != 0 {
            aes_cm(&keys.rtcp.cipher, iv, &mut packet[8..]);
        }
        window.accept(idx);
        self.keep(stream, new_keys, |s| s.rtcp = window);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        let s: String = s.split_whitespace().collect();
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// RFC 3711 appendix B.2: the AES-CM keystream.
    #[test]
    fn rfc3711_b2_aes_cm_keystream() {
        let key: [u8; 16] = hex("2B7E151628AED2A6ABF7158809CF4F3C").try_into().unwrap();
        let cipher = Aes128::new(&key.into());
        let iv: [u8; 16] = hex("F0F1F2F3F4F5F6F7F8F9FAFBFCFD0000").try_into().unwrap();
        let mut stream = vec![0u8; 16 * 0xff02];
        aes_cm(&cipher, iv, &mut stream);
        let block = |j: usize| stream[16 * j..16 * (j + 1)].to_vec();
        assert_eq!(block(0), hex("E03EAD0935C95E80E166B16DD92B4EB4"));
        assert_eq!(block(1), hex("D23513162B02D0F72A43A2FE4A5F97AB"));
        assert_eq!(block(2), hex("41E95B3BB0A2E8DD477901E4FCA894C0"));
        assert_eq!(block(0xfeff), hex("EC8CDF7398607CB0F2D21675EA9EA1E4"));
        assert_eq!(block(0xff00), hex("362B7C3C6773516318A077D7FC5073AE"));
        assert_eq!(block(0xff01), hex("6A2CC3787889374FBEB4C81B17BA6C44"));
    }

    /// RFC 3711 appendix B.3: session keys from a master key.
    #[test]
    fn rfc3711_b3_key_derivation() {
        let master = MasterKey::from_bytes(&hex(
            "E1F97A0D3E018BE0D64FA32C06DE4139 0EC675AD498AFEEBB6960B3AABE6",
        ))
        .unwrap();
        let kdf = Kdf::new(&master);
        let mut key = [0u8; 16];
        kdf.derive(0, None, &mut key);
        assert_eq!(key.to_vec(), hex("C61E7A93744F39EE10734AFE3FF7A087"));
        let mut salt = [0u8; 14];
        kdf.derive(2, None, &mut salt);
        assert_eq!(salt.to_vec(), hex("30CBBC08863D8C85D49DB34A9AE1"));
        let mut auth = [0u8; 94];
        kdf.derive(1, None, &mut auth);
        assert_eq!(
            auth.to_vec(),
            hex(
                "CEBE321F6FF7716B6FD4AB49AF256A156D38BAA48F0A0ACF3C34E2359E6CDBCE
                 E049646C43D9327AD175578EF72270986371C10C9A369AC2F94A8C5FBCDDDC25
                 6D6E919A48B610EF17C2041E474035766B68642C59BBFC2F34DB60DBDFB2"
            )
        );
    }

    fn rtp(seq: u16, payload: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        crate::net::rtp::write(
            &crate::net::rtp::RtpHeader {
                marker: false,
                payload_type: 110,
                sequence: seq,
                timestamp: 1000,
                ssrc: 0xdeca_fbad,
            },
            payload,
            &mut out,
        )
        .unwrap();
        out
    }

    #[test]
    fn rtp_round_trip_replay_and_tamper() {
        let master = MasterKey::from_passphrase("secret", "room");
        let mut tx = Srtp::new(&master).unwrap();
        let mut rx = Srtp::new(&master).unwrap();
        let plain = rtp(65534, b"speex frame bytes");
        let mut p = plain.clone();
        tx.protect_rtp(&mut p).unwrap();
        assert_eq!(p.len(), plain.len() + SESSION_FIELD_LEN + TAG_LEN);
        assert_ne!(&p[12..plain.len()], &plain[12..]);
        let copy = p.clone();
        rx.unprotect_rtp(&mut p).unwrap();
        assert_eq!(p, plain);
        assert_eq!(rx.unprotect_rtp(&mut copy.clone()), Err(SrtpError::Replay));
        let mut bad = copy.clone();
        bad[14] ^= 1;
        // A tampered copy of a packet already seen fails the replay check first; a fresh one
        // fails authentication.
        let mut fresh = rtp(65535, b"another");
        tx.protect_rtp(&mut fresh).unwrap();
        let mut tampered = fresh.clone();
        tampered[13] ^= 0x40;
        assert_eq!(rx.unprotect_rtp(&mut tampered), Err(SrtpError::AuthFailed));
        rx.unprotect_rtp(&mut fresh).unwrap();
        // Across the sequence wrap the rollover counter moves on both sides.
        for seq in [0u16, 1, 2] {
            let mut p = rtp(seq, b"after wrap");
            tx.protect_rtp(&mut p).unwrap();
            rx.unprotect_rtp(&mut p).unwrap();
            assert_eq!(p, rtp(seq, b"after wrap"));
        }
        let mut other = Srtp::new(&MasterKey::from_passphrase("wrong", "room")).unwrap();
        let mut p = rtp(5, b"x");
        tx.protect_rtp(&mut p).unwrap();
        assert_eq!(other.unprotect_rtp(&mut p), Err(SrtpError::AuthFailed));
    }

    #[test]
    fn rtcp_round_trip() {
        let master = MasterKey::from_hex(&"ab".repeat(30)).unwrap();
        let mut tx = Srtp::new(&master).unwrap();
        let mut rx = Srtp::new(&master).unwrap();
        let mut plain = Vec::new();
        crate::net::rtcp::build(
            &crate::net::rtcp::Outgoing {
                ssrc: 9,
                cname: "c",
                name: Some("n"),
                ..Default::default()
            },
            &mut plain,
        )
        .unwrap();
        let mut p = plain.clone();
        tx.protect_rtcp(&mut p).unwrap();
        let copy = p.clone();
        rx.unprotect_rtcp(&mut p).unwrap();
        assert_eq!(p, plain);
        assert_eq!(rx.unprotect_rtcp(&mut copy.clone()), Err(SrtpError::Replay));
    }

    #[test]
    fn passphrase_keys_depend_on_room_and_hex_round_trips() {
        let a = MasterKey::from_passphrase("pw", "a");
        assert_ne!(a, MasterKey::from_passphrase("pw", "b"));
        let raw = MasterKey::from_hex(&a.to_hex()).unwrap();
        assert_eq!((raw.key, raw.salt), (a.key, a.salt));
        // A passphrase is lipcall's own: keys per session. A raw key is RFC 3711 as is.
        assert_eq!(a.scheme, KeyScheme::PerSession);
        assert_eq!(raw.scheme, KeyScheme::Rfc3711);
        assert_eq!(MasterKey::from_hex("zz"), Err(SrtpError::KeyFormat));
        assert_eq!(MasterKey::from_hex("é"), Err(SrtpError::KeyFormat));
    }

    /// A per-session key without PBKDF2's 100 000 rounds.
    fn session_key() -> MasterKey {
        MasterKey {
            scheme: KeyScheme::PerSession,
            ..MasterKey::from_hex(&"c3".repeat(30)).unwrap()
        }
    }

    const NOW: u64 = 1_750_000_000;

    fn protected(tx: &mut Srtp, seq: u16, at: u64) -> Vec<u8> {
        let mut p = rtp(seq, b"frame");
        tx.protect_rtp_at(&mut p, at).unwrap();
        p
    }

    fn report(ssrc: u32) -> Vec<u8> {
        let mut plain = Vec::new();
        crate::net::rtcp::build(
            &crate::net::rtcp::Outgoing {
                ssrc,
                cname: "c",
                ..Default::default()
            },
            &mut plain,
        )
        .unwrap();
        plain
    }

    fn protected_report(tx: &mut Srtp, at: u64) -> Vec<u8> {
        let mut p = report(0xdeca_fbad);
        tx.protect_rtcp_at(&mut p, at).unwrap();
        p
    }

    #[test]
    fn per_session_packets_carry_their_session_bound_and_authenticated() {
        let key = session_key();
        let mut tx = Srtp::with_session(&key, 0x1234_5678);
        let mut rx = Srtp::with_session(&key, 9);
        let plain = rtp(10, b"frame");
        let p = protected(&mut tx, 10, NOW);
        assert_eq!(p.len(), plain.len() + SESSION_FIELD_LEN + TAG_LEN);
        let field = &p[plain.len()..plain.len() + SESSION_FIELD_LEN];
        assert_eq!(field[..4], 0x1234_5678u32.to_be_bytes());
        assert_eq!(field[4..], (NOW as u32).to_be_bytes());
        // Another session id, or another clock, fails: the field is bound to the packet.
        for at in [plain.len(), plain.len() + 7] {
            let mut forged = p.clone();
            forged[at] ^= 1;
            assert_eq!(
                rx.unprotect_rtp_at(&mut forged, NOW),
                Err(SrtpError::AuthFailed)
            );
        }
        let mut ok = p.clone();
        rx.unprotect_rtp_at(&mut ok, NOW + 1).unwrap();
        assert_eq!(ok, plain);
        // The same SSRC in another session has another keystream, and so has RFC 3711 under
        // the same master key, whose packets carry no field.
        let q = protected(&mut Srtp::with_session(&key, 0x1234_5679), 10, NOW);
        assert_ne!(p[12..plain.len()], q[12..plain.len()]);
        let mut raw = Srtp::new(&MasterKey::from_hex(&"c3".repeat(30)).unwrap()).unwrap();
        let mut r = plain.clone();
        raw.protect_rtp(&mut r).unwrap();
        assert_eq!(r.len(), plain.len() + TAG_LEN);
        assert_ne!(r[12..plain.len()], p[12..plain.len()]);
        // SRTCP likewise.
        let c = protected_report(&mut tx, NOW);
        let mut forged = c.clone();
        let field_at = c.len() - TAG_LEN - SESSION_FIELD_LEN;
        forged[field_at + 7] ^= 1;
        assert_eq!(
            rx.unprotect_rtcp_at(&mut forged, NOW),
            Err(SrtpError::AuthFailed)
        );
        let mut ok = c.clone();
        rx.unprotect_rtcp_at(&mut ok, NOW).unwrap();
        assert_eq!(ok, report(0xdeca_fbad));
    }

    #[test]
    fn a_recording_replayed_into_a_later_receiver_is_refused() {
        let key = session_key();
        let mut tx = Srtp::with_session(&key, 77);
        let recording: Vec<Vec<u8>> = (0..50).map(|k| protected(&mut tx, 100 + k, NOW)).collect();
        let report = protected_report(&mut tx, NOW);
        // A receiver that starts after the tolerance takes up nothing of it, media or report;
        // nor a sender whose clock runs ahead by more.
        let mut later = Srtp::with_session(&key, 1);
        for p in &recording {
            let at = NOW + u64::from(DEFAULT_CLOCK_TOLERANCE) + 1;
            assert_eq!(
                later.unprotect_rtp_at(&mut p.clone(), at),
                Err(SrtpError::Stale)
            );
        }
        assert_eq!(
            later.unprotect_rtcp_at(&mut report.clone(), NOW + 31),
            Err(SrtpError::Stale)
        );
        assert_eq!(
            later.unprotect_rtp_at(&mut recording[0].clone(), NOW - 31),
            Err(SrtpError::Stale)
        );
        assert!(later.inbound.is_empty());
        // A sender starting then is heard.
        let mut fresh = Srtp::with_session(&key, 78);
        let mut p = protected(&mut fresh, 5, NOW + 31);
        later.unprotect_rtp_at(&mut p, NOW + 31).unwrap();
        // Within the tolerance, a receiver that never saw the stream cannot tell a replay.
        let mut soon = Srtp::with_session(&key, 2);
        soon.unprotect_rtp_at(&mut recording[0].clone(), NOW + 30)
            .unwrap();
        let mut strict = Srtp::with_session(&key, 3);
        strict.set_clock_tolerance(1);
        assert_eq!(
            strict.unprotect_rtp_at(&mut recording[0].clone(), NOW + 2),
            Err(SrtpError::Stale)
        );
        strict
            .unprotect_rtp_at(&mut recording[0].clone(), NOW + 1)
            .unwrap();
    }

    #[test]
    fn replay_state_lives_as_long_as_the_receiver() {
        // Replayed after its peer has gone, a stream the receiver knows is a replay, not new.
        let key = session_key();
        let mut tx = Srtp::with_session(&key, 5);
        let mut rx = Srtp::with_session(&key, 6);
        let recording: Vec<Vec<u8>> = (0..100).map(|k| protected(&mut tx, k, NOW)).collect();
        let report = protected_report(&mut tx, NOW);
        for p in &recording {
            rx.unprotect_rtp_at(&mut p.clone(), NOW).unwrap();
        }
        rx.unprotect_rtcp_at(&mut report.clone(), NOW).unwrap();
        for p in &recording {
            assert_eq!(
                rx.unprotect_rtp_at(&mut p.clone(), NOW + 10),
                Err(SrtpError::Replay)
            );
        }
        assert_eq!(
            rx.unprotect_rtcp_at(&mut report.clone(), NOW + 10),
            Err(SrtpError::Replay)
        );
        // Beyond MAX_STREAMS the least recently used stream is forgotten: a new stream again,
        // taken up only while its clock is fresh.
        for s in 0..MAX_STREAMS as u32 {
            let mut p = protected(&mut Srtp::with_session(&key, 1000 + s), 1, NOW + 40);
            rx.unprotect_rtp_at(&mut p, NOW + 40).unwrap();
        }
        assert_eq!(rx.inbound.len(), MAX_STREAMS);
        let first = StreamId {
            ssrc: 0xdeca_fbad,
            session: 5,
        };
        assert!(!rx.inbound.contains_key(&first));
        assert_eq!(
            rx.unprotect_rtp_at(&mut recording[99].clone(), NOW + 40),
            Err(SrtpError::Stale)
        );
    }

    #[test]
    fn per_session_packets_cut_or_flipped_are_refused_not_panicking() {
        let key = session_key();
        let mut tx = Srtp::with_session(&key, 5);
        let media = protected(&mut tx, 1, NOW);
        let report = protected_report(&mut tx, NOW);
        type Unprotect = fn(&mut Srtp, &mut Vec<u8>, u64) -> Result<(), SrtpError>;
        let cases: [(&Vec<u8>, Unprotect); 2] = [
            (&media, Srtp::unprotect_rtp_at),
            (&report, Srtp::unprotect_rtcp_at),
        ];
        for (packet, unprotect) in cases {
            let mut rx = Srtp::with_session(&key, 6);
            for cut in 0..packet.len() {
                assert!(unprotect(&mut rx, &mut packet[..cut].to_vec(), NOW).is_err());
                let _ = rx.unprotect_rtp_at(&mut packet[..cut].to_vec(), NOW);
                let _ = rx.unprotect_rtcp_at(&mut packet[..cut].to_vec(), NOW);
            }
            for bit in 0..packet.len() * 8 {
                let mut flipped = packet.clone();
                flipped[bit / 8] ^= 1 << (bit % 8);
                assert!(unprotect(&mut rx, &mut flipped, NOW).is_err(), "bit {bit}");
            }
            unprotect(&mut rx, &mut packet.clone(), NOW).unwrap();
        }
    }
}

//! `lipcall send`, `lipcall receive` and `lipcall relay`: the headless real-time transport.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use zeroize::Zeroizing;

use super::playout::{DIRECT, open_outputs, play};
use super::recording::{TICK, stop_flag, stopped};
use crate::call::media::{MediaError, MediaFile, MediaKind, Packets};
use crate::codec::any::{Codec, EncoderSettings, PayloadMap};
use crate::codec::opus::codec::Bandwidth;
use crate::net::host_port::resolve_with_port;
use crate::net::session::{Session, SessionConfig};
use crate::net::srtp::MasterKey;
use crate::net::transport::PeerInfo;
use crate::secrets::SecretSource;
use crate::vocab::FrameFeatures;

/// How the call is keyed: a room passphrase (PBKDF2 over passphrase and room name) or a raw
/// 30-byte SRTP master key + salt, each from a file or the environment, never the arguments.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct KeyArgs {
    /// A file whose first line is the room passphrase (otherwise the variable LIPCALL_KEY):
    /// media is encrypted and authenticated with SRTP. Without either (or a hex key) the call
    /// is plain RTP.
    #[arg(long = "key-file", value_name = "FILE")]
    pub passphrase_file: Option<PathBuf>,
    /// A file whose first line is a raw SRTP master key + salt, 60 hex digits (otherwise the
    /// variable LIPCALL_KEY_HEX), e.g. to talk to GStreamer's srtpenc.
    #[arg(id = "key_hex", long = "key-hex-file", value_name = "FILE")]
    pub hex_file: Option<PathBuf>,
}

/// Where the room passphrase is read from.
pub const PASSPHRASE: SecretSource = SecretSource {
    flag: "--key-file",
    variable: "LIPCALL_KEY",
};

/// Where a raw SRTP master key + salt is read from.
pub const HEX_KEY: SecretSource = SecretSource {
    flag: "--key-hex-file",
    variable: "LIPCALL_KEY_HEX",
};

impl KeyArgs {
    /// The room passphrase (a Janus room's pin), if one is given.
    pub(crate) fn passphrase(&self) -> Result<Option<Zeroizing<String>>> {
        let passphrase = PASSPHRASE.read(self.passphrase_file.as_deref())?;
        if let Some(p) = &passphrase {
            super::parse_passphrase(p).map_err(anyhow::Error::msg)?;
        }
        Ok(passphrase)
    }

    /// Whether a key file is named (a variable in the environment is not asked for).
    pub(crate) fn named(&self) -> bool {
        self.passphrase_file.is_some() || self.hex_file.is_some()
    }

    fn master_key(&self, room: Option<&str>) -> Result<Option<MasterKey>> {
        let hex = HEX_KEY.read(self.hex_file.as_deref())?;
        match (self.passphrase()?, hex) {
            (Some(_), Some(_)) => bail!(
                "give either a passphrase ({}) or a hex key ({}), not both",
                PASSPHRASE.how_to_give(),
                HEX_KEY.how_to_give()
            ),
            (Some(p), None) => Ok(Some(MasterKey::from_passphrase(&p, room.unwrap_or("")))),
            (None, Some(h)) => Ok(Some(MasterKey::from_hex(h.trim()).context(HEX_KEY.flag)?)),
            (None, None) => Ok(None),
        }
    }
}

pub(crate) fn resolve(addr: &str) -> Result<SocketAddr> {
    Ok(resolve_with_port(addr)?)
}

fn any_port_like(addr: SocketAddr) -> SocketAddr {
    let ip: std::net::IpAddr = match addr {
        SocketAddr::V4(a) if a.ip().is_loopback() => [127, 0, 0, 1].into(),
        SocketAddr::V4(_) => [0, 0, 0, 0].into(),
        SocketAddr::V6(a) if a.ip().is_loopback() => std::net::Ipv6Addr::LOCALHOST.into(),
        SocketAddr::V6(_) => std::net::Ipv6Addr::UNSPECIFIED.into(),
    };
    SocketAddr::new(ip, 0)
}

fn announce_security(key: &Option<MasterKey>) {
    if key.is_some() {
        eprintln!("lipcall: media encrypted and authenticated (SRTP AES_CM_128_HMAC_SHA1_80)");
    } else {
        eprintln!(
            "lipcall: warning: the call is NOT encrypted (plain RTP); set LIPCALL_KEY or give \
             --key-file to encrypt"
        );
    }
}

/// When a send ends before its file does: `--seconds` after the start, or a signal.
pub(crate) struct Pacing {
    pub stop: Arc<AtomicBool>,
    pub until: Option<Instant>,
}

impl Pacing {
    /// Until `until` (to the file's end without it), and until SIGINT or SIGTERM.
    pub(crate) fn new(until: Option<Instant>) -> Result<Self> {
        Ok(Self {
            stop: stop_flag()?,
            until,
        })
    }
}

/// `seconds` from now, where given (and representable).
pub(crate) fn deadline(seconds: Option<f64>) -> Option<Instant> {
    seconds.and_then(|s| Instant::now().checked_add(Duration::from_secs_f64(s)))
}

/// How a paced send ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Paced {
    Whole,
    TimeUp,
    Stopped,
}

impl Paced {
    /// Says why the send ended early, if it did.
    pub(crate) fn announce(self) {
        match self {
            Self::Whole => {}
            Self::TimeUp => eprintln!("lipcall: --seconds is up; stopped sending"),
            Self::Stopped => eprintln!("lipcall: stopped by a signal"),
        }
    }
}

/// Longest sleep between two looks at the stop flag and the deadline.
const STOP_LOOK: Duration = Duration::from_millis(20);

/// Sends `packets` (payload, duration in RTP ticks of `codec`) each at its time from now, as a
/// live source would, until the last one, `pacing`'s deadline or a signal.
pub(crate) fn send_paced(
    packets: &[(Vec<u8>, u32)],
    codec: Codec,
    pacing: &Pacing,
    mut send: impl FnMut(&[u8], u32) -> Result<()>,
) -> Result<Paced> {
    let clock = f64::from(codec.clock_rate());
    let start = Instant::now();
    let mut at = 0u64;
    for (payload, duration) in packets {
        let due = start + Duration::from_secs_f64(at as f64 / clock);
        loop {
            if stopped(&pacing.stop) {
                return Ok(Paced::Stopped);
            }
            let now = Instant::now();
            if pacing.until.is_some_and(|until| now >= until) {
                return Ok(Paced::TimeUp);
            }
            match due.checked_duration_since(now) {
                Some(wait) if !wait.is_zero() => std::thread::sleep(wait.min(STOP_LOOK)),
                _ => break,
            }
        }
        send(payload, *duration)?;
        at += u64::from(*duration);
    }
    Ok(Paced::Whole)
}

/// What `send` sends ([`MediaFile::packets`]). A name of no known type whose content tells
/// nothing (or that cannot be read) is refused for its name.
pub(crate) fn load_packets(
    input: &Path,
    codec: Option<Codec>,
    settings: &EncoderSettings,
) -> Result<(Codec, Packets)> {
    let file = match MediaFile::open(input) {
        Ok(file) => file,
        Err(_) if MediaKind::from_extension(input).is_none() => {
            return Err(MediaError::Unknown(input.display().to_string()).into());
        }
        Err(e) => return Err(e.into()),
    };
    Ok(file.packets(codec, settings)?)
}

/// The payload-type map from `--pt CODEC=PT` flags.
fn payload_map(assignments: &[String]) -> Result<PayloadMap> {
    PayloadMap::default()
        .with_assignments(assignments)
        .context("--pt")
}

/// Says which codec an assignment took its type from and gave none back (`--pt speex=96` moves
/// Speex onto Opus's type: Opus is then not received). `send` refuses its own codec unmapped.
fn warn_unmapped(map: &PayloadMap) {
    for codec in Codec::ALL {
        if map.payload_type(codec).is_none() {
            eprintln!(
                "lipcall: warning: --pt leaves {codec} without a payload type: its packets are \
                 counted as unknown and dropped (map it with --pt {}=PT)",
                codec.name()
            );
        }
    }
}

/// `lipcall send` to a receiver or relay (`--janus`, in `commands::janus::SendCommand`, sends
/// into a Janus room instead). `to` is empty only with `--janus`.
#[derive(Debug, Clone, clap::Args)]
pub struct SendArgs {
    /// Audio to send: .wav (any rate, encoded here), or .spx or .opus (sent as they are,
    /// unless --codec asks for another codec).
    pub input: PathBuf,
    /// Receiver (or relay, with --room) as HOST:PORT.
    #[arg(
        long,
        value_name = "HOST:PORT",
        required_unless_present_any = ["janus", "mumble"],
        default_value = "",
        hide_default_value = true
    )]
    pub to: String,
    #[command(flatten)]
    pub key: KeyArgs,
    /// Display name sent to peers (RTCP SDES NAME).
    #[arg(long)]
    pub name: Option<String>,
    /// Join this room on the relay given by --to.
    #[arg(long)]
    pub room: Option<String>,
    /// The codec sent: speex, opus, pcmu or pcma (default: a coded file's own; Speex for
    /// a WAV). Opus goes at 20 kb/s with in-band FEC.
    #[arg(long, value_parser = parse_codec)]
    pub codec: Option<Codec>,
    /// The band Opus codes from a .wav (at 48 kHz): nb, mb, wb, swb or fb (up to 20 kHz),
    /// or auto (libopus picks by bitrate: 20 kb/s for nb and mb, 24 for wb, 32 above).
    #[arg(long, default_value = "fb", value_parser = super::parse_bandwidth)]
    pub bandwidth: Bandwidth,
    /// Opus's frame length, ms: 20, or 10 (10 ms less framing delay, twice the packets; see
    /// docs/audio.md). A .opus file is re-encoded for 10. Other codecs go in 20 ms frames.
    #[arg(long, default_value_t = 20, value_parser = super::parse_frame_ms)]
    pub frame_ms: u8,
    /// Speex quality for .wav input, 0 to 10.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(0..=10))]
    pub quality: u8,
    /// Carry a codec on another RTP payload type, e.g. opus=111 (repeatable). Without SDP the
    /// defaults are GStreamer's: speex=110, opus=96; pcmu=0 and pcma=8 are static.
    #[arg(long = "pt", value_name = "CODEC=PT", value_parser = parse_payload_type)]
    pub payload_types: Vec<String>,
    /// Send no RTCP (for receivers that take RTP only, such as a bare GStreamer udpsrc).
    #[arg(long)]
    pub no_rtcp: bool,
    /// Use this SSRC (hex) instead of a random one, for set-ups that need it in advance.
    #[arg(long, value_parser = parse_hex_u32)]
    pub ssrc: Option<u32>,
    /// Stop this many seconds after the start (otherwise at the file's end); with --janus or
    /// --mumble the join counts too (a join not done by then fails). Ctrl-C (SIGINT) or
    /// SIGTERM ends the send at any time, saying goodbye to the peers.
    #[arg(long, allow_hyphen_values = true, value_parser = super::parse_seconds)]
    pub seconds: Option<f64>,
}

pub fn send(args: &SendArgs) -> Result<()> {
    // The key first: core dumps are off from then on.
    let key = args.key.master_key(args.room.as_deref())?;
    let payloads = payload_map(&args.payload_types)?;
    let mut settings = EncoderSettings::wideband(args.bandwidth);
    settings.speex.quality = args.quality;
    settings.opus.frame_ms = args.frame_ms;
    if let Some(codec) = args.codec {
        super::check_frame_ms(codec, args.frame_ms)?;
    }
    let (codec, packets) = load_packets(&args.input, args.codec, &settings)?;
    super::check_frame_ms(codec, args.frame_ms)?;
    if packets.is_empty() {
        bail!("{}: no audio to send", args.input.display());
    }
    if payloads.payload_type(codec).is_none() {
        bail!("no RTP payload type is mapped to {codec} (--pt took it)");
    }
    let to = resolve(&args.to)?;
    announce_security(&key);
    let mut config = SessionConfig::new(any_port_like(to));
    config.destinations = vec![to];
    config.room = args.room.clone();
    config.key = key;
    config.name = args.name.clone();
    config.send_rtcp = !args.no_rtcp;
    config.ssrc = args.ssrc;
    config.codec = codec;
    config.payloads = payloads;
    let pacing = Pacing::new(deadline(args.seconds))?;
    let session = Session::start(config)?;
    if args.room.is_some() {
        wait_for_relay(&session, &pacing.stop, pacing.until)?;
    }
    let clock = f64::from(codec.clock_rate());
    let ticks: u64 = packets.iter().map(|(_, t)| u64::from(*t)).sum();
    eprintln!(
        "lipcall: sending {:.2} s ({} packets of {codec}) to {to} as SSRC {:08x}",
        ticks as f64 / clock,
        packets.len(),
        session.ssrc()
    );
    let start = Instant::now();
    let paced = send_paced(&packets, codec, &pacing, |payload, duration| {
        Ok(session.send_packet(payload, duration)?)
    })?;
    paced.announce();
    if paced == Paced::Whole {
        // Let the last packet's slot pass before saying BYE.
        std::thread::sleep(TICK);
    }
    session.leave();
    let stats = session.stats();
    eprintln!(
        "lipcall: sent {} packets in {:.2} s; send_errors={}",
        stats.sent_rtp,
        start.elapsed().as_secs_f64(),
        stats.send_errors
    );
    for peer in session.peers() {
        print_peer(&peer);
    }
    if stats.sent_rtp == 0 {
        bail!(
            "no packet could be sent to {to} ({} send errors)",
            stats.send_errors
        );
    }
    Ok(())
}

/// How long a join waits for the relay to confirm it.
const RELAY_JOIN_WAIT: Duration = Duration::from_secs(3);

/// Until the relay confirms our place in the room (its join handshake runs in the session),
/// for at most [`RELAY_JOIN_WAIT`] and never past `until` (the whole receive's end); a signal
/// (`stop`) ends the wait at once, and the receive then ends as stopped.
fn wait_for_relay(session: &Session, stop: &AtomicBool, until: Option<Instant>) -> Result<()> {
    let started = Instant::now();
    let deadline = until.map_or(started + RELAY_JOIN_WAIT, |until| {
        until.min(started + RELAY_JOIN_WAIT)
    });
    while Instant::now() < deadline {
        let stats = session.stats();
        if let Some(why) = stats.relay_refusal {
            bail!("the relay refused to join the room: {why}");
        }
        if stats.relay_joined || stopped(stop) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let waited = format!("{:.1} s", started.elapsed().as_secs_f64());
    let stats = session.stats();
    if stats.relay_outdated {
        bail!("the relay speaks another protocol version: update lipcall on both sides");
    }
    if stats.relay_challenges > 0 {
        bail!(
            "the relay sent a cookie but never confirmed the join within {waited} (are replies \
             from this address reaching it?)"
        );
    }
    bail!(
        "the relay did not answer the join within {waited} (no relay there, or one of an older \
         lipcall version)"
    )
}

pub(crate) fn print_peer(peer: &PeerInfo) {
    let j = &peer.receiver.jitter;
    let opt = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
    let codec = peer.receiver.codec.map_or("-", Codec::name);
    eprintln!(
        "peer {} name={:?} addr={} codec={codec} received={} played={} lost={} late={} \
         duplicates={} reordered={} concealed={} recovered={} stretched={} dropped={} forced={} \
         overflow={} flushed={} drift_ppm={:.0} unknown_pt={} decode_errors={} jitter_ms={:.1} target_ms={:.1} \
         delay_ms={:.1} rtt_ms={} their_loss={} bye={}",
        peer.id,
        peer.name.as_deref().unwrap_or(""),
        peer.addr,
        j.received,
        j.played,
        j.lost,
        j.late,
        j.duplicates,
        j.reordered,
        peer.receiver.concealed,
        peer.receiver.recovered,
        j.stretched,
        j.dropped,
        j.forced,
        j.overflow,
        j.flushed,
        j.drift_ppm,
        peer.receiver.unknown_payload,
        peer.receiver.decode_errors,
        j.jitter_ms,
        j.target_delay_ms,
        j.current_delay_ms,
        opt(peer.rtt_ms),
        opt(peer.their_loss),
        peer.said_bye
    );
}

/// `lipcall receive` from direct callers or a relay room (`--janus`, in
/// `commands::janus::ReceiveCommand`, receives a Janus room instead). `listen` is empty only
/// with `--janus`; `peer_timeout` and `clock_tolerance` are `None` only when built in code (the
/// session's defaults).
#[derive(Debug, Clone, clap::Args)]
pub struct ReceiveArgs {
    /// Address to listen on, HOST:PORT (port 0 picks one). Once bound, one stderr line
    /// says the address: `lipcall: listening on IP:PORT` (a stable format, for scripts).
    #[arg(
        long,
        value_name = "HOST:PORT",
        required_unless_present_any = ["janus", "mumble"],
        default_value = "",
        hide_default_value = true
    )]
    pub listen: String,
    /// Write the audio as played (all peers mixed), streamed to disk as it plays, at the
    /// rate of the streams first heard (48000 for Opus, 16000 for G.722, 8000 for G.711 and
    /// Speex narrowband) unless --rate says another.
    #[arg(long, value_name = "OUT.wav")]
    pub wav: Option<PathBuf>,
    /// OUT.wav's sample rate, Hz (every peer is resampled to it).
    #[arg(long, value_name = "HZ", value_parser = super::parse_frame_rate)]
    pub rate: Option<u32>,
    /// Write viseme weights from the built-in lip-sync network (one file per peer).
    #[arg(long, value_name = "WEIGHTS.csv")]
    pub weights: Option<PathBuf>,
    /// Write per-frame LSP + energy features aligned to OUT.wav (one file per peer).
    #[arg(long, value_name = "FEATURES.csv")]
    pub features: Option<PathBuf>,
    #[command(flatten)]
    pub key: KeyArgs,
    /// Stop this many seconds after the start, joining a relay room, a Janus room or a Mumble
    /// server included (a join not done by then fails). Without it, the receive ends once
    /// everyone who called has left: said BYE, or sent nothing for --peer-timeout. Before
    /// anyone calls it waits. Ctrl-C (SIGINT) or SIGTERM ends it at any time; the files
    /// written so far are finished and whole either way.
    #[arg(long, allow_hyphen_values = true, value_parser = super::parse_seconds)]
    pub seconds: Option<f64>,
    /// A peer that sent nothing (no RTP, no RTCP) for this many seconds has left (in a
    /// Janus room, Janus says when a publisher leaves).
    #[arg(long, value_name = "SECONDS", default_value = "30", value_parser = super::parse_peer_timeout)]
    pub peer_timeout: Option<f64>,
    /// With --key: how far (either way) a caller's clock may be from ours. A new encrypted
    /// stream stamped further off is refused as a replay of an earlier call (counted as
    /// stale).
    #[arg(long, value_name = "SECONDS", default_value = CLOCK_TOLERANCE_TEXT,
          value_parser = clap::value_parser!(u32).range(1..=86_400))]
    pub clock_tolerance: Option<u32>,
    /// Join a room on this relay (with --room).
    #[arg(long, value_name = "HOST:PORT")]
    pub relay: Option<String>,
    #[arg(long)]
    pub room: Option<String>,
    /// Display name sent to peers.
    #[arg(long)]
    pub name: Option<String>,
    /// Carry a codec on another RTP payload type, e.g. opus=111 (repeatable). Without SDP the
    /// defaults are GStreamer's: speex=110, opus=96; pcmu=0 and pcma=8 are static.
    #[arg(long = "pt", value_name = "CODEC=PT", value_parser = parse_payload_type)]
    pub payload_types: Vec<String>,
}

pub fn receive(args: &ReceiveArgs) -> Result<()> {
    receive_with(args, &mut |_, _, _| {})
}

/// The whole receive side; `on_frame(ssrc, time_s, features)` sees every played frame's
/// features as it is played (where the lip-sync network plugs in).
pub fn receive_with(
    args: &ReceiveArgs,
    on_frame: &mut dyn FnMut(u32, f64, &FrameFeatures),
) -> Result<()> {
    if args.room.is_some() != args.relay.is_some() {
        bail!("--relay and --room go together");
    }
    let listen = resolve(&args.listen)?;
    let key = args.key.master_key(args.room.as_deref())?;
    let mut config = SessionConfig::new(listen);
    if let Some(relay) = &args.relay {
        config.destinations = vec![resolve(relay)?];
        config.room = args.room.clone();
    }
    config.key = key;
    config.name = args.name.clone();
    config.payloads = payload_map(&args.payload_types)?;
    warn_unmapped(&config.payloads);
    if let Some(timeout) = args.peer_timeout {
        config.peer_timeout = Duration::from_secs_f64(timeout);
    }
    if let Some(seconds) = args.clock_tolerance {
        config.clock_tolerance = Duration::from_secs(u64::from(seconds));
    }
    let stop = stop_flag()?;
    let (model, mut recorder) = open_outputs(
        args.wav.as_deref(),
        args.rate,
        args.features.as_deref(),
        args.weights.as_deref(),
    )?;
    announce_security(&config.key);
    let until = deadline(args.seconds);
    let mut session = Session::start(config)?;
    eprintln!("lipcall: listening on {}", session.local_addr()?);
    if args.room.is_some() {
        wait_for_relay(&session, &stop, until)?;
    }
    let played = play(
        &mut session,
        DIRECT,
        until,
        model.as_ref(),
        on_frame,
        &mut recorder,
        &stop,
    );
    session.leave();

    let stats = session.stats();
    eprintln!(
        "lipcall: played {:.2} s; datagrams={} rtp={} rtcp={} malformed={} unknown={} \
         unknown_pt={} auth_failed={} replayed={} stale={} too_many_peers={}",
        recorder.seconds(),
        stats.datagrams,
        stats.rtp,
        stats.rtcp,
        stats.malformed,
        stats.unknown,
        stats.unknown_payload,
        stats.auth_failed,
        stats.replayed,
        stats.stale,
        stats.too_many_peers
    );
    for peer in session.peers() {
        print_peer(&peer);
    }
    let finished = recorder.finish();
    played.and(finished)
}

/// `--clock-tolerance`'s default as clap shows it: [`crate::net::srtp::DEFAULT_CLOCK_TOLERANCE`]
/// (a test ties the two).
const CLOCK_TOLERANCE_TEXT: &str = "30";

pub(crate) fn parse_codec(s: &str) -> Result<Codec, String> {
    s.parse()
        .map_err(|e: crate::codec::any::PayloadMapError| e.to_string())
}

/// A `--pt CODEC=PT` flag, checked as the payload-type map will take it.
fn parse_payload_type(s: &str) -> Result<String, String> {
    PayloadMap::default()
        .with_assignments(&[s])
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

fn parse_hex_u32(s: &str) -> Result<u32, String> {
    u32::from_str_radix(s.trim_start_matches("0x"), 16).map_err(|e| e.to_string())
}

#[cfg(test)]
mod argument_tests {
    #[test]
    fn the_shown_clock_tolerance_is_the_sessions_default() {
        assert_eq!(
            super::CLOCK_TOLERANCE_TEXT.parse::<u32>(),
            Ok(crate::net::srtp::DEFAULT_CLOCK_TOLERANCE)
        );
    }
}

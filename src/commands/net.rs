//! `lipcall send`, `lipcall receive` and `lipcall relay`: the headless real-time transport.

use std::io::Write;
use std::net::{SocketAddr, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::audio::wav;
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD, PayloadMap};
use crate::codec::speex::features::FrameFeatures;
use crate::codec::speex::split::split_frames;
use crate::codec::{FRAME_SIZE, SAMPLE_RATE, opus, speex};
use crate::lipsync::network::Model;
use crate::lipsync::{self, LipSync, LipSyncOptions};
use crate::net::relay::{Relay, RelayConfig};
use crate::net::session::{PeerFrame, PeerInfo, Session, SessionConfig};
use crate::net::srtp::MasterKey;

const TICK: Duration = Duration::from_millis(20);

/// How the call is keyed.
#[derive(Debug, Clone, Default)]
pub struct KeyArgs {
    /// Room passphrase (PBKDF2 over passphrase and room name).
    pub passphrase: Option<String>,
    /// A raw 30-byte SRTP master key + salt in hex, for interop with other SRTP stacks.
    pub hex: Option<String>,
}

impl KeyArgs {
    fn master_key(&self, room: Option<&str>) -> Result<Option<MasterKey>> {
        match (&self.passphrase, &self.hex) {
            (Some(_), Some(_)) => bail!("give either --key or --key-hex, not both"),
            (Some(p), None) => Ok(Some(MasterKey::from_passphrase(p, room.unwrap_or("")))),
            (None, Some(h)) => Ok(Some(MasterKey::from_hex(h).context("--key-hex")?)),
            (None, None) => Ok(None),
        }
    }
}

fn resolve(addr: &str) -> Result<SocketAddr> {
    addr.to_socket_addrs()
        .with_context(|| format!("cannot resolve {addr}"))?
        .next()
        .with_context(|| format!("{addr} resolves to no address"))
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
        eprintln!("lipcall: warning: the call is NOT encrypted (plain RTP); use --key to encrypt");
    }
}

/// Payloads to send, each with its duration in ticks of the codec's RTP clock.
type Packets = Vec<(Vec<u8>, u32)>;

/// Encodes 8 kHz audio in 20 ms frames (the last padded with silence).
fn encode_pcm(pcm: &[i16], codec: Codec, settings: &EncoderSettings) -> Result<Packets> {
    let mut encoder = FrameEncoder::new(codec, settings)?;
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let mut out = Vec::with_capacity(pcm.len() / FRAME_SIZE + 1);
    for chunk in pcm.chunks(FRAME_SIZE) {
        let mut frame = [0i16; FRAME_SIZE];
        frame[..chunk.len()].copy_from_slice(chunk);
        if let Some((n, frames)) = encoder.encode(&frame, &mut payload)? {
            out.push((payload[..n].to_vec(), frames * codec.frame_ticks()));
        }
    }
    Ok(out)
}

/// What `send` sends: a coded file as it is (Ogg Speex, Ogg Opus), or audio encoded here (a
/// WAV, or a coded file when `--codec` asks for another codec). Without `--codec`, a WAV goes
/// as Speex, the reference path.
pub(crate) fn load_packets(
    input: &Path,
    codec: Option<Codec>,
    settings: &EncoderSettings,
) -> Result<(Codec, Packets)> {
    let ext = input
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let read = || crate::input::read(input, crate::input::MAX_INPUT_BYTES);
    let what = || input.display().to_string();
    match ext.as_deref() {
        Some("spx" | "ogg" | "opus") => {
            let bytes = read()?;
            if opus::ogg_file::holds_opus(&bytes) || ext.as_deref() == Some("opus") {
                let decoded = opus::stream::decode(&bytes).with_context(what)?;
                if codec.is_some_and(|c| c != Codec::Opus) {
                    let codec = codec.unwrap_or(Codec::Opus);
                    return Ok((codec, encode_pcm(&decoded.pcm, codec, settings)?));
                }
                // Timestamps count 48 kHz ticks; the packets were decoded at 8 kHz.
                let per_sample = Codec::Opus.clock_rate() / SAMPLE_RATE;
                let packets = decoded
                    .packets
                    .into_iter()
                    .map(|p| (p.data, p.samples as u32 * per_sample))
                    .collect();
                return Ok((Codec::Opus, packets));
            }
            if codec.is_some_and(|c| c != Codec::Speex) {
                let codec = codec.unwrap_or(Codec::Speex);
                let decoded = speex::stream::decode(&bytes, true).with_context(what)?;
                return Ok((codec, encode_pcm(&decoded.pcm, codec, settings)?));
            }
            let file = speex::ogg_file::read(&bytes).with_context(what)?;
            let per_packet = file.header.frames_per_packet.max(1) as u32;
            let step = Codec::Speex.frame_ticks();
            let mut out = Vec::new();
            for packet in file.pages.iter().flat_map(|p| &p.packets) {
                match split_frames(packet) {
                    Some(frames) => out.extend(frames.into_iter().map(|f| (f, step))),
                    None => out.push((packet.clone(), per_packet * step)),
                }
            }
            Ok((Codec::Speex, out))
        }
        Some("wav") => {
            let pcm = wav::read_narrowband(input)?;
            let codec = codec.unwrap_or(Codec::Speex);
            Ok((codec, encode_pcm(&pcm, codec, settings)?))
        }
        _ => bail!("{}: expected a .wav, .spx or .opus file", input.display()),
    }
}

/// The payload-type map from `--pt CODEC=PT` flags.
fn payload_map(assignments: &[String]) -> Result<PayloadMap> {
    PayloadMap::default()
        .with_assignments(assignments)
        .context("--pt")
}

#[derive(Debug, Clone)]
pub struct SendArgs {
    pub input: PathBuf,
    pub to: String,
    pub key: KeyArgs,
    pub name: Option<String>,
    pub room: Option<String>,
    pub quality: u8,
    pub no_rtcp: bool,
    pub ssrc: Option<u32>,
    /// The codec to send; `None`: a coded file's own, Speex for a WAV.
    pub codec: Option<Codec>,
    /// `CODEC=PT` assignments moving dynamic payload types (`opus=111`).
    pub payload_types: Vec<String>,
}

pub fn send(args: &SendArgs) -> Result<()> {
    let payloads = payload_map(&args.payload_types)?;
    let mut settings = EncoderSettings::default();
    settings.speex.quality = args.quality;
    let (codec, packets) = load_packets(&args.input, args.codec, &settings)?;
    if packets.is_empty() {
        bail!("{}: no audio to send", args.input.display());
    }
    if payloads.payload_type(codec).is_none() {
        bail!("no RTP payload type is mapped to {codec} (--pt took it)");
    }
    let to = resolve(&args.to)?;
    let key = args.key.master_key(args.room.as_deref())?;
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
    let session = Session::start(config)?;
    if args.room.is_some() {
        wait_for_relay(&session)?;
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
    let mut at = 0u64;
    for (payload, duration) in &packets {
        let due = start + Duration::from_secs_f64(at as f64 / clock);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        session.send_packet(payload, *duration)?;
        at += u64::from(*duration);
    }
    // Let the last packet's slot pass before saying BYE.
    std::thread::sleep(TICK);
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

fn wait_for_relay(session: &Session) -> Result<()> {
    let deadline = Instant::now() + Duration::from_secs(3);
    while Instant::now() < deadline {
        let stats = session.stats();
        if stats.relay_refused {
            bail!("the relay refused to join the room (full, or too many rooms)");
        }
        if stats.relay_joined {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    bail!("the relay did not answer the join within 3 s")
}

pub(crate) fn print_peer(peer: &PeerInfo) {
    let j = &peer.receiver.jitter;
    let opt = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
    let codec = peer.receiver.codec.map_or("-", Codec::name);
    eprintln!(
        "peer ssrc={:08x} name={:?} addr={} codec={codec} received={} played={} lost={} late={} \
         duplicates={} reordered={} concealed={} recovered={} stretched={} dropped={} \
         unknown_pt={} decode_errors={} jitter_ms={:.1} target_ms={:.1} delay_ms={:.1} rtt_ms={} \
         their_loss={} bye={}",
        peer.ssrc,
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

#[derive(Debug, Clone)]
pub struct ReceiveArgs {
    pub listen: String,
    pub wav: Option<PathBuf>,
    pub weights: Option<PathBuf>,
    pub features: Option<PathBuf>,
    pub key: KeyArgs,
    pub seconds: Option<f64>,
    pub relay: Option<String>,
    pub room: Option<String>,
    pub name: Option<String>,
    /// `CODEC=PT` assignments moving dynamic payload types (`opus=111`).
    pub payload_types: Vec<String>,
}

/// One feature row of one peer, on the output timeline.
struct Row {
    frame: usize,
    features: FrameFeatures,
    /// Viseme weights from the peer's network, when `--weights` asked for them.
    weights: Vec<f32>,
}

/// What the receiver keeps per remote speaker: its rows and, with `--weights`, its lip sync.
struct PeerTrack<'m> {
    ssrc: u32,
    rows: Vec<Row>,
    lipsync: Option<LipSync<'m>>,
}

impl PeerTrack<'_> {
    /// Weights the lip sync gave out (frame `tag` of this track) go into their row.
    fn store(rows: &mut [Row], out: Option<(u64, &[f32])>) {
        if let Some((tag, w)) = out
            && let Some(row) = rows.get_mut(tag as usize)
        {
            row.weights.clear();
            row.weights.extend_from_slice(w);
        }
    }

    /// The frames still waiting for their look-ahead, given out now (the peer's next frame
    /// did not come in time, or the call ended).
    fn flush(&mut self, all: bool) {
        if let Some(lipsync) = &mut self.lipsync {
            while let Some(out) = lipsync.flush() {
                Self::store(&mut self.rows, Some(out));
                if !all {
                    break;
                }
            }
        }
    }
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
    let model = args.weights.as_ref().map(|_| lipsync::default_model());
    if args.room.is_some() != args.relay.is_some() {
        bail!("--relay and --room go together");
    }
    let listen = resolve(&args.listen)?;
    let key = args.key.master_key(args.room.as_deref())?;
    announce_security(&key);
    let mut config = SessionConfig::new(listen);
    if let Some(relay) = &args.relay {
        config.destinations = vec![resolve(relay)?];
        config.room = args.room.clone();
    }
    config.key = key;
    config.name = args.name.clone();
    config.payloads = payload_map(&args.payload_types)?;
    let session = Session::start(config)?;
    eprintln!("lipcall: listening on {}", session.local_addr()?);
    if args.room.is_some() {
        wait_for_relay(&session)?;
    }
    let played = play(&mut &session, args.seconds, model.as_ref(), on_frame)?;
    session.leave();

    let stats = session.stats();
    eprintln!(
        "lipcall: played {:.2} s; datagrams={} rtp={} rtcp={} malformed={} unknown={} \
         unknown_pt={} auth_failed={} replayed={} too_many_peers={}",
        played.pcm.len() as f64 / f64::from(SAMPLE_RATE),
        stats.datagrams,
        stats.rtp,
        stats.rtcp,
        stats.malformed,
        stats.unknown,
        stats.unknown_payload,
        stats.auth_failed,
        stats.replayed,
        stats.too_many_peers
    );
    for peer in session.peers() {
        print_peer(&peer);
    }
    write_outputs(
        &played,
        args.wav.as_deref(),
        args.features.as_deref(),
        args.weights.as_deref(),
        model.as_ref(),
    )
}

/// Where a receiver's played frames come from: a [`Session`], or a Janus room.
pub(crate) trait FrameSource {
    /// The next 20 ms (starting at `now` on the output clock) of every peer that is playing.
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) -> Result<()>;
    /// Every peer that came has left (the receive ends there without `--seconds`).
    fn all_left(&mut self) -> bool;
}

impl FrameSource for &Session {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) -> Result<()> {
        Session::pull(self, now, out);
        Ok(())
    }

    fn all_left(&mut self) -> bool {
        let peers = self.peers();
        !peers.is_empty() && peers.iter().all(|p| p.said_bye)
    }
}

/// What a receive played: the mix and each peer's rows.
pub(crate) struct Played<'m> {
    pub pcm: Vec<i16>,
    tracks: Vec<PeerTrack<'m>>,
}

/// The receive loop: pulls every 20 ms, mixes, and runs each peer's lip sync when a model is
/// given.
pub(crate) fn play<'m>(
    source: &mut dyn FrameSource,
    seconds: Option<f64>,
    model: Option<&'m Model>,
    on_frame: &mut dyn FnMut(u32, f64, &FrameFeatures),
) -> Result<Played<'m>> {
    let limit = seconds.map(Duration::from_secs_f64);
    let start = Instant::now();
    let mut pcm: Vec<i16> = Vec::new();
    let mut tracks: Vec<PeerTrack> = Vec::new();
    let mut frames: Vec<PeerFrame> = Vec::new();
    // Output ticks since the first audible one, and the last tick that had audio.
    let mut timeline: Option<usize> = None;
    let mut last_audible = 0usize;
    let mut tick = 0u32;
    loop {
        let due = start + TICK * tick;
        tick += 1;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        if limit.is_some_and(|l| due.duration_since(start) >= l) {
            break;
        }
        frames.clear();
        source.pull(due, &mut frames)?;
        if frames.is_empty() && timeline.is_some() && limit.is_none() && source.all_left() {
            break;
        }
        if frames.is_empty() && timeline.is_none() {
            continue;
        }
        let row = timeline.get_or_insert(0);
        let index = *row;
        *row += 1;
        let mut mix = [0i32; FRAME_SIZE];
        for f in &frames {
            for (m, &s) in mix.iter_mut().zip(&f.frame.pcm) {
                *m += i32::from(s);
            }
            let time = index as f64 * TICK.as_secs_f64();
            on_frame(f.ssrc, time, &f.frame.features);
            let slot = match tracks.iter().position(|t| t.ssrc == f.ssrc) {
                Some(i) => i,
                None => {
                    let lipsync = match model {
                        Some(model) => Some(LipSync::new(model, &LipSyncOptions::default())?),
                        None => None,
                    };
                    tracks.push(PeerTrack {
                        ssrc: f.ssrc,
                        rows: Vec::new(),
                        lipsync,
                    });
                    tracks.len() - 1
                }
            };
            let track = &mut tracks[slot];
            let tag = track.rows.len() as u64;
            track.rows.push(Row {
                frame: index,
                features: f.frame.features,
                weights: Vec::new(),
            });
            if let Some(lipsync) = &mut track.lipsync {
                PeerTrack::store(&mut track.rows, lipsync.push(tag, &f.frame.features));
            }
        }
        for track in &mut tracks {
            if !frames.iter().any(|f| f.ssrc == track.ssrc) {
                track.flush(false);
            }
        }
        if !frames.is_empty() {
            last_audible = index + 1;
        }
        pcm.extend(mix.iter().map(|&m| m.clamp(-32768, 32767) as i16));
    }
    pcm.truncate(last_audible * FRAME_SIZE);
    for track in &mut tracks {
        track.flush(true);
    }
    Ok(Played { pcm, tracks })
}

/// OUT.wav, FEATURES.csv and WEIGHTS.csv of a receive (one CSV per peer).
pub(crate) fn write_outputs(
    played: &Played,
    wav_path: Option<&Path>,
    features: Option<&Path>,
    weights: Option<&Path>,
    model: Option<&Model>,
) -> Result<()> {
    let Played { pcm, tracks } = played;
    if let Some(path) = wav_path {
        wav::write_mono_i16(path, SAMPLE_RATE, pcm)?;
    }
    if let Some(path) = features {
        for (i, track) in tracks.iter().enumerate() {
            let target = if i == 0 {
                path.to_path_buf()
            } else {
                peer_path(path, track.ssrc)
            };
            write_rows(&target, &track.rows)?;
        }
        if tracks.is_empty() {
            write_rows(path, &[])?;
        }
    }
    if let (Some(path), Some(model)) = (weights, model) {
        let names: Vec<&str> = tracks
            .first()
            .and_then(|t| t.lipsync.as_ref())
            .map(|l| l.visemes().members().iter().map(|v| v.name()).collect())
            .unwrap_or_else(|| model.viseme_names());
        for (i, track) in tracks.iter().enumerate() {
            let target = if i == 0 {
                path.to_path_buf()
            } else {
                peer_path(path, track.ssrc)
            };
            write_weight_rows(&target, &names, &track.rows)?;
        }
        if tracks.is_empty() {
            write_weight_rows(path, &names, &[])?;
        }
    }
    Ok(())
}

/// FEATURES.csv of a second or later peer: `NAME-<ssrc>.csv` beside the first.
fn peer_path(path: &Path, ssrc: u32) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!("{stem}-{ssrc:08x}.csv"))
}

/// FEATURES.csv rows on the output timeline: `frame` counts 20 ms ticks of OUT.wav.
fn write_rows(path: &Path, rows: &[Row]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let lsp_names: Vec<String> = (1..=10).map(|i| format!("lsp{i}")).collect();
    writeln!(out, "frame,time_s,mode,{},energy_db", lsp_names.join(","))?;
    for row in rows {
        let time = row.frame as f64 * TICK.as_secs_f64();
        let mode = row.features.mode.map(|m| m.to_string()).unwrap_or_default();
        write!(out, "{},{time:.3},{mode}", row.frame)?;
        for l in row.features.lsp {
            write!(out, ",{l:.6}")?;
        }
        writeln!(out, ",{:.2}", row.features.energy_db)?;
    }
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

/// WEIGHTS.csv rows on the output timeline, like FEATURES.csv.
fn write_weight_rows(path: &Path, names: &[&str], rows: &[Row]) -> Result<()> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    writeln!(out, "frame,time_s,{}", names.join(","))?;
    for row in rows {
        write!(
            out,
            "{},{:.3}",
            row.frame,
            row.frame as f64 * TICK.as_secs_f64()
        )?;
        for w in &row.weights {
            write!(out, ",{w:.4}")?;
        }
        writeln!(out)?;
    }
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

pub fn relay(listen: &str, seconds: Option<f64>) -> Result<()> {
    let relay = Relay::start(resolve(listen)?, RelayConfig::default())?;
    eprintln!("lipcall: relay listening on {}", relay.local_addr());
    let start = Instant::now();
    let mut next_report = start + Duration::from_secs(10);
    loop {
        std::thread::sleep(Duration::from_millis(100));
        if seconds.is_some_and(|s| start.elapsed().as_secs_f64() >= s) {
            break;
        }
        if Instant::now() >= next_report {
            print_relay(&relay);
            next_report += Duration::from_secs(10);
        }
    }
    print_relay(&relay);
    Ok(())
}

fn print_relay(relay: &Relay) {
    let s = relay.stats();
    eprintln!(
        "relay rooms={} members={} datagrams={} forwarded={} copies={} joins={} refused={} \
         expired={} unknown_source={} malformed={} rate_limited={}",
        s.rooms,
        s.members,
        s.datagrams,
        s.forwarded,
        s.copies,
        s.joins,
        s.refused,
        s.expired,
        s.unknown_source,
        s.malformed,
        s.rate_limited
    );
}

//! `lipcall send --janus` and `lipcall receive --janus`: the headless transport through a
//! Janus VideoRoom instead of lipcall's own relay. Audio goes as Opus (what WebRTC speaks);
//! received audio takes the same path as a direct call's (jitter buffer, decoder, features,
//! lip sync) and the same outputs.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use zeroize::Zeroizing;

use super::net::{
    KeyArgs, Paced, Pacing, ReceiveArgs, SendArgs, deadline, load_packets, print_peer, send_paced,
};
use super::playout::{JANUS, ReceiveOutputs, play, print_event};
use super::recording::stop_flag;
use crate::call::janus::JanusLink;
use crate::call::link::JoinWait;
use crate::codec::any::{Codec, EncoderSettings};
use crate::net::janus::JanusError;
use crate::net::janus::candidates::{IceServers, TurnServer};
use crate::net::janus::messages::JanusAuth;
use crate::net::janus::room::{Member, Notice, RoomConfig, server_addr};
use crate::net::jitter::JitterConfig;
use crate::secrets::SecretSource;
use crate::vocab::FrameFeatures;

#[derive(Debug, Clone)]
pub struct JanusArgs {
    /// Janus's API, `http(s)://host:8088/janus`.
    pub url: String,
    pub auth: JanusAuth,
    pub room: String,
    pub name: Option<String>,
    /// The room's pin.
    pub pin: Option<String>,
    /// STUN and TURN servers for the media's ICE.
    pub ice: IceServers,
}

impl JanusArgs {
    fn config(&self, subscribe: bool, default_name: &str) -> RoomConfig {
        RoomConfig {
            url: self.url.clone(),
            auth: self.auth.clone(),
            room: self.room.clone(),
            name: self
                .name
                .clone()
                .unwrap_or_else(|| default_name.to_string()),
            pin: self.pin.clone(),
            subscribe,
            jitter: JitterConfig::default(),
            ice: self.ice.clone(),
        }
    }
}

fn announce_security() {
    eprintln!(
        "lipcall: media encrypted hop by hop (WebRTC DTLS-SRTP): the Janus server can hear it"
    );
}

fn print_notices(notices: &[Notice]) {
    for n in notices {
        print_event(&n.clone().into(), JANUS);
    }
}

/// Janus's refusal of a room's pin, with what to do about it.
fn pin_hint(e: JanusError) -> anyhow::Error {
    match &e {
        JanusError::Plugin { code, reason } if *code == 433 || reason.contains("pin") => {
            anyhow::Error::new(e)
                .context("the room has a pin: set LIPCALL_KEY or give --key-file FILE")
        }
        _ => e.into(),
    }
}

fn no_answer_in_time(seconds: Option<f64>) -> anyhow::Error {
    let seconds = seconds.unwrap_or_default();
    anyhow!("no answer from Janus in time: not in the room after the {seconds} s of --seconds")
}

/// Publishes a file's audio in the room, paced in real time, until `seconds` after the start,
/// the join included.
pub fn send(
    input: &std::path::Path,
    janus: &JanusArgs,
    seconds: Option<f64>,
    frame_ms: u8,
) -> Result<()> {
    let mut settings = EncoderSettings::wideband(crate::codec::opus::codec::Bandwidth::Fullband);
    settings.opus.frame_ms = frame_ms;
    let (codec, packets) = load_packets(input, Some(Codec::Opus), &settings)?;
    if packets.is_empty() {
        bail!("{}: no audio to send", input.display());
    }
    let until = deadline(seconds);
    let stop = stop_flag()?;
    let joining = || format!("publishing in room {:?} on {}", janus.room, janus.url);
    let mut link = JanusLink::start(janus.config(false, "lipcall"), true)
        .map_err(anyhow::Error::new)
        .with_context(joining)?;
    let notices = match link.wait_joined(&stop, until) {
        JoinWait::Joined(notices) => notices,
        JoinWait::Failed(e) => return Err(pin_hint(e)).with_context(joining),
        JoinWait::Stopped => {
            eprintln!("lipcall: stopped by a signal before the room was joined");
            return Ok(());
        }
        JoinWait::TimedOut => return Err(no_answer_in_time(seconds)).with_context(joining),
    };
    let mut room = link
        .into_member()
        .ok_or_else(|| anyhow!("joined, yet not in the room"))?;
    announce_security();
    print_notices(&notices);
    let pacing = Pacing::new(until)?;
    let clock = f64::from(codec.clock_rate());
    let ticks: u64 = packets.iter().map(|(_, t)| u64::from(*t)).sum();
    eprintln!(
        "lipcall: sending {:.2} s ({} packets of {codec}) to room {:?} as {}",
        ticks as f64 / clock,
        packets.len(),
        janus.room,
        room.id().unwrap_or_else(|| "-".into())
    );
    let start = Instant::now();
    let paced = send_paced(&packets, codec, &pacing, |payload, duration| {
        room.send(payload, duration)?;
        // Janus's events are read while sending; a restarted Janus is rejoined.
        print_notices(&room.poll());
        Ok(())
    })?;
    paced.announce();
    if paced == Paced::Whole {
        // The last packets leave str0m's pacer, then Janus forwards them before we hang up.
        std::thread::sleep(Duration::from_millis(200));
    }
    let stats = room.media_stats();
    eprintln!(
        "lipcall: sent {} packets in {:.2} s; datagrams_sent={} send_errors={}",
        stats.published,
        start.elapsed().as_secs_f64(),
        stats.sent,
        stats.send_errors
    );
    room.leave()?;
    Ok(())
}

/// `lipcall send`'s flags: a direct or relayed call, or with `--janus` a Janus room (`--room`
/// and the room passphrase then name the room and its pin).
#[derive(Debug, Clone, clap::Args)]
pub struct SendCommand {
    #[command(flatten)]
    pub call: SendArgs,
    /// Publish in a room (--room) of this Janus server instead, http://HOST:PORT/janus;
    /// the room passphrase is its pin. Sent as Opus over WebRTC.
    // Listed right after --to (display order 1 sorts before the others by name).
    #[arg(long, value_name = "URL", conflicts_with_all = ["to", "key_hex", "codec", "ssrc"],
          requires = "room", display_order = 1)]
    pub janus: Option<String>,
    #[command(flatten)]
    pub server: JanusServerArgs,
    #[command(flatten)]
    pub mumble: super::mumble::MumbleFlags,
}

/// What a Janus deployment may ask of us: the credentials of a restricted API, and a STUN
/// server for peers behind a NAT. Every secret comes from a file or the environment.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct JanusServerArgs {
    /// A file whose first line is the Janus server's api_secret (its janus.jcfg), sent with
    /// every request (otherwise the variable LIPCALL_JANUS_SECRET).
    #[arg(long, value_name = "FILE", requires = "janus")]
    pub janus_secret_file: Option<PathBuf>,
    /// A file whose first line is a token the Janus admin stored for us (token_auth), sent
    /// with every request (otherwise the variable LIPCALL_JANUS_TOKEN).
    #[arg(long, value_name = "FILE", requires = "janus")]
    pub janus_token_file: Option<PathBuf>,
    /// A STUN server, HOST:PORT, asked for our public address, which WebRTC then offers
    /// beside the local ones (behind a NAT; see docs/janus.md).
    #[arg(long, value_name = "HOST:PORT", requires = "janus")]
    pub stun: Option<String>,
    /// A TURN server, HOST:PORT, whose relay WebRTC offers too (symmetric NATs, UDP let out
    /// only to the relay); with --turn-user, and the password in LIPCALL_TURN_PASSWORD or
    /// --turn-password-file.
    #[arg(long, value_name = "HOST:PORT", requires_all = ["janus", "turn_user"])]
    pub turn: Option<String>,
    #[arg(long, value_name = "USER", requires = "turn")]
    pub turn_user: Option<String>,
    /// A file whose first line is the TURN password (otherwise the variable
    /// LIPCALL_TURN_PASSWORD).
    #[arg(long, value_name = "FILE", requires = "turn")]
    pub turn_password_file: Option<PathBuf>,
    /// Send and receive through the TURN relay only: Janus never learns this machine's own
    /// addresses.
    #[arg(long, requires = "turn")]
    pub turn_only: bool,
}

/// Where a Janus's api_secret is read from.
pub const JANUS_SECRET: SecretSource = SecretSource {
    flag: "--janus-secret-file",
    variable: "LIPCALL_JANUS_SECRET",
};

/// Where a Janus token is read from.
pub const JANUS_TOKEN: SecretSource = SecretSource {
    flag: "--janus-token-file",
    variable: "LIPCALL_JANUS_TOKEN",
};

/// Where the TURN server's password is read from.
pub const TURN_PASSWORD: SecretSource = SecretSource {
    flag: "--turn-password-file",
    variable: "LIPCALL_TURN_PASSWORD",
};

impl JanusServerArgs {
    /// The Janus room of `url` that `call`'s flags name.
    fn room_args(
        &self,
        url: &str,
        room: Option<&String>,
        name: Option<&String>,
        key: &KeyArgs,
    ) -> Result<JanusArgs> {
        let given = |secret: Option<Zeroizing<String>>| secret.map(|s| s.as_str().to_owned());
        let turn = match &self.turn {
            Some(server) => {
                let Some(password) = TURN_PASSWORD.read(self.turn_password_file.as_deref())? else {
                    bail!(
                        "--turn {server} needs its password: {}",
                        TURN_PASSWORD.how_to_give()
                    );
                };
                Some(TurnServer {
                    server: server.clone(),
                    username: self.turn_user.clone().unwrap_or_default(),
                    password: password.as_str().to_owned(),
                })
            }
            None => None,
        };
        Ok(JanusArgs {
            url: url.to_string(),
            auth: JanusAuth {
                api_secret: given(JANUS_SECRET.read(self.janus_secret_file.as_deref())?),
                token: given(JANUS_TOKEN.read(self.janus_token_file.as_deref())?),
            },
            room: room.cloned().unwrap_or_default(),
            name: name.cloned(),
            pin: given(key.passphrase()?),
            ice: IceServers {
                stun: self.stun.clone(),
                turn,
                relay_only: self.turn_only,
            },
        })
    }
}

/// `lipcall receive`'s flags: direct callers or a relay room, or with `--janus` a Janus room.
#[derive(Debug, Clone, clap::Args)]
pub struct ReceiveCommand {
    #[command(flatten)]
    pub call: ReceiveArgs,
    /// Join a room (--room) of this Janus server instead, http://HOST:PORT/janus, and
    /// receive every publisher there; the room passphrase is its pin.
    // Listed right after --listen (display order 1 sorts before --wav's by name).
    #[arg(long, value_name = "URL", conflicts_with_all = ["listen", "relay", "key_hex"],
          requires = "room", display_order = 1)]
    pub janus: Option<String>,
    #[command(flatten)]
    pub server: JanusServerArgs,
    #[command(flatten)]
    pub mumble: super::mumble::MumbleFlags,
}

#[derive(Debug, Clone)]
pub struct JanusReceiveArgs {
    pub janus: JanusArgs,
    pub out: ReceiveOutputs,
}

pub fn receive(args: &JanusReceiveArgs) -> Result<()> {
    receive_with(args, &mut |_, _, _| {})
}

pub fn receive_with(
    args: &JanusReceiveArgs,
    on_frame: &mut dyn FnMut(u32, f64, &FrameFeatures),
) -> Result<()> {
    let stop = stop_flag()?;
    let (model, mut recorder) = args.out.open()?;
    let server = server_addr(&args.janus.url)?;
    let joining = || format!("joining room {:?} on {}", args.janus.room, args.janus.url);
    // The join counts in the receive's --seconds.
    let seconds = args.out.seconds;
    let until = deadline(seconds);
    let mut link = JanusLink::start(args.janus.config(true, "lipcall-receiver"), false)
        .map_err(anyhow::Error::new)
        .with_context(joining)?;
    let notices = match link.wait_joined(&stop, until) {
        JoinWait::Joined(notices) => notices,
        JoinWait::Failed(e) => return Err(pin_hint(e)).with_context(joining),
        JoinWait::Stopped => {
            eprintln!("lipcall: stopped by a signal before the room was joined");
            return recorder.finish();
        }
        JoinWait::TimedOut => return Err(no_answer_in_time(seconds)).with_context(joining),
    };
    announce_security();
    eprintln!(
        "lipcall: in room {:?} on {} as {}",
        args.janus.room,
        args.janus.url,
        link.member()
            .and_then(Member::id)
            .unwrap_or_else(|| "-".into())
    );
    print_notices(&notices);
    let played = play(
        &mut link,
        JANUS,
        until,
        model.as_ref(),
        on_frame,
        &mut recorder,
        &stop,
    );
    if let Some(room) = link.member() {
        let stats = room.media_stats();
        eprintln!(
            "lipcall: played {:.2} s; datagrams={} unmatched={} sent={}",
            recorder.seconds(),
            stats.datagrams,
            stats.unmatched,
            stats.sent
        );
        // The same line per peer as a direct `receive`, the feed's media coming from Janus.
        for feed in room.feeds() {
            match feed.peer_info(server) {
                Some(peer) => print_peer(&peer),
                None => eprintln!("peer feed={} name={:?} no media", feed.feed, feed.name),
            }
        }
    }
    if let Err(e) = link.hang_up() {
        eprintln!("lipcall: leaving the room: {e}");
    }
    let finished = recorder.finish();
    played.and(finished)
}

/// `lipcall send`: into the Janus room of `--janus`, or to `--to`.
pub fn send_command(command: &SendCommand) -> Result<()> {
    let call = &command.call;
    if let Some(mumble) =
        super::mumble::MumbleArgs::from_flags(&command.mumble, call.name.as_deref())?
    {
        if !call.to.is_empty() || call.room.is_some() || call.key.named() {
            bail!("--mumble joins a Mumble server: it does not go with --to, --room or a key file");
        }
        return super::mumble::send(&call.input, &mumble, call.seconds, call.frame_ms);
    }
    match &command.janus {
        Some(url) => send(
            &call.input,
            &command
                .server
                .room_args(url, call.room.as_ref(), call.name.as_ref(), &call.key)?,
            call.seconds,
            call.frame_ms,
        ),
        None => super::net::send(call),
    }
}

/// `lipcall receive`: from the Janus room of `--janus`, or on `--listen`.
pub fn receive_command(command: &ReceiveCommand) -> Result<()> {
    let call = &command.call;
    let out = ReceiveOutputs {
        wav: call.wav.clone(),
        rate: call.rate,
        weights: call.weights.clone(),
        features: call.features.clone(),
        seconds: call.seconds,
    };
    if let Some(mumble) =
        super::mumble::MumbleArgs::from_flags(&command.mumble, call.name.as_deref())?
    {
        let others = !call.listen.is_empty() || call.relay.is_some() || call.room.is_some();
        if others || call.key.named() {
            bail!(
                "--mumble joins a Mumble server: it does not go with --listen, --relay, --room or \
                 a key file"
            );
        }
        return super::mumble::receive(&super::mumble::MumbleReceiveArgs { mumble, out });
    }
    match &command.janus {
        Some(url) => receive(&JanusReceiveArgs {
            janus: command.server.room_args(
                url,
                call.room.as_ref(),
                call.name.as_ref(),
                &call.key,
            )?,
            out,
        }),
        None => super::net::receive(call),
    }
}

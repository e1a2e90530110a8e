//! `lipcall send --mumble` and `lipcall receive --mumble`: the headless client of a Mumble
//! server. Audio goes as Opus (what Mumble speaks); each speaker in the channel is a peer,
//! received through the same path as a direct call (jitter buffer, decoder, features, lip
//! sync) with the same outputs, one WAV and CSV per speaker.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};

use super::net::{Paced, Pacing, deadline, load_packets, print_peer, send_paced};
use super::playout::{MUMBLE, ReceiveOutputs, play};
use super::recording::{stop_flag, stopped};
use crate::call::link::{JoinWait, Link};
use crate::call::mumble::MumbleLink;
use crate::codec::any::{Codec, EncoderSettings};
use crate::net::jitter::JitterConfig;
use crate::net::mumble::client::{ClientConfig, ClientEvent};
use crate::net::mumble::connection::{ConnectConfig, Connection, Notice};
use crate::net::mumble::events::describe_unlisted;
use crate::net::mumble::identity::{self, Trust};
use crate::secrets::SecretSource;

/// How long a channel move may take to be confirmed or refused.
const MOVE_WAIT: Duration = Duration::from_secs(2);

/// The flags `send` and `receive` share for a Mumble server.
#[derive(Debug, Clone, clap::Args)]
pub struct MumbleFlags {
    /// Join this Mumble server instead, HOST[:PORT] (port 64738 by default), as --name.
    /// Its certificate is trusted on first use; ours is made once and kept (both in
    /// $XDG_CONFIG_HOME/lipcall/mumble/). Sent as Opus.
    // Listed right after --to/--listen (display order 1 sorts before the others by name).
    #[arg(
        long,
        value_name = "HOST[:PORT]",
        conflicts_with = "janus",
        requires = "name",
        display_order = 1
    )]
    pub mumble: Option<String>,
    /// With --mumble: the channel to join (the server's default channel otherwise).
    #[arg(long, requires = "mumble", display_order = 91)]
    pub channel: Option<String>,
    /// With --mumble: a file whose first line is the server's password (otherwise the
    /// variable LIPCALL_MUMBLE_PASSWORD, if set).
    #[arg(long, value_name = "FILE", requires = "mumble", display_order = 92)]
    pub password_file: Option<PathBuf>,
    /// With --mumble: voice through the TLS connection only, never UDP (for networks that
    /// block UDP; Mumble's own TCP tunnel).
    #[arg(long, requires = "mumble", display_order = 93)]
    pub tcp_only: bool,
}

/// Where a Mumble server's password is read from.
pub const MUMBLE_PASSWORD: SecretSource = SecretSource {
    flag: "--password-file",
    variable: "LIPCALL_MUMBLE_PASSWORD",
};

/// A Mumble join as the commands ask for it.
#[derive(Debug, Clone)]
pub struct MumbleArgs {
    pub server: String,
    pub name: String,
    pub channel: Option<String>,
    pub password: Option<String>,
    pub tcp_only: bool,
}

impl MumbleArgs {
    /// From the flags (`None` without --mumble); `name` is --name.
    pub fn from_flags(flags: &MumbleFlags, name: Option<&str>) -> Result<Option<Self>> {
        let Some(server) = flags.mumble.clone() else {
            return Ok(None);
        };
        let password = MUMBLE_PASSWORD.read(flags.password_file.as_deref())?;
        Ok(Some(Self {
            server,
            name: name.unwrap_or("lipcall").to_string(),
            channel: flags.channel.clone(),
            password: password.map(|p| p.as_str().to_owned()),
            tcp_only: flags.tcp_only,
        }))
    }
}

fn print_notice(notice: &Notice) {
    match notice {
        Notice::Client(ClientEvent::Synced {
            session, channel, ..
        }) => eprintln!("lipcall: joined as session {session} in channel {channel:?}"),
        Notice::Client(ClientEvent::UserJoined { session, name }) => {
            eprintln!("lipcall: {name:?} (session {session}) is in the channel")
        }
        Notice::Client(ClientEvent::UserLeft { session, name }) => {
            eprintln!("lipcall: {name:?} (session {session}) left")
        }
        Notice::Client(ClientEvent::Rejected(reason)) => {
            eprintln!("lipcall: the Mumble server refused us: {reason}")
        }
        Notice::Client(ClientEvent::Removed(reason)) => {
            eprintln!("lipcall: the Mumble server removed us: {reason}")
        }
        Notice::Client(ClientEvent::Denied(reason)) => {
            eprintln!("lipcall: the Mumble server refused: {reason}")
        }
        Notice::Client(ClientEvent::Text { from, message }) => {
            eprintln!("lipcall: {from} says: {message}")
        }
        Notice::Client(ClientEvent::UdpWorking(true)) => eprintln!("lipcall: voice goes by UDP"),
        Notice::Client(ClientEvent::UdpWorking(false)) => {
            eprintln!("lipcall: voice goes through the TLS tunnel")
        }
        Notice::Lost(reason) => {
            eprintln!("lipcall: lost the Mumble server ({reason}); reconnecting")
        }
        Notice::RejoinFailed { reason, retry } => eprintln!(
            "lipcall: cannot reconnect yet ({reason}); trying again in {} s, then less often",
            retry.as_secs()
        ),
        Notice::Client(ClientEvent::Unlisted {
            joined,
            left,
            messages,
        }) => eprintln!("lipcall: {}", describe_unlisted(*joined, *left, *messages)),
        Notice::Rejoined(session) => {
            eprintln!("lipcall: back on the Mumble server as session {session}")
        }
        Notice::Untrusted(reason) => eprintln!("lipcall: {reason}; not reconnecting"),
    }
}

/// Connects and joins (the channel asked for, if any) by `until` (`seconds` after the start);
/// says whose certificate we trust. None when a signal came first.
fn connect(
    args: &MumbleArgs,
    stop: &AtomicBool,
    seconds: Option<f64>,
    until: Option<Instant>,
) -> Result<Option<Connection>> {
    let dir = identity::default_dir()
        .context("no folder for the client certificate: set HOME or XDG_CONFIG_HOME")?;
    let config = ConnectConfig {
        address: args.server.clone(),
        client: ClientConfig {
            name: args.name.clone(),
            password: args.password.clone(),
            channel: args.channel.clone(),
            jitter: JitterConfig::default(),
            tcp_only: args.tcp_only,
        },
        identity_dir: dir,
    };
    let joining = || {
        format!(
            "joining the Mumble server {} as {:?}",
            args.server, args.name
        )
    };
    let mut link = MumbleLink::join(config, args.server.clone())
        .context("cannot start the join's thread")
        .with_context(joining)?;
    match link.wait_joined(stop, until) {
        JoinWait::Joined(()) => {}
        JoinWait::Failed(e) => return Err(e).with_context(joining),
        JoinWait::Stopped => {
            eprintln!("lipcall: stopped by a signal before the server was joined");
            return Ok(None);
        }
        JoinWait::TimedOut => return Err(no_answer_in_time(seconds)).with_context(joining),
    }
    let connection = link
        .into_connection()
        .ok_or_else(|| anyhow!("joined, yet not connected"))
        .with_context(joining)?;
    let (print, trust) = connection.fingerprint();
    match trust {
        Trust::New => eprintln!(
            "lipcall: first visit to {}: its certificate (SHA-256 {print}) is now trusted",
            connection.server()
        ),
        Trust::Known => eprintln!(
            "lipcall: {} shows the certificate trusted before (SHA-256 {print})",
            connection.server()
        ),
    }
    eprintln!(
        "lipcall: media encrypted hop by hop (TLS, OCB2-AES128): the Mumble server can hear it"
    );
    if let Some(channel) = &args.channel {
        let moved_by = Instant::now() + MOVE_WAIT;
        loop {
            for notice in connection.poll() {
                print_notice(&notice);
                if let Notice::Client(ClientEvent::Denied(reason)) = notice {
                    bail!("cannot join channel {channel:?}: {reason}");
                }
            }
            if connection.current_channel().as_deref() == Some(channel.as_str()) {
                break;
            }
            if stopped(stop) {
                eprintln!("lipcall: stopped by a signal before the channel was joined");
                return Ok(None);
            }
            let now = Instant::now();
            if until.is_some_and(|until| now >= until) {
                return Err(no_answer_in_time(seconds))
                    .with_context(|| format!("moving to channel {channel:?}"));
            }
            if now > moved_by {
                bail!("the Mumble server did not move us to channel {channel:?}");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    Ok(Some(connection))
}

fn no_answer_in_time(seconds: Option<f64>) -> anyhow::Error {
    let seconds = seconds.unwrap_or_default();
    anyhow!(
        "no answer from the Mumble server in time: not joined after the {seconds} s of --seconds"
    )
}

/// Sends a file's audio to the channel, paced in real time, until `seconds` after the start,
/// the join included.
pub fn send(input: &Path, args: &MumbleArgs, seconds: Option<f64>, frame_ms: u8) -> Result<()> {
    let mut settings = EncoderSettings::default();
    settings.opus.frame_ms = frame_ms;
    let (codec, packets) = load_packets(input, Some(Codec::Opus), &settings)?;
    if packets.is_empty() {
        bail!("{}: no audio to send", input.display());
    }
    let until = deadline(seconds);
    let stop = stop_flag()?;
    let Some(mut connection) = connect(args, &stop, seconds, until)? else {
        return Ok(());
    };
    let pacing = Pacing::new(until)?;
    let clock = f64::from(codec.clock_rate());
    let ticks: u64 = packets.iter().map(|(_, t)| u64::from(*t)).sum();
    eprintln!(
        "lipcall: sending {:.2} s ({} packets of {codec}) to {} as {:?}",
        ticks as f64 / clock,
        packets.len(),
        connection.server(),
        args.name
    );
    let start = Instant::now();
    let paced = send_paced(&packets, codec, &pacing, |payload, duration| {
        // While the server is away (a restart) the audio is dropped; the call goes on.
        if let Err(e) = connection.send_voice(payload, duration) {
            tracing::debug!("Mumble: {e}");
        }
        for notice in connection.poll() {
            print_notice(&notice);
            match notice {
                Notice::Client(ClientEvent::Removed(reason)) => {
                    bail!("the Mumble server removed us: {reason}")
                }
                Notice::Untrusted(reason) => bail!("{reason}; not reconnecting"),
                _ => {}
            }
        }
        Ok(())
    })?;
    paced.announce();
    if paced == Paced::Whole {
        // The last packets reach the server before we leave.
        std::thread::sleep(Duration::from_millis(300));
    }
    let stats = connection.stats();
    eprintln!(
        "lipcall: sent {:.2} s; udp_sent={} tunnel_sent={}",
        start.elapsed().as_secs_f64(),
        stats.udp_sent,
        stats.tunnel_sent
    );
    connection.close();
    Ok(())
}

#[derive(Debug, Clone)]
pub struct MumbleReceiveArgs {
    pub mumble: MumbleArgs,
    pub out: ReceiveOutputs,
}

/// Joins the channel and receives every speaker there until `--seconds`, a signal, or (without
/// `--seconds`) everyone who spoke has left.
pub fn receive(args: &MumbleReceiveArgs) -> Result<()> {
    let stop = stop_flag()?;
    let (model, mut recorder) = args.out.open()?;
    let until = deadline(args.out.seconds);
    let Some(connection) = connect(&args.mumble, &stop, args.out.seconds, until)? else {
        return recorder.finish();
    };
    for notice in connection.poll() {
        print_notice(&notice);
    }
    let place = format!(
        "channel {:?} of Mumble server {}",
        connection.current_channel().unwrap_or_default(),
        connection.server()
    );
    let mut link = MumbleLink::joined(connection, place);
    let played = play(
        &mut link,
        MUMBLE,
        until,
        model.as_ref(),
        &mut |_, _, _| {},
        &mut recorder,
        &stop,
    );
    if let Some(connection) = link.connection() {
        let stats = connection.stats();
        eprintln!(
            "lipcall: played {:.2} s; udp={} tunnel={} decrypt_failed={} malformed={} \
             other_codec={} resyncs={}",
            recorder.seconds(),
            stats.udp_received,
            stats.tunnel_received,
            stats.decrypt_failed,
            stats.malformed,
            stats.other_codec,
            stats.resyncs
        );
    }
    for peer in link.peers() {
        print_peer(&peer);
    }
    let unlisted = link.connection().map_or(0, Connection::speakers_unlisted);
    if unlisted > 0 {
        eprintln!("lipcall: and {unlisted} more speakers who left, not listed");
    }
    link.leave();
    let finished = recorder.finish();
    played.and(finished)?;
    match link.ended() {
        Some(reason) => bail!("{reason}"),
        None => Ok(()),
    }
}

//! `lipcall sip call` and `lipcall sip answer`: a phone call over SIP that plays a file as our
//! voice and does with the peer's what `receive` does (WAV as played, WEIGHTS.csv, summary).

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use super::net::{load_packets, parse_codec, print_peer};
use super::playout::{DIRECT, open_outputs, play, print_event};
use super::recording::{stop_flag, stopped};
use crate::call::link::{Link, LinkEvent};
use crate::call::media::Packets;
use crate::call::sip::{CallState, SipLink, SipSecurity};
use crate::codec::any::{Codec, EncoderSettings};
use crate::net::host_port::resolve_with_port;
use crate::net::janus::candidates::local_ip_towards;
use crate::net::rtcp::ReportBlock;
use crate::net::sip::address::{bind_towards, host_port, resolve_host};
use crate::net::sip::agent::{Account, Role, codecs};
use crate::net::sip::transport::SrtpPolicy;
use crate::secrets::{SecretSource, forbid_core_dumps};

/// How often the set-up phase looks at the stop flag and the deadline.
const SETUP_STEP: Duration = Duration::from_millis(50);

#[derive(Debug, Clone, clap::Args)]
pub struct SipCommand {
    #[command(subcommand)]
    pub action: SipAction,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub enum SipAction {
    /// Call a SIP address; ends when either side hangs up or after --seconds.
    Call(SipCallArgs),
    /// Wait for a call and answer the first; ends when either side hangs up or after --seconds.
    Answer(SipAnswerArgs),
}

/// What both directions share.
#[derive(Debug, Clone, clap::Args)]
pub struct SipCommon {
    /// Our voice: any audio file lipcall reads, sent in the agreed codec, paced in real time.
    #[arg(long, value_name = "IN")]
    pub play: PathBuf,
    /// Our SIP account, sip:USER@DOMAIN (;transport=tcp|tls, or sips: for TLS on port 5061 by
    /// default): registers (digest authentication) before the call.
    /// Its password comes from --password-file or the environment variable
    /// LIPCALL_SIP_PASSWORD, never from the arguments (which every user of the machine sees).
    #[arg(long, value_name = "URI")]
    pub account: Option<String>,
    /// A file whose first line is the account's password (instead of LIPCALL_SIP_PASSWORD).
    #[arg(long, value_name = "FILE", requires = "account")]
    pub password_file: Option<PathBuf>,
    /// Register with this HOST[:PORT] instead of the account's domain.
    #[arg(long, value_name = "HOST:PORT", requires = "account")]
    pub registrar: Option<String>,
    /// Write the peer's audio as played, at its codec's rate (48000 for Opus, 8000 for
    /// G.711) unless --rate says another.
    #[arg(long, value_name = "OUT.wav")]
    pub wav: Option<PathBuf>,
    /// OUT.wav's sample rate, Hz.
    #[arg(long, value_name = "HZ", value_parser = super::parse_frame_rate)]
    pub rate: Option<u32>,
    /// Write the peer's viseme weights per 20 ms.
    #[arg(long, value_name = "WEIGHTS.csv")]
    pub weights: Option<PathBuf>,
    /// Stop after this many seconds (set-up included).
    #[arg(long, allow_hyphen_values = true, value_parser = super::parse_seconds)]
    pub seconds: Option<f64>,
    /// Offer or accept only this codec (otherwise Opus, G.722, PCMU and PCMA, in that order).
    #[arg(long, value_parser = parse_sip_codec)]
    pub codec: Option<Codec>,
    /// Opus's frame length, ms: 10 asks for 10 ms packets (`a=ptime:10`) and sends them where
    /// the peer takes them (no `a=ptime` above 10); 20 (the default) sends 20 unless the
    /// peer's `a=maxptime` is below 20. Other codecs go in 20 ms frames.
    #[arg(long, default_value_t = 20, value_parser = super::parse_frame_ms)]
    pub frame_ms: u8,
    /// A STUN server, HOST:PORT: the SDP gives the media address it sees (behind a NAT).
    #[arg(long, value_name = "HOST:PORT")]
    pub stun: Option<String>,
    /// SRTP (AES_CM_128_HMAC_SHA1_80 keyed by SDES, RFC 4568): `optional` (the default)
    /// offers it where the signalling is TLS and takes it when offered; `required` (or
    /// `--srtp` alone) offers it always and refuses a call without it (`sip answer`: 488);
    /// `off` offers plain RTP even over TLS. SDES keys travel in the SIP messages: as safe as
    /// the path the signalling takes.
    #[arg(
        long,
        value_name = "WHEN",
        num_args = 0..=1,
        default_value = "optional",
        default_missing_value = "required",
        require_equals = true
    )]
    pub srtp: SrtpPolicy,
    /// A PEM file of the authority that signed the TLS server's certificate, trusted beside
    /// the system's roots (a PBX's own CA).
    #[arg(long, value_name = "FILE")]
    pub ca: Option<PathBuf>,
}

#[derive(Debug, Clone, clap::Args)]
pub struct SipCallArgs {
    /// Whom to call: sip:USER@HOST[:PORT], with ;transport=tcp or ;transport=tls (or sips:)
    /// for those. With --account, a callee of the account's domain is reached through its
    /// registrar, over the account's transport.
    pub target: String,
    #[command(flatten)]
    pub common: SipCommon,
    /// DTMF keys (0-9 * # A-D) to send as RFC 4733 events once the call is answered.
    #[arg(long, value_name = "DIGITS")]
    pub dtmf: Option<String>,
    /// Our SIP socket (UDP; TCP and TLS connect from its address); by default a free port on
    /// the address towards the peer.
    #[arg(long, value_name = "HOST:PORT")]
    pub bind: Option<String>,
}

#[derive(Debug, Clone, clap::Args)]
pub struct SipAnswerArgs {
    /// Where to wait for calls (UDP).
    #[arg(long, value_name = "HOST:PORT", default_value = "0.0.0.0:5060")]
    pub listen: String,
    #[command(flatten)]
    pub common: SipCommon,
}

fn parse_sip_codec(s: &str) -> Result<Codec, String> {
    match parse_codec(s)? {
        Codec::Speex | Codec::SpeexWb => {
            Err("SIP peers do not speak Speex: opus, g722, pcmu or pcma".into())
        }
        codec => Ok(codec),
    }
}

pub fn run(command: &SipCommand) -> Result<()> {
    // A call holds secrets: our SDES key, and the account's password and digests.
    forbid_core_dumps();
    match &command.action {
        SipAction::Call(args) => call(args),
        SipAction::Answer(args) => answer(args),
    }
}

/// Where `--account`'s password is read from.
pub const SIP_PASSWORD: SecretSource = SecretSource {
    flag: "--password-file",
    variable: "LIPCALL_SIP_PASSWORD",
};

fn account(common: &SipCommon) -> Result<Option<Account>> {
    let Some(uri) = &common.account else {
        return Ok(None);
    };
    let Some(password) = SIP_PASSWORD.read(common.password_file.as_deref())? else {
        bail!(
            "--account {uri} needs its password: {}",
            SIP_PASSWORD.how_to_give()
        );
    };
    let mut account = Account::parse(uri, &password)?;
    account.registrar = common.registrar.clone();
    Ok(Some(account))
}

fn call(args: &SipCallArgs) -> Result<()> {
    let account = account(&args.common)?;
    let towards = match &account {
        Some(a) => a.registrar(),
        None => &args.target,
    };
    let bind = match &args.bind {
        Some(bind) => bind
            .parse::<SocketAddr>()
            .with_context(|| format!("--bind {bind:?}: expected IP:PORT"))?,
        None => bind_towards(towards)?,
    };
    let role = Role::Call(args.target.clone());
    run_call(&args.common, account, bind, role, args.dtmf.as_deref())
}

fn answer(args: &SipAnswerArgs) -> Result<()> {
    let account = account(&args.common)?;
    let mut listen =
        resolve_with_port(&args.listen).with_context(|| format!("--listen {:?}", args.listen))?;
    if listen.ip().is_unspecified() {
        // Our Contact and SDP must name an address the peer can reach.
        let towards = match &account {
            Some(a) => resolve_host(host_port(a.registrar()))?,
            None => IpAddr::from([203, 0, 113, 1]),
        };
        listen.set_ip(local_ip_towards(towards)?);
    }
    run_call(&args.common, account, listen, Role::Answer, None)
}

/// Our file, encoded in the agreed codec and frame length.
fn voice(path: &Path, codec: Codec, frame_ms: u8) -> Result<Packets> {
    let mut settings = EncoderSettings::default();
    settings.opus.frame_ms = frame_ms;
    let (_, packets) = load_packets(path, Some(codec), &settings)?;
    if packets.is_empty() {
        bail!("{}: no audio to send", path.display());
    }
    Ok(packets)
}

fn run_call(
    common: &SipCommon,
    account: Option<Account>,
    bind: SocketAddr,
    role: Role,
    dtmf: Option<&str>,
) -> Result<()> {
    // A file that cannot be read fails before any call is made.
    voice(&common.play, Codec::Pcmu, 20)?;
    if let Some(codec) = common.codec {
        super::check_frame_ms(codec, common.frame_ms)?;
    }
    let stop = stop_flag()?;
    let (model, mut recorder) = open_outputs(
        common.wav.as_deref(),
        common.rate,
        None,
        common.weights.as_deref(),
    )?;
    let answering = role == Role::Answer;
    let ca = match &common.ca {
        Some(path) => {
            Some(std::fs::read(path).with_context(|| format!("--ca {}", path.display()))?)
        }
        None => None,
    };
    let security = SipSecurity {
        srtp: common.srtp,
        ca,
    };
    let mut link = SipLink::open(
        bind,
        account,
        role,
        codecs(common.codec),
        common.frame_ms,
        &security,
        common.stun.as_deref(),
    )?;
    let start = Instant::now();
    let limit = common.seconds.map(Duration::from_secs_f64);
    if let Err(e) = set_up(&mut link, start, limit, &stop, answering) {
        link.hang_up();
        return Err(e);
    }
    let (codec, frame_ms) = link
        .negotiated()
        .map(|n| (n.codec, n.frame_ms))
        .context("the call was answered without media")?;
    if frame_ms != 20 || common.frame_ms != 20 {
        eprintln!("lipcall: sending {codec} in {frame_ms} ms frames");
    }
    let packets = voice(&common.play, codec, frame_ms)?;
    if let Some(keys) = dtmf
        && !link.send_digits(keys)
    {
        eprintln!("lipcall: warning: DTMF {keys:?} not sent: the peer agreed no telephone-events");
    }
    let until = limit.and_then(|l| start.checked_add(l));
    link.play(packets);
    let played = match until {
        Some(until) if Instant::now() >= until => Ok(()),
        _ => play(
            &mut link,
            DIRECT,
            until,
            model.as_ref(),
            &mut |_, _, _| {},
            &mut recorder,
            &stop,
        ),
    };
    let digits_sent = link.digits_sent();
    link.leave();
    let stats = link.rtp_stats();
    let their_report = link.heard().about_us;
    let their = |field: fn(&ReportBlock) -> u32| {
        their_report.map_or_else(|| "-".to_owned(), |b| field(&b).to_string())
    };
    eprintln!(
        "lipcall: played {:.2} s; datagrams={} rtp={} rtcp={} rtcp_stray={} sent_rtcp={} \
         their_lost={} their_jitter={} malformed={} unknown_pt={} \
         auth_failed={} dtmf_in={} sent_rtp={} dtmf_sent={} keepalives={} send_errors={}",
        recorder.seconds(),
        stats.datagrams,
        stats.rtp,
        stats.rtcp,
        stats.foreign_rtcp + stats.rtcp_auth_failed,
        stats.sent_rtcp,
        their(|b| b.cumulative_lost),
        their(|b| b.jitter),
        stats.malformed,
        stats.unknown_payload,
        stats.auth_failed - stats.rtcp_auth_failed,
        stats.events_in,
        stats.sent_rtp,
        stats.sent_events,
        stats.keepalives,
        stats.send_errors
    );
    for peer in link.peers() {
        print_peer(&peer);
    }
    if dtmf.is_some() && !digits_sent {
        eprintln!("lipcall: warning: the call ended before every DTMF key was sent");
    }
    let finished = recorder.finish();
    if !link.answered() {
        finished?;
        if let CallState::Failed(e) = link.state() {
            bail!("{e}");
        }
        let seconds = limit.map_or(0.0, |l| l.as_secs_f64());
        bail!("no answer within {seconds} s; the call was cancelled");
    }
    match link.state() {
        CallState::Failed(e) => bail!("the call failed: {e}"),
        CallState::Ended { by_peer: true } => eprintln!("lipcall: the peer hung up"),
        _ => eprintln!("lipcall: hung up"),
    }
    played.and(finished)
}

/// Registers and dials (or waits for a caller) until the call is answered; an error where it
/// is refused, fails, or the time runs out (the call is then cancelled).
fn set_up(
    link: &mut SipLink,
    start: Instant,
    limit: Option<Duration>,
    stop: &AtomicBool,
    answering: bool,
) -> Result<()> {
    loop {
        link.follow(SETUP_STEP);
        // A failure is said once, as the error below.
        for event in link.poll() {
            if !matches!(event, LinkEvent::Failed(_)) {
                print_event(&event, DIRECT);
            }
        }
        match link.state() {
            CallState::Established => return Ok(()),
            // Early media: played (and animated) while it rings.
            CallState::Setting if link.codec().is_some() => return Ok(()),
            CallState::Failed(e) => bail!("{e}"),
            // Answered and hung up within one look: the call happened, and ends as any does.
            CallState::Ended { .. } if link.answered() => return Ok(()),
            CallState::Ended { .. } => bail!("the call ended before it was answered"),
            CallState::Setting => {}
        }
        if stopped(stop) {
            bail!("stopped by a signal before the call was answered");
        }
        if limit.is_some_and(|l| start.elapsed() >= l) {
            let seconds = limit.map_or(0.0, |l| l.as_secs_f64());
            if answering {
                bail!("no call came within {seconds} s");
            }
            bail!("no answer within {seconds} s; the call was cancelled");
        }
    }
}

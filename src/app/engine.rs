//! The call engine: a worker thread that owns the sessions, the microphone and the per-peer
//! decoders' animators. It pulls decoded audio on the mixer's demand (the output device's
//! clock, [`FramePacer`]), and runs the demo sender and the status on the system clock. The UI
//! sees it through [`Shared`] (one short lock per UI frame) and steers it with [`Command`]s.
//! Its SIP phone's hooks are in `engine/sip.rs`.

mod answer;
mod consent;
mod input;
mod lookup;
mod news;
mod output;
mod phase;
mod place;
mod ring;
mod send;
mod sip;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender, TryRecvError};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::audio::pacer::PLAYBACK_LEAD;
use crate::audio::{
    Capture, DeviceChoice, FramePacer, MicControls, OpenedOutput, OutputStatus, Playback,
    PlaybackConfig,
};
use crate::call::janus::is_janus_url;
use crate::call::link::Link;
use crate::call::mumble::is_mumble_url;
use crate::call::sip_sockets::MediaSockets;
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::codec::opus::codec::Bandwidth;
use crate::net::janus::candidates::IceServers;
use crate::net::janus::messages::JanusAuth;
use crate::net::session::{Blocked, Session, SessionConfig};
use crate::net::srtp::MasterKey;
use crate::net::transport::{PeerFrame, PeerInfo};

pub use super::call_status::{
    CallPhase, CallStatus, DIRECT_ANSWER_WAIT, Encryption, RINGING_ANSWER_WAIT,
};
pub use super::counters::{DEMO_NAME, EngineCounters};
use super::demo::Demo;
use super::device_opener::DeviceOpener;
use super::listen::dialable;
use super::lookup::Lookups;
use super::mumble_call::{MumbleCall, MumbleJoin, MumbleView};
use super::retire::Retirer;
use super::revival::Revival;
use super::ring_notice::RingNotice;
use super::roster::Roster;
use super::settings::DEFAULT_CODEC;
use super::sip_call::{PhoneCommand, PhoneStatus, SipPhone, is_sip_address};
use super::timing::{RelayWatch, Ticker};

/// The peers' status and the relay's are refreshed every this many ticks (200 ms).
const STATUS_TICKS: u32 = 10;
/// How often the worker looks at the mixer's demand and the microphone at the least (the mixer
/// wakes it as it finishes each frame, the microphone after each buffer it delivers).
const POLL: Duration = Duration::from_millis(5);
/// How long the settings' speaker test rings.
pub const SPEAKER_TEST: Duration = Duration::from_secs(2);

/// What the engine is asked to do.
#[derive(Debug, Clone)]
pub enum Command {
    Call(Box<CallSpec>),
    Leave,
    SetInput(DeviceChoice),
    SetOutput(DeviceChoice),
    /// Play the ringtone for [`SPEAKER_TEST`] on the output chosen: the settings' speaker test.
    TestSpeaker,
    /// Move to this channel of the Mumble server we are on.
    Channel(u32),
    Phone(PhoneCommand),
    /// Send our microphone to the listening session's direct caller at this address.
    AnswerCaller(SocketAddr),
    /// Hang up on that direct caller and keep it out for a while.
    DeclineCaller(SocketAddr),
}

/// A call: a peer's (or relay's) address, with a room for a relay, and the codec we send in
/// it (each peer may send another; all four are received).
#[derive(Debug, Clone)]
pub struct CallSpec {
    pub address: String,
    pub room: Option<String>,
    pub passphrase: Option<String>,
    pub name: String,
    pub codec: Codec,
    /// A Janus's api_secret and token, where it asks for them.
    pub janus_auth: JanusAuth,
    /// The band Opus codes (the microphone is read at 48 kHz for it).
    pub bandwidth: Bandwidth,
    /// Opus's frame length, ms: 20, or 10 (the settings' choice; docs/audio.md).
    pub frame_ms: u8,
    /// Our Mumble certificate and the servers we trust (the user's config folder if none).
    pub mumble_identity: Option<PathBuf>,
    /// STUN and TURN servers for a Janus room's media.
    pub ice: IceServers,
}

impl Default for CallSpec {
    fn default() -> Self {
        Self {
            address: String::new(),
            room: None,
            passphrase: None,
            name: String::new(),
            codec: DEFAULT_CODEC,
            janus_auth: JanusAuth::default(),
            bandwidth: Bandwidth::Fullband,
            frame_ms: 20,
            mumble_identity: None,
            ice: IceServers::default(),
        }
    }
}

/// How the engine starts.
#[derive(Debug, Clone)]
pub struct EngineConfig {
    /// Where the idle session listens (peers may call it); loopback port 0 if none.
    pub listen: Option<SocketAddr>,
    pub demo: bool,
    pub name: String,
    pub input: DeviceChoice,
    pub output: DeviceChoice,
    /// Run without any audio device (tests): silent playback, no microphone.
    pub no_audio: bool,
    /// The output ring's margin above one device period: latency traded for robustness
    /// ([`PlaybackConfig::buffer`]).
    pub output_margin: Duration,
}

/// State both threads touch; the engine holds the lock only briefly each tick.
pub struct Shared {
    pub playback: Playback,
    /// The call's remote peers, each whole: what the UI shows and chooses, and what the engine
    /// plays and animates for it.
    pub peers: Roster,
    pub call: CallStatus,
    pub output_status: String,
    pub input_status: String,
    pub mic: Option<MicControls>,
    /// The Mumble server we are on: its channels and users.
    pub mumble: Option<MumbleView>,
    pub phone: PhoneStatus,
    /// Someone asked to see the window (a notification's Answer or Show): the UI takes it.
    pub show_window: bool,
}

pub struct Engine {
    pub shared: Arc<Mutex<Shared>>,
    pub counters: Arc<EngineCounters>,
    commands: Sender<Command>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// Locks the shared state, carrying on if the other side panicked while holding it.
pub fn lock(shared: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|e| e.into_inner())
}

impl Engine {
    pub fn start(config: EngineConfig) -> anyhow::Result<Self> {
        let playback_config = PlaybackConfig {
            device: config.output.clone(),
            buffer: config.output_margin,
            ..Default::default()
        };
        let playback = if config.no_audio {
            Playback::start_silent_because(playback_config, NO_AUDIO.into())?
        } else {
            Playback::start(playback_config)?
        };
        let output_status = describe_output(playback.status());
        let shared = Arc::new(Mutex::new(Shared {
            playback,
            peers: Roster::default(),
            call: CallStatus::default(),
            output_status,
            input_status: String::new(),
            mic: None,
            mumble: None,
            phone: PhoneStatus::default(),
            show_window: false,
        }));
        let counters = Arc::new(EngineCounters::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, rx) = std::sync::mpsc::channel();
        let worker = Worker::new(config, shared.clone(), counters.clone(), rx)?;
        let stop2 = stop.clone();
        let shared2 = shared.clone();
        let thread = std::thread::Builder::new()
            .name("lipcall-engine".into())
            .spawn(move || {
                let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    worker.run(&stop2);
                }));
                if run.is_err() {
                    tracing::error!("the engine thread panicked: calls and animation stopped");
                    lock(&shared2).call.error = Some(ENGINE_STOPPED.into());
                }
            })?;
        Ok(Self {
            shared,
            counters,
            commands: tx,
            stop,
            thread: Some(thread),
        })
    }

    /// Hands a command to the engine thread; if that thread is gone, says so in the call
    /// status (and the log) instead of dropping the command silently.
    pub fn send(&self, command: Command) {
        if self.commands.send(command).is_err() {
            tracing::error!("the engine thread has stopped: a command was dropped");
            lock(&self.shared)
                .call
                .error
                .get_or_insert_with(|| ENGINE_STOPPED.into());
        }
    }
}

/// The call status when the engine thread died.
const ENGINE_STOPPED: &str = "the engine stopped after an internal error (see the log)";

impl Drop for Engine {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take()
            && t.join().is_err()
        {
            tracing::error!("the engine thread panicked");
        }
    }
}

/// Why the app has neither sound nor microphone, when it was asked for none.
const NO_AUDIO: &str = "started with --no-audio";

/// The output line the UI shows for a playback status.
pub fn describe_output(status: &OutputStatus) -> String {
    match status {
        OutputStatus::Silent { reason } => {
            let reason = reason.strip_suffix(": playing nothing").unwrap_or(reason);
            format!("No sound: {reason}")
        }
        OutputStatus::Playing {
            device,
            rate,
            channels,
        } => format!(
            "Playing on {device} ({} kHz, {})",
            f64::from(*rate) / 1000.0,
            if *channels == 1 { "mono" } else { "stereo" }
        ),
    }
}

struct Worker {
    config: EngineConfig,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<EngineCounters>,
    commands: Receiver<Command>,
    link: Box<dyn Link>,
    /// Hangs up the links the worker is done with, off its loop.
    retirer: Retirer,
    demo: Option<Demo>,
    mic: Option<Capture>,
    /// The microphone's encoder, for the codec of the current call.
    encoder: FrameEncoder,
    /// The session has destinations: the microphone is sent.
    in_call: bool,
    /// The listening session's callers it sends the microphone back to.
    answered: Vec<SocketAddr>,
    /// The direct callers the user answered.
    consent: consent::Consent,
    /// Callers the user hung up on, kept out by the next listening session.
    blocked: Blocked,
    /// A relay call's join, until the relay confirms it.
    relay: RelayWatch,
    /// The call as its news names it: "Janus room", "Mumble server HOST:PORT".
    call_label: String,
    mumble: Option<MumbleCall>,
    phone: SipPhone,
    /// The host of a call being placed, being looked up.
    lookups: Lookups<Then>,
    /// The desktop notification of the call that rings.
    posted: Option<RingNotice>,
    /// Until when the speaker test rings.
    speaker_test_until: Option<Instant>,
    /// The output device chosen, opening.
    outputs: DeviceOpener<OpenedOutput>,
    /// A lost output opened again: when next, and how long after a failure.
    revival: Revival,
    /// The microphone chosen, opening.
    inputs: DeviceOpener<Capture>,
    /// The controls last handed to the UI: the next microphone keeps their mute and
    /// push-to-talk.
    mic_controls: Option<MicControls>,
    /// Closed microphone frames not yet skipped on the link (which skips whole 20 ms), ms.
    mic_skipped_ms: u8,
}

/// A direct call's room key, derived on the look-up's thread.
type KeySlot = Arc<OnceLock<MasterKey>>;
/// A SIP call's media sockets, bound (and STUN asked) on the look-up's thread.
type MediaSlot = Arc<Mutex<Option<MediaSockets>>>;

/// What follows a call's host being found ([`Lookups`]).
enum Then {
    /// A direct call (or a relay's room) to the address, with the room key derived beside it.
    Direct(Box<CallSpec>, KeySlot),
    /// A SIP call to `target`, from the local address found, on the media sockets bound there.
    Sip { target: String, media: MediaSlot },
    /// A Janus room on the server found.
    Janus(Box<CallSpec>),
}

/// The call's label when nothing names it otherwise.
const CALL: &str = "call";
/// The start of a relay room's call label.
const ROOM: &str = "relay room";

fn idle_session(config: &EngineConfig) -> anyhow::Result<Session> {
    let bind = config
        .listen
        .unwrap_or_else(|| SocketAddr::from(([127, 0, 0, 1], 0)));
    let mut sc = SessionConfig::new(bind);
    sc.name = Some(config.name.clone());
    // Callers wait for the user's answer, and their apps are told so.
    sc.rings_for_callers = true;
    Ok(Session::start(sc)?)
}

impl Worker {
    fn new(
        config: EngineConfig,
        shared: Arc<Mutex<Shared>>,
        counters: Arc<EngineCounters>,
        commands: Receiver<Command>,
    ) -> anyhow::Result<Self> {
        let link: Box<dyn Link> = Box::new(idle_session(&config)?);
        let mut worker = Self {
            encoder: FrameEncoder::new(DEFAULT_CODEC, &EncoderSettings::default())?,
            link,
            retirer: Retirer::start()?,
            demo: None,
            mic: None,
            in_call: false,
            answered: Vec::new(),
            consent: consent::Consent::default(),
            blocked: Blocked::default(),
            relay: RelayWatch::default(),
            call_label: CALL.into(),
            mumble: None,
            phone: SipPhone::default(),
            lookups: Lookups::default(),
            posted: None,
            speaker_test_until: None,
            revival: Revival::default(),
            outputs: DeviceOpener::new("output device"),
            inputs: DeviceOpener::new("microphone"),
            mic_controls: None,
            mic_skipped_ms: 0,
            config,
            shared,
            counters,
            commands,
        };
        worker.set_idle_status();
        if worker.config.demo {
            worker.start_demo();
        }
        worker.open_first_mic();
        Ok(worker)
    }

    fn start_demo(&mut self) {
        let addr = match self.link.local_addr() {
            Some(a) if a.ip().is_unspecified() => SocketAddr::from(([127, 0, 0, 1], a.port())),
            Some(a) => a,
            None => return,
        };
        match Demo::start(addr) {
            Ok(d) => self.demo = Some(d),
            Err(e) => lock(&self.shared).call.error = Some(format!("demo peer: {e:#}")),
        }
    }

    fn set_idle_status(&self) {
        let addr = self.link.local_addr();
        let mut s = lock(&self.shared);
        s.call = CallStatus {
            state: match addr {
                Some(a) => {
                    let dial: Vec<String> = dialable(a).iter().map(|a| a.to_string()).collect();
                    format!("others can call you at {}", dial.join(" or "))
                }
                None => "not in a call".into(),
            },
            in_call: false,
            encryption: Encryption::None,
            codec: None,
            local_addr: addr,
            error: s.call.error.take(),
            unknown_payload: 0,
            phase: match s.call.phase.clone() {
                p @ (CallPhase::Failed { .. }
                | CallPhase::Ended { .. }
                | CallPhase::Missed { .. }) => p,
                _ => CallPhase::Idle,
            },
        };
    }

    fn call(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        if is_janus_url(&spec.address) {
            return self.join_janus(spec);
        }
        if is_mumble_url(&spec.address) {
            let join = MumbleJoin {
                name: self.call_name(spec),
                password: spec.passphrase.as_deref(),
                encoder: spec.encoder_settings(),
                identity: spec.mumble_identity.as_deref(),
            };
            let (link, call, encoder) = MumbleCall::join(&spec.address, join)?;
            self.switch_link(link, encoder);
            self.relay = RelayWatch::default();
            self.call_label = format!("Mumble server {}", call.server());
            let mut s = lock(&self.shared);
            s.call = CallStatus {
                state: format!("joining the Mumble server {}…", call.server()),
                in_call: true,
                encryption: Encryption::HopByHop,
                codec: Some(Codec::Opus),
                phase: s.call.phase.clone(),
                ..CallStatus::default()
            };
            drop(s);
            self.mumble = Some(call);
            return Ok(());
        }
        if is_sip_address(&spec.address) {
            return self.dial_sip(spec);
        }
        self.place_direct(spec)
    }

    fn call_name(&self, spec: &CallSpec) -> String {
        if spec.name.trim().is_empty() {
            self.config.name.clone()
        } else {
            spec.name.clone()
        }
    }

    /// Hangs up the current link (and the demo) for a call's.
    fn switch_link(&mut self, link: Box<dyn Link>, encoder: FrameEncoder) {
        self.keep_blocks_but(None);
        self.answered.clear();
        self.consent.clear();
        self.demo = None;
        let old = std::mem::replace(&mut self.link, link);
        self.retirer.retire(old);
        self.encoder = encoder;
        self.mic_skipped_ms = 0;
        self.in_call = true;
        self.forget_call();
        self.drop_peers();
    }

    /// What the worker kept beside the link it is done with.
    fn forget_call(&mut self) {
        self.phone.call_left();
        self.call_label = CALL.into();
        self.mumble = None;
        lock(&self.shared).mumble = None;
    }

    fn leave(&mut self) -> anyhow::Result<()> {
        self.in_call = false;
        self.forget_call();
        self.drop_peers();
        let idle = Box::new(idle_session(&self.config)?);
        let old = std::mem::replace(&mut self.link, idle);
        self.retirer.retire(old);
        self.hand_on_blocks();
        self.set_idle_status();
        Ok(())
    }

    fn drop_peers(&mut self) {
        let s = &mut *lock(&self.shared);
        s.peers.clear(&mut s.playback);
    }

    fn handle(&mut self, command: Command) {
        let result = match command {
            Command::Call(spec) => {
                self.lookups.forget();
                self.consent.clear();
                self.answer_callers();
                self.start_calling(&spec.address);
                if let Err(e) = self.call(&spec) {
                    self.fail(format!("{e:#}"));
                }
                Ok(())
            }
            Command::Leave => {
                self.lookups.forget();
                let was = lock(&self.shared).call.phase.clone();
                let left = if self.in_call {
                    self.leave()
                } else {
                    // The listening session stays (its port, and whom it keeps out).
                    self.hang_up_on_callers();
                    self.drop_peers();
                    self.set_idle_status();
                    Ok(())
                };
                let by = match was {
                    CallPhase::InCall { .. } => "you hung up",
                    CallPhase::Calling { .. } => "you cancelled it",
                    _ => "",
                };
                if !by.is_empty() {
                    self.set_phase(CallPhase::Ended { by: by.into() });
                }
                left
            }
            Command::Channel(id) => self.mumble.as_ref().map_or(Ok(()), |m| m.join_channel(id)),
            Command::Phone(command) => self.phone_command(command),
            Command::AnswerCaller(addr) => self.answer_caller(addr),
            Command::DeclineCaller(addr) => {
                self.decline_caller(addr);
                Ok(())
            }
            Command::SetInput(choice) => self.open_input(choice),
            Command::SetOutput(choice) => self.open_output(choice),
            Command::TestSpeaker => {
                self.speaker_test_until = Some(Instant::now() + SPEAKER_TEST);
                Ok(())
            }
        };
        if let Err(e) = result {
            lock(&self.shared).call.error = Some(format!("{e:#}"));
        }
    }

    /// The worker's loop. Decoded audio is pulled on the mixer's demand (the output device's
    /// clock, [`FramePacer`]); the demo sender and the status follow the system clock's 20 ms
    /// ticks, as a remote sender would.
    fn run(mut self, stop: &AtomicBool) {
        let mixed = lock(&self.shared).playback.mixed();
        mixed.wake_me();
        let mut pacer = FramePacer::new(PLAYBACK_LEAD);
        let mut ticker = Ticker::new(Instant::now());
        let mut frames: Vec<PeerFrame> = Vec::new();
        let mut pass_began = Instant::now();
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            self.counters.pass_took(now - pass_began);
            pass_began = now;
            if let Some(wait) = ticker.due().checked_duration_since(Instant::now()) {
                std::thread::park_timeout(wait.min(POLL));
            }
            loop {
                match self.commands.try_recv() {
                    Ok(c) => self.handle(c),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => return,
                }
            }
            self.send_mic();
            self.follow_lookup();
            self.follow_output();
            self.follow_input();
            self.follow_link();
            self.refresh_mumble();
            self.follow_phone();
            self.follow_ring();
            if let Some(tick) = ticker.poll(Instant::now()) {
                // The output's health (a lock and a walk over the peers' clocks) once a tick,
                // not on every pass the microphone or the mixer wakes.
                self.revive_output(Instant::now());
                if let Some(demo) = &mut self.demo {
                    demo.tick();
                }
                if tick.is_multiple_of(STATUS_TICKS) {
                    let infos = self.link.peers();
                    self.check_relay();
                    self.refresh_peers(&infos);
                }
            }
            let pulls = pacer.poll(mixed.chunks(), Instant::now());
            for i in 0..pulls.total() {
                frames.clear();
                self.link.pull(Instant::now(), &mut frames);
                self.counters.ticks.fetch_add(1, Ordering::Relaxed);
                self.play(&frames, pulls.ahead(i));
            }
        }
        self.link.leave();
    }

    /// Says when the relay refused the call's room or never confirmed it.
    fn check_relay(&mut self) {
        let mut s = lock(&self.shared);
        s.call.unknown_payload = self.link.unknown_payload();
        let Some(session) = self.link.session().filter(|_| self.in_call) else {
            self.relay = RelayWatch::default();
            return;
        };
        if let Some(error) = self.relay.check(&session.stats(), Instant::now()) {
            s.call.error = Some(error);
        }
    }

    /// One pull's frames, to the mixer and through each peer's animation ([`Roster::play`]).
    fn play(&mut self, frames: &[PeerFrame], ahead: Option<usize>) {
        let s = &mut *lock(&self.shared);
        s.peers.play(
            &mut s.playback,
            frames,
            ahead,
            Instant::now(),
            &self.counters,
        );
    }

    /// The peers as the UI shows them; forgets those that have left. A real peer takes the
    /// demo's place.
    fn refresh_peers(&mut self, infos: &[PeerInfo]) {
        {
            let silent = self.link.silent_members();
            let everyone: Vec<PeerInfo> = infos.iter().chain(&silent).cloned().collect();
            let s = &mut *lock(&self.shared);
            s.peers.seat(&mut s.playback, &silent);
            s.peers.describe(&mut s.playback, &everyone, Instant::now());
        }
        self.follow_peers(infos, Instant::now());
        self.answer_callers();
        let real_peer = infos
            .iter()
            .any(|i| i.name.as_deref() != Some(DEMO_NAME) && !i.ended);
        if real_peer && let Some(d) = self.demo.take() {
            d.leave();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_output_is_described_in_words() {
        let playing = OutputStatus::Playing {
            device: "Default Audio Device".into(),
            rate: 48_000,
            channels: 2,
        };
        assert_eq!(
            describe_output(&playing),
            "Playing on Default Audio Device (48 kHz, stereo)"
        );
        let mono = OutputStatus::Playing {
            device: "USB".into(),
            rate: 44_100,
            channels: 1,
        };
        assert_eq!(describe_output(&mono), "Playing on USB (44.1 kHz, mono)");
        let asked = OutputStatus::Silent {
            reason: NO_AUDIO.into(),
        };
        assert_eq!(describe_output(&asked), "No sound: started with --no-audio");
        let gone = OutputStatus::Silent {
            reason: "the output device disappeared: playing nothing".into(),
        };
        assert_eq!(
            describe_output(&gone),
            "No sound: the output device disappeared"
        );
    }
}

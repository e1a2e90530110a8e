//! The playback engine: per-peer queues -> mixer thread -> one ring -> output callback.
//!
//! Real-time rules: the output callback only copies from the ring (rtrb, wait-free), fills
//! silence on underrun, and publishes its position through atomics ([`OutputClock`]). Mixing,
//! resampling, peers joining and leaving all happen on the mixer thread, which keeps the ring
//! filled to a target level. Without a device (or after losing it) a virtual sink consumes the
//! ring at the same pace, so the rest of the app, lip-sync included, runs on as if heard.
//!
//! Here the engine the app holds ([`Playback`]): its peers, its status and the switch between
//! outputs; beside it the sinks (`sink`: a device's stream and its callback, or the virtual
//! sink) and the mixer thread that feeds them (`mix_thread`).

mod mix_thread;
mod sink;

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::clock::{PeerClock, Schedule};
use super::devices::DeviceChoice;
use super::error::AudioError;
use super::mixer::{
    DEFAULT_MIX_RATE, MAX_PEERS, MixProgress, Mixer, PeerControls, PeerFeed, PeerId, mix_rate_for,
};
use super::ringtone::RingSwitch;
use mix_thread::{Command, mixer_thread};
pub use sink::OutputStatus;
use sink::{RingTarget, Sink, device_sink, virtual_sink};

#[cfg(test)]
pub(crate) use sink::test_output_state;

/// The output ring's margin above one device period (see docs/audio.md for the numbers).
pub const DEFAULT_OUTPUT_MARGIN: Duration = Duration::from_millis(5);

/// How the engine runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlaybackConfig {
    pub device: DeviceChoice,
    /// Audio the mixer keeps queued for the output callback beyond the device period (10 ms)
    /// each callback takes. More survives a busier machine, less answers sooner; the lip-sync
    /// clock accounts for it either way.
    pub buffer: Duration,
    /// Capacity of each peer's queue.
    pub peer_queue: Duration,
}

impl Default for PlaybackConfig {
    fn default() -> Self {
        Self {
            device: DeviceChoice::Default,
            buffer: DEFAULT_OUTPUT_MARGIN,
            peer_queue: Duration::from_secs(1),
        }
    }
}

/// Counters for a status line or a test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PlaybackStats {
    /// Device frames played, silence included.
    pub frames_played: u64,
    /// Callbacks that found the ring short, and the frames of silence they played.
    pub underruns: u64,
    pub underrun_frames: u64,
    /// The device's last reported output latency.
    pub latency: Duration,
    /// Errors the device reported (xruns and the like).
    pub device_errors: u64,
}

struct PeerEntry {
    controls: Arc<PeerControls>,
    clock: PeerClock,
}

/// The playback engine the app holds. Dropping it stops everything.
pub struct Playback {
    config: PlaybackConfig,
    sink: Sink,
    status: OutputStatus,
    /// The device was lost (gone, or stalled with errors): the choice is worth opening again.
    lost: bool,
    commands: mpsc::Sender<Command>,
    mixer: Option<JoinHandle<()>>,
    peers: HashMap<PeerId, PeerEntry>,
    next_id: u32,
    /// Frames played and device errors at the last poll that saw playback advance, and when.
    progress: (u64, u64, Instant),
    /// Why the mixer thread stopped feeding the sink, for [`Playback::poll`] to report.
    detached: Arc<Mutex<Option<String>>>,
    mixed: MixProgress,
    /// The mixer's rate, fixed for the engine's life: the first output's (48 kHz without one).
    mix_rate: u32,
    ringtone: RingSwitch,
}

/// A device that has played nothing for this long while reporting errors is taken as gone:
/// a server that drops our stream leaves cpal's ALSA host repeating a backend error, not
/// reporting a disconnect. (A stall without errors is not enough: an idle PulseAudio null
/// sink can take up to two seconds to start consuming a new stream.)
const STALL: Duration = Duration::from_millis(500);

impl std::fmt::Debug for Playback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Playback")
            .field("status", &self.status)
            .field("peers", &self.peers.len())
            .finish()
    }
}

impl Playback {
    /// Starts the engine on the configured device, or silent (virtual clock) when there is
    /// none: never fails for want of a device; [`Playback::status`] says what happened.
    pub fn start(config: PlaybackConfig) -> Result<Self, AudioError> {
        match device_sink(&config.device, config.buffer) {
            Ok((sink, ring, target, status)) => Self::with_sink(config, sink, ring, target, status),
            Err(e) => Self::start_silent_because(config, e.to_string()),
        }
    }

    /// Starts without any device: the engine runs on a virtual clock.
    pub fn start_silent(config: PlaybackConfig) -> Result<Self, AudioError> {
        Self::start_silent_because(config, "no output device chosen: playing nothing".into())
    }

    /// Starts without any device, for `reason` (what [`OutputStatus::Silent`] says).
    pub fn start_silent_because(
        config: PlaybackConfig,
        reason: String,
    ) -> Result<Self, AudioError> {
        let (sink, ring, target) = virtual_sink(DEFAULT_MIX_RATE, config.buffer);
        Self::with_sink(config, sink, ring, target, OutputStatus::Silent { reason })
    }

    fn with_sink(
        config: PlaybackConfig,
        sink: Sink,
        ring: rtrb::Producer<f32>,
        target: RingTarget,
        status: OutputStatus,
    ) -> Result<Self, AudioError> {
        let (tx, rx) = mpsc::channel();
        let detached = Arc::new(Mutex::new(None));
        let detached2 = detached.clone();
        let mix = Mixer::at_rate(mix_rate_for(sink.clock().rate()));
        let mix_rate = mix.rate();
        let mixed = mix.progress();
        let ringtone = mix.ring_switch();
        let mixer = std::thread::Builder::new()
            .name("lipcall-mixer".into())
            .spawn(move || mixer_thread(mix, rx, &detached2))
            .map_err(|_| AudioError::MixerStopped)?;
        tx.send(Command::Attach {
            ring,
            clock: sink.clock().clone(),
            target,
        })
        .map_err(|_| AudioError::MixerStopped)?;
        Ok(Self {
            config,
            sink,
            status,
            lost: false,
            commands: tx,
            mixer: Some(mixer),
            peers: HashMap::new(),
            next_id: 1,
            progress: (0, 0, Instant::now()),
            detached,
            mixed,
            mix_rate,
            ringtone,
        })
    }

    /// Plays the ringtone ([`super::ringtone`]) over the peers while `ringing`; it stops within
    /// the output's buffer of being switched off.
    pub fn set_ringing(&self, ringing: bool) {
        self.ringtone.set(ringing);
    }

    pub fn is_ringing(&self) -> bool {
        self.ringtone.is_on()
    }

    /// The mixer's rate: what [`PeerFeed`]s queue and stream positions count in.
    pub fn mix_rate(&self) -> u32 {
        self.mix_rate
    }

    /// The mixer's count of samples and 20 ms frames mixed: what the output has asked of the
    /// peers' queues so far. Pull decoded frames by it ([`super::FramePacer`]), not by the system
    /// clock, and park between polls: it wakes the puller ([`MixProgress::wake_me`]).
    pub fn mixed(&self) -> MixProgress {
        self.mixed.clone()
    }

    pub fn status(&self) -> &OutputStatus {
        &self.status
    }

    /// The device chosen, where it was lost (gone, or stalled): one to open again, as a
    /// sound server that restarts or a machine that was starved gives it back.
    pub fn lost_output(&self) -> Option<&DeviceChoice> {
        self.lost.then_some(&self.config.device)
    }

    /// Call regularly (each UI frame): keeps the peers' clocks current and, when the device
    /// has gone, switches to the silent sink and returns the status line to show.
    pub fn poll(&mut self) -> Option<&OutputStatus> {
        for p in self.peers.values_mut() {
            p.clock.drain();
        }
        if let Some(mixer) = self.mixer.take_if(|t| t.is_finished()) {
            if mixer.join().is_err() {
                tracing::error!("the mixer thread panicked");
            }
            self.status = OutputStatus::Silent {
                reason: "the mixer stopped after an internal error (see the log): playing nothing"
                    .into(),
            };
            return Some(&self.status);
        }
        let detached = self
            .detached
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        if let Some(why) = detached {
            // Not "Playing" while nothing is fed: a virtual sink keeps the clocks going.
            if matches!(self.sink, Sink::Device { .. }) {
                let (sink, ring, target) = virtual_sink(self.mix_rate, self.config.buffer);
                self.attach(sink, ring, target).ok()?;
                self.progress = (0, 0, Instant::now());
                self.lost = true;
            }
            self.status = OutputStatus::Silent {
                reason: format!("{why}: playing nothing"),
            };
            return Some(&self.status);
        }
        let played = self.sink.clock().frames_played();
        let errors = self.stats().device_errors;
        let now = Instant::now();
        if played != self.progress.0 {
            self.progress = (played, errors, now);
        }
        let stalled = now.duration_since(self.progress.2) > STALL && errors > self.progress.1;
        let lost = matches!(&self.sink, Sink::Device { fault, .. }
            if fault.lost.load(Ordering::Relaxed) || stalled);
        if !lost {
            return None;
        }
        let (sink, ring, target) = virtual_sink(self.mix_rate, self.config.buffer);
        self.attach(sink, ring, target).ok()?;
        self.progress = (0, 0, Instant::now());
        self.lost = true;
        self.status = OutputStatus::Silent {
            reason: "the output device disappeared: playing nothing".into(),
        };
        Some(&self.status)
    }

    /// Switches to another output device; on failure the current one stays.
    pub fn set_output(&mut self, choice: DeviceChoice) -> Result<(), AudioError> {
        let opened = Self::open_output(&choice, self.buffer())?;
        self.use_output(choice, opened).map(drop)
    }

    /// The output buffer a device is opened with.
    pub fn buffer(&self) -> Duration {
        self.config.buffer
    }

    /// Opens an output device without touching the playback. Opening can take seconds
    /// (PulseAudio), so a playback shared behind a lock is switched in two steps: open
    /// without the lock, then [`Playback::use_output`] under it.
    pub fn open_output(
        choice: &DeviceChoice,
        buffer: Duration,
    ) -> Result<OpenedOutput, AudioError> {
        let (sink, ring, target, status) = device_sink(choice, buffer)?;
        Ok(OpenedOutput {
            sink,
            ring,
            target,
            status,
        })
    }

    /// Plays the mix on an output opened by [`Playback::open_output`]. Returns the output it
    /// replaces, to be dropped (closing a device can take time too) outside any lock.
    pub fn use_output(
        &mut self,
        choice: DeviceChoice,
        opened: OpenedOutput,
    ) -> Result<RetiredOutput, AudioError> {
        let OpenedOutput {
            sink,
            ring,
            target,
            status,
        } = opened;
        let old = self.attach(sink, ring, target)?;
        self.config.device = choice;
        self.status = status;
        self.lost = false;
        self.progress = (0, 0, Instant::now());
        Ok(RetiredOutput { _sink: old })
    }

    /// Returns the sink replaced.
    fn attach(
        &mut self,
        sink: Sink,
        ring: rtrb::Producer<f32>,
        target: RingTarget,
    ) -> Result<Sink, AudioError> {
        self.commands
            .send(Command::Attach {
                ring,
                clock: sink.clock().clone(),
                target,
            })
            .map_err(|_| AudioError::MixerStopped)?;
        Ok(std::mem::replace(&mut self.sink, sink))
    }

    /// Adds a remote peer; hand the returned feed to its decoder thread.
    pub fn add_peer(&mut self) -> Result<PeerFeed, AudioError> {
        if self.peers.len() >= MAX_PEERS {
            return Err(AudioError::TooManyPeers { max: MAX_PEERS });
        }
        let id = PeerId(self.next_id);
        self.next_id += 1;
        let controls = Arc::new(PeerControls::default());
        let queue = (self.config.peer_queue.as_secs_f64() * f64::from(self.mix_rate)) as usize;
        let (feed, mixer_peer, clock) =
            super::mixer::peer_channel_at(id, self.mix_rate, queue, controls.clone());
        self.commands
            .send(Command::Add(mixer_peer))
            .map_err(|_| AudioError::MixerStopped)?;
        self.peers.insert(id, PeerEntry { controls, clock });
        Ok(feed)
    }

    pub fn remove_peer(&mut self, id: PeerId) {
        if self.peers.remove(&id).is_some() && self.commands.send(Command::Remove(id)).is_err() {
            tracing::error!("the mixer thread has stopped: peer {id:?} not removed");
        }
    }

    /// A peer's volume and mute (and its counters), `None` for an unknown peer.
    pub fn peer_controls(&self, id: PeerId) -> Option<&PeerControls> {
        self.peers.get(&id).map(|p| &*p.controls)
    }

    /// The mix position (samples at [`Playback::mix_rate`]) heard at `now`.
    pub fn heard_mix_position(&self, now: Instant) -> Option<u64> {
        self.sink.clock().heard_mix_position(now)
    }

    /// How long what the mixer has mixed waits before it is heard, at `now`: the output ring,
    /// the resampler (if any) and the device's own latency. `None` before the first callback.
    pub fn output_delay(&self, now: Instant) -> Option<Duration> {
        let heard = self.heard_mix_position(now)?;
        let mixed = self.mixed.samples();
        let waiting = mixed.saturating_sub(heard) as f64 / f64::from(self.mix_rate);
        Some(Duration::from_secs_f64(waiting))
    }

    /// The position in peer `id`'s stream (as counted by [`PeerFeed::push`]) heard at `now`;
    /// `None` when that peer is silent there or unknown.
    pub fn heard_position(&mut self, id: PeerId, now: Instant) -> Option<u64> {
        let mix = self.heard_mix_position(now)?;
        self.peers.get_mut(&id)?.clock.stream_position(mix)
    }

    /// Like [`Playback::heard_position`] but holds the peer's last heard position through its
    /// silences (keeps the last mouth shape).
    pub fn last_heard_position(&mut self, id: PeerId, now: Instant) -> Option<u64> {
        let mix = self.heard_mix_position(now)?;
        self.peers.get_mut(&id)?.clock.last_stream_position(mix)
    }

    /// The row of `schedule` (peer `id`'s weights, tagged with the positions
    /// [`PeerFeed::push`] returned) that belongs to the audio heard at `now`; `None` while the
    /// peer is silent (show the neutral face) or its row has not arrived.
    pub fn weights_now<'s, W>(
        &mut self,
        schedule: &'s mut Schedule<W>,
        id: PeerId,
        now: Instant,
    ) -> Option<&'s W> {
        let pos = self.heard_position(id, now)?;
        schedule.at(pos)
    }

    pub fn stats(&self) -> PlaybackStats {
        let clock = self.sink.clock();
        PlaybackStats {
            frames_played: clock.frames_played(),
            underruns: clock.underruns(),
            underrun_frames: clock.underrun_frames(),
            latency: clock.latency(),
            device_errors: match &self.sink {
                Sink::Device { fault, .. } => fault.errors.load(Ordering::Relaxed),
                Sink::Virtual { .. } => 0,
            },
        }
    }
}

impl Drop for Playback {
    fn drop(&mut self) {
        // A mixer that is gone already has nothing to stop; its panic is reported below.
        let _ = self.commands.send(Command::Stop);
        if let Some(t) = self.mixer.take()
            && t.join().is_err()
        {
            tracing::error!("the mixer thread panicked");
        }
    }
}

/// An output device opened by [`Playback::open_output`], not yet playing.
pub struct OpenedOutput {
    sink: Sink,
    ring: rtrb::Producer<f32>,
    target: RingTarget,
    status: OutputStatus,
}

/// The output a [`Playback::use_output`] replaced; dropping it closes the device.
pub struct RetiredOutput {
    _sink: Sink,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn silent_engine_plays_peers_on_the_virtual_clock() {
        let mut pb = Playback::start_silent(PlaybackConfig::default()).unwrap();
        assert!(matches!(pb.status(), OutputStatus::Silent { .. }));
        let added = Instant::now();
        let mut feed = pb.add_peer().unwrap();
        let id = feed.id();
        // The mixer runs at 48 kHz without a device: stream positions count 48 kHz samples.
        assert_eq!(
            (pb.mix_rate(), feed.rate(), feed.frame_len()),
            (48_000, 48_000, 960)
        );
        let (mut rows, mut schedule) = Schedule::channel_with_rows(64, 960);
        for f in 0..50u64 {
            let (start, n) = feed.push(&[1000; 960]);
            assert_eq!((start, n), (f * 960, 960));
            rows.send(start, f);
        }
        std::thread::sleep(Duration::from_millis(400));
        let now = Instant::now();
        let pos = pb.heard_position(id, now).expect("peer heard");
        // Past the start, and not past what the time since the peer came can play: the virtual
        // clock takes a chunk at once, then one every 20 ms (the sleep may last longer than 400 ms).
        let playable = (now - added).as_secs_f64() * 48_000.0 + 960.0;
        assert!(pos > 0 && (pos as f64) <= playable, "{pos} of {playable}");
        let row = *pb.weights_now(&mut schedule, id, now).expect("a row");
        assert_eq!(row, pos / 960);
        pb.peer_controls(id).unwrap().set_volume(0.5);
        assert!(pb.stats().frames_played > 0);
        pb.remove_peer(id);
        assert!(pb.heard_position(id, now).is_none());
    }

    #[test]
    fn frames_pulled_one_ahead_as_the_mixer_wakes_the_puller_play_without_gaps() {
        // The engine's way (the app's worker): park between polls, woken by the mixer as it
        // finishes each frame, one frame ahead. The queue holds little more than that frame, no
        // silence comes between the frames, and what is mixed waits little for the output.
        use crate::audio::pacer::{FramePacer, PLAYBACK_LEAD};
        let mut pb = Playback::start_silent(PlaybackConfig::default()).unwrap();
        let mut feed = pb.add_peer().unwrap();
        let id = feed.id();
        let mixed = pb.mixed();
        let puller = std::thread::spawn(move || {
            mixed.wake_me();
            let mut pacer = FramePacer::new(PLAYBACK_LEAD);
            let (mut most_queued, mut frames) = (0, 0u64);
            let start = Instant::now();
            while start.elapsed() < Duration::from_millis(1500) {
                std::thread::park_timeout(Duration::from_millis(5));
                let pulls = pacer.poll(mixed.chunks(), Instant::now());
                for i in 0..pulls.total() {
                    if let Some(ahead) = pulls.ahead(i) {
                        feed.push_paced(&[1000; 960], ahead, frames == 0);
                        frames += 1;
                    }
                    most_queued = most_queued.max(feed.queued());
                }
            }
            (most_queued, frames, feed)
        });
        let mut waits = Vec::new();
        for _ in 0..100 {
            std::thread::sleep(Duration::from_millis(13));
            waits.extend(pb.output_delay(Instant::now()));
        }
        let (most_queued, frames, _feed) = puller.join().unwrap();
        let starved = pb.peer_controls(id).unwrap().starved();
        assert!(frames > 50, "{frames}");
        // One frame ahead; half a frame more where the peer's first frame came mid-frame.
        assert!(most_queued <= 960 + 480, "{most_queued}");
        // (A puller held up for longer than the ring's half would show here.)
        assert!(starved < 960, "{starved} samples of silence between frames");
        waits.sort();
        let median = waits[waits.len() / 2];
        // The ring: 20 ms, topped up 10 ms at a time (it was 30 ms, 20 at a time: 30-50).
        assert!(median <= Duration::from_millis(35), "{median:?}");
    }

    #[test]
    fn an_output_the_mixer_detached_shows_in_the_status() {
        // It used to be a warning nobody saw while the status still said what played before.
        let mut pb = Playback::start_silent(PlaybackConfig::default()).unwrap();
        assert!(pb.poll().is_none());
        *pb.detached.lock().unwrap() = Some("resampling failed, output detached: test".into());
        let Some(OutputStatus::Silent { reason }) = pb.poll() else {
            panic!("the status did not change");
        };
        assert!(reason.contains("output detached"), "{reason}");
        assert!(pb.poll().is_none(), "said once");
    }

    #[test]
    fn a_missing_device_id_is_a_typed_error_and_the_engine_stays_silent() {
        let config = PlaybackConfig {
            device: DeviceChoice::Id("alsa:no-such-device-here".into()),
            ..PlaybackConfig::default()
        };
        let mut pb = Playback::start(config).unwrap();
        let OutputStatus::Silent { reason } = pb.status() else {
            panic!("expected silent");
        };
        assert!(reason.contains("no-such-device-here") || reason.contains("no output"));
        let err = pb
            .set_output(DeviceChoice::Id("alsa:no-such-device-here".into()))
            .unwrap_err();
        assert!(err.to_string().contains("not found") || err.to_string().contains("no output"));
        assert!(matches!(pb.status(), OutputStatus::Silent { .. }));
    }
}

//! The playback engine: per-peer queues -> mixer thread -> one ring -> output callback.
//!
//! Real-time rules: the output callback only copies from the ring (rtrb, wait-free), fills
//! silence on underrun, and publishes its position through atomics ([`OutputClock`]). Mixing,
//! resampling, peers joining and leaving all happen on the mixer thread, which keeps the ring
//! filled to a target level. Without a device (or after losing it) a virtual sink consumes the
//! ring at the same pace, so the rest of the app, lip-sync included, runs on as if heard.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cpal::traits::{DeviceTrait, StreamTrait};
use cpal::{FromSample, Sample, SizedSample};

use super::clock::{OutputClock, PeerClock, Schedule, SinkMapping};
use super::devices::{self, DeviceChoice, Direction};
use super::error::AudioError;
use super::mixer::{
    CHUNK, MAX_PEERS, MixProgress, Mixer, MixerPeer, PeerControls, PeerFeed, PeerId, Upsampler,
};
use crate::vocab::SAMPLE_RATE;

/// How the engine runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlaybackConfig {
    pub device: DeviceChoice,
    /// Audio the mixer keeps queued for the output callback. More survives a busier machine,
    /// less answers sooner; the lip-sync clock accounts for it either way.
    pub buffer: Duration,
    /// Capacity of each peer's queue.
    pub peer_queue: Duration,
}

impl Default for PlaybackConfig {
    fn default() -> Self {
        Self {
            device: DeviceChoice::Default,
            buffer: Duration::from_millis(60),
            peer_queue: Duration::from_secs(1),
        }
    }
}

/// What the user hears.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OutputStatus {
    Playing {
        device: String,
        rate: u32,
        channels: u16,
    },
    /// No device: the engine runs on a virtual clock and plays nothing; `reason` is the line
    /// to show.
    Silent { reason: String },
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

enum Command {
    Attach {
        ring: rtrb::Producer<f32>,
        clock: Arc<OutputClock>,
        target_frames: usize,
    },
    Add(MixerPeer),
    Remove(PeerId),
    Stop,
}

/// Raised by the device's error callback (atomics only).
#[derive(Debug, Default)]
struct Fault {
    lost: AtomicBool,
    errors: AtomicU64,
}

enum Sink {
    Device {
        _stream: cpal::Stream,
        clock: Arc<OutputClock>,
        fault: Arc<Fault>,
    },
    Virtual {
        thread: Option<JoinHandle<()>>,
        stop: Arc<AtomicBool>,
        clock: Arc<OutputClock>,
    },
}

impl Sink {
    fn clock(&self) -> &Arc<OutputClock> {
        match self {
            Sink::Device { clock, .. } | Sink::Virtual { clock, .. } => clock,
        }
    }
}

impl Drop for Sink {
    fn drop(&mut self) {
        if let Sink::Virtual { thread, stop, .. } = self {
            stop.store(true, Ordering::Relaxed);
            if let Some(t) = thread.take() {
                let _ = t.join();
            }
        }
    }
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
    commands: mpsc::Sender<Command>,
    mixer: Option<JoinHandle<()>>,
    peers: HashMap<PeerId, PeerEntry>,
    next_id: u32,
    /// Frames played and device errors at the last poll that saw playback advance, and when.
    progress: (u64, u64, Instant),
    /// Why the mixer thread stopped feeding the sink, for [`Playback::poll`] to report.
    detached: Arc<Mutex<Option<String>>>,
    mixed: MixProgress,
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

/// The output callback's state: a ring to copy from and a clock to publish to.
struct OutputState {
    ring: rtrb::Consumer<f32>,
    clock: Arc<OutputClock>,
    channels: usize,
    consumed: u64,
}

impl OutputState {
    /// Fills an interleaved buffer from the mono ring; silence where the ring runs short.
    /// No lock, no allocation, no system call beyond what the caller did to learn `heard_at`.
    fn fill<T: Sample + FromSample<f32>>(
        &mut self,
        data: &mut [T],
        heard_at: Instant,
        latency: Duration,
    ) {
        let ch = self.channels.max(1);
        let frames = data.len() / ch;
        let before = self.consumed;
        let n = self.ring.slots().min(frames);
        if let Ok(chunk) = self.ring.read_chunk(n) {
            let (a, b) = chunk.as_slices();
            for (frame, &s) in data.chunks_exact_mut(ch).zip(a.iter().chain(b)) {
                frame.fill(T::from_sample(s));
            }
            chunk.commit_all();
        }
        for frame in data.chunks_exact_mut(ch).skip(n) {
            frame.fill(T::EQUILIBRIUM);
        }
        self.consumed += n as u64;
        self.clock
            .publish(before, self.consumed, frames as u64, heard_at, latency);
    }
}

fn ring_capacity(rate: u32, buffer: Duration, chunk_out: usize) -> (usize, usize) {
    let target = (buffer.as_secs_f64() * f64::from(rate)).ceil() as usize;
    let target = target.max(chunk_out);
    (target, 2 * target + 2 * chunk_out)
}

fn chunk_out_len(rate: u32) -> usize {
    (CHUNK * rate as usize).div_ceil(SAMPLE_RATE as usize) + 1
}

fn build_output<T>(
    device: &cpal::Device,
    config: cpal::StreamConfig,
    mut state: OutputState,
    fault: Arc<Fault>,
) -> Result<cpal::Stream, cpal::Error>
where
    T: SizedSample + FromSample<f32>,
{
    device.build_output_stream::<T, _, _>(
        config,
        move |data: &mut [T], info: &cpal::OutputCallbackInfo| {
            let ts = info.timestamp();
            let latency = ts
                .playback
                .checked_duration_since(ts.callback)
                .unwrap_or_default();
            state.fill(data, Instant::now() + latency, latency);
        },
        move |e: cpal::Error| {
            fault.errors.fetch_add(1, Ordering::Relaxed);
            if matches!(
                e.kind(),
                cpal::ErrorKind::DeviceNotAvailable | cpal::ErrorKind::StreamInvalidated
            ) {
                fault.lost.store(true, Ordering::Relaxed);
            }
        },
        None,
    )
}

/// Opens the device, builds and starts its stream. Returns the sink, its ring's producer, the
/// target fill, and the status line.
fn device_sink(
    choice: &DeviceChoice,
    buffer: Duration,
) -> Result<(Sink, rtrb::Producer<f32>, usize, OutputStatus), AudioError> {
    let opened = devices::open(choice, Direction::Output)?;
    let rate = opened.config.sample_rate();
    let channels = opened.config.channels();
    let format = opened.config.sample_format();
    let config: cpal::StreamConfig = opened.config.config();
    let (target, cap) = ring_capacity(rate, buffer, chunk_out_len(rate));
    let (tx, rx) = rtrb::RingBuffer::new(cap);
    let clock = Arc::new(OutputClock::new(rate));
    let fault = Arc::new(Fault::default());
    let state = OutputState {
        ring: rx,
        clock: clock.clone(),
        channels: usize::from(channels),
        consumed: 0,
    };
    let d = &opened.device;
    let f = fault.clone();
    use cpal::SampleFormat as F;
    let stream = match format {
        F::F32 => build_output::<f32>(d, config, state, f),
        F::F64 => build_output::<f64>(d, config, state, f),
        F::I16 => build_output::<i16>(d, config, state, f),
        F::U16 => build_output::<u16>(d, config, state, f),
        F::I32 => build_output::<i32>(d, config, state, f),
        F::U32 => build_output::<u32>(d, config, state, f),
        F::I8 => build_output::<i8>(d, config, state, f),
        F::U8 => build_output::<u8>(d, config, state, f),
        other => return Err(AudioError::UnsupportedFormat(other.to_string())),
    }
    .map_err(|e| devices::no_device(Direction::Output, e.to_string()))?;
    stream
        .play()
        .map_err(|e| devices::no_device(Direction::Output, e.to_string()))?;
    let status = OutputStatus::Playing {
        device: opened.name,
        rate,
        channels,
    };
    Ok((
        Sink::Device {
            _stream: stream,
            clock,
            fault,
        },
        tx,
        target,
        status,
    ))
}

/// A sink that plays nothing at real-time pace: 8 kHz, 10 ms periods, timed by the system clock.
fn virtual_sink(buffer: Duration) -> (Sink, rtrb::Producer<f32>, usize) {
    const PERIOD: usize = 80;
    let rate = SAMPLE_RATE;
    let (target, cap) = ring_capacity(rate, buffer, CHUNK);
    let (tx, rx) = rtrb::RingBuffer::new(cap);
    let clock = Arc::new(OutputClock::new(rate));
    let stop = Arc::new(AtomicBool::new(false));
    let mut state = OutputState {
        ring: rx,
        clock: clock.clone(),
        channels: 1,
        consumed: 0,
    };
    let stop2 = stop.clone();
    let thread = std::thread::Builder::new()
        .name("lipcall-silent-sink".into())
        .spawn(move || {
            let mut scratch = [0.0f32; PERIOD];
            let start = Instant::now();
            let mut played: u64 = 0;
            while !stop2.load(Ordering::Relaxed) {
                let due = (start.elapsed().as_secs_f64() * f64::from(rate)) as u64;
                // The period [played, played + PERIOD) is heard from its nominal start on.
                while played <= due {
                    let at = start + Duration::from_secs_f64(played as f64 / f64::from(rate));
                    state.fill(&mut scratch, at, Duration::ZERO);
                    played += PERIOD as u64;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        });
    let thread = thread.ok();
    (
        Sink::Virtual {
            thread,
            stop,
            clock,
        },
        tx,
        target,
    )
}

/// The mixer thread: keeps the current sink's ring filled to its target.
fn mixer_thread(
    mut mixer: Mixer,
    commands: mpsc::Receiver<Command>,
    detached: &Mutex<Option<String>>,
) {
    let detach = |why: String| {
        tracing::warn!("{why}");
        *detached.lock().unwrap_or_else(PoisonError::into_inner) = Some(why);
    };
    let mut chunk = [0.0f32; CHUNK];
    let mut sink: Option<(rtrb::Producer<f32>, Upsampler, usize)> = None;
    loop {
        loop {
            match commands.try_recv() {
                Ok(Command::Attach {
                    ring,
                    clock,
                    target_frames,
                }) => match Upsampler::new(clock.rate()) {
                    Ok(up) => {
                        clock.set_mapping(SinkMapping {
                            mix_start: mixer.position(),
                            ring_start: 0,
                            resampler_delay: up.delay() as u64,
                            rate: clock.rate(),
                        });
                        sink = Some((ring, up, target_frames));
                    }
                    Err(e) => {
                        detach(format!("output not attached: {e}"));
                        sink = None;
                    }
                },
                Ok(Command::Add(p)) => {
                    if let Err(p) = mixer.add(p) {
                        tracing::warn!("peer {:?} not mixed: table full", p.id());
                    }
                }
                Ok(Command::Remove(id)) => {
                    mixer.remove(id);
                }
                Ok(Command::Stop) | Err(mpsc::TryRecvError::Disconnected) => return,
                Err(mpsc::TryRecvError::Empty) => break,
            }
        }
        if let Some((ring, up, target)) = sink.as_mut() {
            let cap = ring.buffer().capacity();
            while cap - ring.slots() < *target && ring.slots() >= up.next_len() {
                mixer.mix(&mut chunk);
                match up.process(&chunk) {
                    Ok(out) => {
                        // Room was checked above; a short push cannot happen.
                        let _ = ring.push_partial_slice(out);
                    }
                    Err(e) => {
                        detach(format!("resampling failed, output detached: {e}"));
                        sink = None;
                        break;
                    }
                }
            }
        }
        std::thread::sleep(Duration::from_millis(4));
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

    fn start_silent_because(config: PlaybackConfig, reason: String) -> Result<Self, AudioError> {
        let (sink, ring, target) = virtual_sink(config.buffer);
        Self::with_sink(config, sink, ring, target, OutputStatus::Silent { reason })
    }

    fn with_sink(
        config: PlaybackConfig,
        sink: Sink,
        ring: rtrb::Producer<f32>,
        target_frames: usize,
        status: OutputStatus,
    ) -> Result<Self, AudioError> {
        let (tx, rx) = mpsc::channel();
        let detached = Arc::new(Mutex::new(None));
        let detached2 = detached.clone();
        let mix = Mixer::new();
        let mixed = mix.progress();
        let mixer = std::thread::Builder::new()
            .name("lipcall-mixer".into())
            .spawn(move || mixer_thread(mix, rx, &detached2))
            .map_err(|_| AudioError::MixerStopped)?;
        tx.send(Command::Attach {
            ring,
            clock: sink.clock().clone(),
            target_frames,
        })
        .map_err(|_| AudioError::MixerStopped)?;
        Ok(Self {
            config,
            sink,
            status,
            commands: tx,
            mixer: Some(mixer),
            peers: HashMap::new(),
            next_id: 1,
            progress: (0, 0, Instant::now()),
            detached,
            mixed,
        })
    }

    /// The mixer's count of 20 ms chunks mixed: what the output has asked of the peers' queues
    /// so far. Pull decoded frames by it ([`super::FramePacer`]), not by the system clock.
    pub fn mixed(&self) -> MixProgress {
        self.mixed.clone()
    }

    pub fn status(&self) -> &OutputStatus {
        &self.status
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
                let (sink, ring, target) = virtual_sink(self.config.buffer);
                self.attach(sink, ring, target).ok()?;
                self.progress = (0, 0, Instant::now());
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
        let (sink, ring, target) = virtual_sink(self.config.buffer);
        self.attach(sink, ring, target).ok()?;
        self.progress = (0, 0, Instant::now());
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
        self.progress = (0, 0, Instant::now());
        Ok(RetiredOutput { _sink: old })
    }

    /// Returns the sink replaced.
    fn attach(
        &mut self,
        sink: Sink,
        ring: rtrb::Producer<f32>,
        target_frames: usize,
    ) -> Result<Sink, AudioError> {
        self.commands
            .send(Command::Attach {
                ring,
                clock: sink.clock().clone(),
                target_frames,
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
        let queue = (self.config.peer_queue.as_secs_f64() * f64::from(SAMPLE_RATE)) as usize;
        let (feed, mixer_peer, clock) = super::mixer::peer_channel(id, queue, controls.clone());
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

    /// The 8 kHz mix position heard at `now`.
    pub fn heard_mix_position(&self, now: Instant) -> Option<u64> {
        self.sink.clock().heard_mix_position(now)
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
    target: usize,
    status: OutputStatus,
}

/// The output a [`Playback::use_output`] replaced; dropping it closes the device.
pub struct RetiredOutput {
    _sink: Sink,
}

/// An output callback over a fresh ring, for tests that drive it by hand.
#[cfg(test)]
pub(crate) fn test_output_state(
    rate: u32,
    channels: usize,
    capacity: usize,
) -> (rtrb::Producer<f32>, impl FnMut(&mut [f32], Instant)) {
    let (tx, rx) = rtrb::RingBuffer::new(capacity);
    let mut st = OutputState {
        ring: rx,
        clock: Arc::new(OutputClock::new(rate)),
        channels,
        consumed: 0,
    };
    (tx, move |data: &mut [f32], at: Instant| {
        st.fill(data, at, Duration::from_millis(10))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_callback_copies_counts_underruns_and_publishes() {
        let (mut tx, rx) = rtrb::RingBuffer::new(16);
        let clock = Arc::new(OutputClock::new(8000));
        let mut st = OutputState {
            ring: rx,
            clock: clock.clone(),
            channels: 2,
            consumed: 0,
        };
        let _ = tx.push_partial_slice(&[0.5, -0.5, 0.25]);
        let mut data = [7i16; 8]; // 4 stereo frames, 3 in the ring
        let t = Instant::now();
        st.fill(&mut data, t, Duration::from_millis(3));
        assert_eq!(data, [16384, 16384, -16384, -16384, 8192, 8192, 0, 0]);
        assert_eq!(clock.underruns(), 1);
        assert_eq!(clock.underrun_frames(), 1);
        assert_eq!(clock.frames_played(), 4);
        let a = clock.anchor().unwrap();
        assert_eq!((a.ring_frame, a.ring_end), (0, 3));
        let mut data = [0.0f32; 8];
        st.fill(&mut data, t, Duration::ZERO);
        assert_eq!(clock.underrun_frames(), 5);
        assert_eq!(clock.anchor().unwrap().ring_frame, 3);
    }

    #[test]
    fn silent_engine_plays_peers_on_the_virtual_clock() {
        let mut pb = Playback::start_silent(PlaybackConfig::default()).unwrap();
        assert!(matches!(pb.status(), OutputStatus::Silent { .. }));
        let added = Instant::now();
        let mut feed = pb.add_peer().unwrap();
        let id = feed.id();
        let (mut rows, mut schedule) = Schedule::channel(64);
        for f in 0..50u64 {
            let (start, n) = feed.push(&[1000; 160]);
            assert_eq!((start, n), (f * 160, 160));
            rows.send(start, f);
        }
        std::thread::sleep(Duration::from_millis(400));
        let now = Instant::now();
        let pos = pb.heard_position(id, now).expect("peer heard");
        // Past the start, and not past what the time since the peer came can play: the virtual
        // clock takes a chunk at once, then one every 20 ms (the sleep may last longer than 400 ms).
        let playable = (now - added).as_secs_f64() * 8000.0 + super::super::mixer::CHUNK as f64;
        assert!(pos > 0 && (pos as f64) <= playable, "{pos} of {playable}");
        let row = *pb.weights_now(&mut schedule, id, now).expect("a row");
        assert_eq!(row, pos / 160);
        pb.peer_controls(id).unwrap().set_volume(0.5);
        assert!(pb.stats().frames_played > 0);
        pb.remove_peer(id);
        assert!(pb.heard_position(id, now).is_none());
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

//! The playback clock: which sample of which peer's stream is being heard right now.
//!
//! Three mappings are chained, each kept where its facts are known:
//! 1. output callback: ring frame <-> wall time. Each callback publishes (frames taken from the
//!    output ring before this buffer, instant the buffer's first frame reaches the listener)
//!    using the device's own latency report ([`OutputClock`]).
//! 2. mixer thread: ring frame <-> mix position (where the sink was attached, resampler delay,
//!    the device's rate and the mixer's), fixed per sink ([`SinkMapping`]).
//! 3. mixer thread: mix position <-> peer stream position, one [`Segment`] per mixed chunk, since a
//!    peer whose queue ran dry contributes silence and its stream stops advancing ([`PeerClock`]).
//!
//! [`Schedule`] then holds (stream position, weights) rows per peer and answers with the row that
//! covers the heard position. Everything here is testable without a device.

use std::collections::VecDeque;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering, fence};
use std::time::{Duration, Instant};

use crate::vocab::FRAME_SIZE;

/// Nanoseconds since a process-wide origin: lets atomics carry instants.
pub fn instant_to_nanos(t: Instant) -> u64 {
    let origin = *ORIGIN.get_or_init(Instant::now);
    // An instant before the origin only happens for instants taken before the first call.
    t.checked_duration_since(origin)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// The inverse of [`instant_to_nanos`].
pub fn nanos_to_instant(nanos: u64) -> Instant {
    let origin = *ORIGIN.get_or_init(Instant::now);
    origin + Duration::from_nanos(nanos)
}

static ORIGIN: OnceLock<Instant> = OnceLock::new();

/// The last anchor published by the output callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Anchor {
    /// Ring frames consumed before the buffer this anchor describes.
    pub ring_frame: u64,
    /// Ring frames consumed once that buffer was filled (less than `ring_frame + buffer
    /// length` when the ring ran dry and silence was played instead).
    pub ring_end: u64,
    /// When the buffer's first frame is heard, in [`instant_to_nanos`] units.
    pub heard_at_ns: u64,
}

/// Written by the output callback, read by anyone. A seqlock over atomics: the writer never
/// waits; a reader retries while a write is in progress.
#[derive(Debug)]
pub struct OutputClock {
    rate: u32,
    seq: AtomicU64,
    ring_frame: AtomicU64,
    ring_end: AtomicU64,
    heard_at_ns: AtomicU64,
    latency_ns: AtomicU64,
    /// Device frames handed to the device, silence included.
    frames_played: AtomicU64,
    /// Device frames of silence played because the ring was empty.
    underrun_frames: AtomicU64,
    /// Callbacks that found the ring short (once it had started delivering).
    underruns: AtomicU64,
    mapping: MappingCell,
    /// The thread that refills the ring (the mixer), woken after every buffer played.
    refiller: OnceLock<std::thread::Thread>,
}

impl OutputClock {
    pub fn new(rate: u32) -> Self {
        // Fix the time origin now, so the callback never initialises it.
        instant_to_nanos(Instant::now());
        Self {
            rate: rate.max(1),
            seq: AtomicU64::new(0),
            ring_frame: AtomicU64::new(0),
            ring_end: AtomicU64::new(0),
            heard_at_ns: AtomicU64::new(0),
            latency_ns: AtomicU64::new(0),
            frames_played: AtomicU64::new(0),
            underrun_frames: AtomicU64::new(0),
            underruns: AtomicU64::new(0),
            mapping: MappingCell::default(),
            refiller: OnceLock::new(),
        }
    }

    /// Unparks the calling thread after every buffer the output plays, so that a refiller
    /// parked between looks ([`std::thread::park_timeout`]) tops the ring up as soon as there
    /// is room, not a sleep later. The first thread to ask is the one woken.
    pub fn wake_me(&self) {
        let _ = self.refiller.set(std::thread::current());
    }

    /// Device rate in frames per second.
    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// Called by the output callback after filling a buffer of `buffer_frames` frames, of which
    /// the ring supplied `ring_end - ring_frame`. `heard_at` is when its first frame will be heard.
    /// Only atomics: no lock, no allocation.
    pub fn publish(
        &self,
        ring_frame: u64,
        ring_end: u64,
        buffer_frames: u64,
        heard_at: Instant,
        latency: Duration,
    ) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        self.ring_frame.store(ring_frame, Ordering::Relaxed);
        self.ring_end.store(ring_end, Ordering::Relaxed);
        self.heard_at_ns
            .store(instant_to_nanos(heard_at), Ordering::Relaxed);
        self.seq.store(s.wrapping_add(2), Ordering::Release);
        self.latency_ns.store(
            u64::try_from(latency.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        self.frames_played
            .fetch_add(buffer_frames, Ordering::Relaxed);
        let short = buffer_frames.saturating_sub(ring_end.saturating_sub(ring_frame));
        // Silence before the mixer's first frame is the start, not an underrun.
        if short > 0 && ring_end > 0 {
            self.underrun_frames.fetch_add(short, Ordering::Relaxed);
            self.underruns.fetch_add(1, Ordering::Relaxed);
        }
        // An atomic swap and at most a futex wake: no lock, no allocation.
        if let Some(t) = self.refiller.get() {
            t.unpark();
        }
    }

    /// The latest anchor, or `None` before the first callback.
    pub fn anchor(&self) -> Option<Anchor> {
        for _ in 0..1000 {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let a = Anchor {
                ring_frame: self.ring_frame.load(Ordering::Relaxed),
                ring_end: self.ring_end.load(Ordering::Relaxed),
                heard_at_ns: self.heard_at_ns.load(Ordering::Relaxed),
            };
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return (s1 > 0).then_some(a);
            }
        }
        None
    }

    /// The ring frame being heard at `now` (fractional), `None` before the first callback.
    pub fn heard_ring_frame(&self, now: Instant) -> Option<f64> {
        self.anchor()
            .map(|a| heard_ring_frame(a, self.rate, instant_to_nanos(now)))
    }

    /// The mix position (at the mixer's rate) being heard at `now`; `None` before the first callback, before the
    /// mixer attached, or while what is heard predates the mixer's first chunk.
    pub fn heard_mix_position(&self, now: Instant) -> Option<u64> {
        let ring = self.heard_ring_frame(now)?;
        self.mapping.get()?.mix_position(ring)
    }

    /// The last output latency the device reported (callback to heard).
    pub fn latency(&self) -> Duration {
        Duration::from_nanos(self.latency_ns.load(Ordering::Relaxed))
    }

    pub fn frames_played(&self) -> u64 {
        self.frames_played.load(Ordering::Relaxed)
    }

    pub fn underrun_frames(&self) -> u64 {
        self.underrun_frames.load(Ordering::Relaxed)
    }

    pub fn underruns(&self) -> u64 {
        self.underruns.load(Ordering::Relaxed)
    }

    /// Set once by the mixer thread when it starts feeding this sink.
    pub fn set_mapping(&self, mapping: SinkMapping) {
        self.mapping.set(mapping);
    }

    pub fn mapping(&self) -> Option<SinkMapping> {
        self.mapping.get()
    }
}

/// Ring frame heard at `now_ns`: linear from the anchor at the device rate, never beyond what
/// the ring actually supplied (after an underrun the silence is heard, not future frames).
pub fn heard_ring_frame(a: Anchor, rate: u32, now_ns: u64) -> f64 {
    let dt = (now_ns as f64 - a.heard_at_ns as f64) * 1e-9;
    let f = a.ring_frame as f64 + dt * f64::from(rate);
    f.clamp(0.0, a.ring_end as f64)
}

/// How the ring frames of one sink relate to the mix timeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SinkMapping {
    /// Mix position of the first chunk written to this sink.
    pub mix_start: u64,
    /// Ring frames written before that chunk (prefilled silence).
    pub ring_start: u64,
    /// Delay of the mixer -> device resampler, in device frames (0 when the rates match).
    pub resampler_delay: u64,
    /// Device rate.
    pub rate: u32,
    /// The mixer's rate: the unit of mix positions.
    pub mix_rate: u32,
}

impl SinkMapping {
    /// The mix position of ring frame `ring`, `None` before the first mixed sample.
    pub fn mix_position(&self, ring: f64) -> Option<u64> {
        let rel = ring - (self.ring_start + self.resampler_delay) as f64;
        if rel < 0.0 {
            return None;
        }
        let mix = rel * f64::from(self.mix_rate) / f64::from(self.rate.max(1));
        Some(self.mix_start + mix as u64)
    }

    /// The ring frame at which mix position `mix` starts (inverse of [`Self::mix_position`]).
    pub fn ring_frame(&self, mix: u64) -> Option<f64> {
        let rel = mix.checked_sub(self.mix_start)? as f64;
        Some(
            (self.ring_start + self.resampler_delay) as f64
                + rel * f64::from(self.rate) / f64::from(self.mix_rate.max(1)),
        )
    }
}

#[derive(Debug, Default)]
struct MappingCell {
    set: AtomicBool,
    mix_start: AtomicU64,
    ring_start: AtomicU64,
    resampler_delay: AtomicU64,
    rate: AtomicU64,
    mix_rate: AtomicU64,
}

impl MappingCell {
    fn set(&self, m: SinkMapping) {
        self.mix_start.store(m.mix_start, Ordering::Relaxed);
        self.ring_start.store(m.ring_start, Ordering::Relaxed);
        self.resampler_delay
            .store(m.resampler_delay, Ordering::Relaxed);
        self.rate.store(u64::from(m.rate), Ordering::Relaxed);
        self.mix_rate
            .store(u64::from(m.mix_rate), Ordering::Relaxed);
        self.set.store(true, Ordering::Release);
    }

    fn get(&self) -> Option<SinkMapping> {
        if !self.set.load(Ordering::Acquire) {
            return None;
        }
        Some(SinkMapping {
            mix_start: self.mix_start.load(Ordering::Relaxed),
            ring_start: self.ring_start.load(Ordering::Relaxed),
            resampler_delay: self.resampler_delay.load(Ordering::Relaxed),
            rate: u32::try_from(self.rate.load(Ordering::Relaxed)).unwrap_or(1),
            mix_rate: u32::try_from(self.mix_rate.load(Ordering::Relaxed)).unwrap_or(1),
        })
    }
}

/// `len` samples of a peer's stream, starting at `stream_start`, were mixed at `mix_start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segment {
    pub mix_start: u64,
    pub stream_start: u64,
    pub len: u32,
}

/// Maps mix positions to one peer's stream positions, from the segments the mixer reports.
/// Lives on the reader's side (the app thread); the mixer feeds it through a ring.
#[derive(Debug)]
pub struct PeerClock {
    incoming: Option<rtrb::Consumer<Segment>>,
    segments: VecDeque<Segment>,
}

/// Segments kept for lookups; older ones are dropped. 250 chunks of 20 ms = 5 s.
const KEPT_SEGMENTS: usize = 250;

impl PeerClock {
    pub fn new(incoming: Option<rtrb::Consumer<Segment>>) -> Self {
        Self {
            incoming,
            segments: VecDeque::with_capacity(KEPT_SEGMENTS + 1),
        }
    }

    /// Adds a segment directly (tests, or a caller that has no ring).
    pub fn push(&mut self, seg: Segment) {
        if let Some(last) = self.segments.back_mut()
            && last.mix_start + u64::from(last.len) == seg.mix_start
            && last.stream_start + u64::from(last.len) == seg.stream_start
            && u64::from(last.len) + u64::from(seg.len) <= u64::from(u32::MAX)
        {
            last.len += seg.len;
            return;
        }
        if seg.len == 0 {
            return;
        }
        if self.segments.len() >= KEPT_SEGMENTS {
            self.segments.pop_front();
        }
        self.segments.push_back(seg);
    }

    /// Takes what the mixer sent (its ring holds about 10 s).
    pub fn drain(&mut self) {
        while let Some(seg) = self.incoming.as_mut().and_then(|c| c.pop().ok()) {
            self.push(seg);
        }
    }

    /// The peer's stream position heard at mix position `mix`, `None` when the peer was
    /// silent there (its queue had run dry) or the position is unknown.
    pub fn stream_position(&mut self, mix: u64) -> Option<u64> {
        self.drain();
        // Segments are in mix order; search from the back, the usual query is recent.
        let seg = self.segments.iter().rev().find(|s| s.mix_start <= mix)?;
        let off = mix - seg.mix_start;
        (off < u64::from(seg.len)).then_some(seg.stream_start + off)
    }

    /// The peer's last stream position heard at or before mix position `mix` (for holding the
    /// last mouth shape through a gap).
    pub fn last_stream_position(&mut self, mix: u64) -> Option<u64> {
        self.drain();
        let seg = self.segments.iter().rev().find(|s| s.mix_start <= mix)?;
        let off = (mix - seg.mix_start).min(u64::from(seg.len).saturating_sub(1));
        Some(seg.stream_start + off)
    }
}

/// One peer's rows of per-frame data (viseme weights), keyed by stream position, and the
/// lookup "which row is heard now".
#[derive(Debug)]
pub struct Schedule<W> {
    incoming: Option<rtrb::Consumer<(u64, W)>>,
    rows: VecDeque<(u64, W)>,
    /// Stream samples a row covers (20 ms at the mixer's rate).
    row_len: u64,
}

/// Sender half of a [`Schedule`], for the decoder thread: never blocks; a full ring drops.
pub struct ScheduleSender<W> {
    tx: rtrb::Producer<(u64, W)>,
    dropped: u64,
}

impl<W> ScheduleSender<W> {
    /// Sends the row for the frame starting at stream position `pos`; false if the ring was full.
    pub fn send(&mut self, pos: u64, row: W) -> bool {
        let ok = self.tx.push((pos, row)).is_ok();
        if !ok {
            self.dropped += 1;
        }
        ok
    }

    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

const KEPT_ROWS: usize = 500;

impl<W> Default for Schedule<W> {
    fn default() -> Self {
        Self {
            incoming: None,
            rows: VecDeque::new(),
            row_len: FRAME_SIZE as u64,
        }
    }
}

impl<W> Schedule<W> {
    pub fn new() -> Self {
        Self::default()
    }

    /// A schedule of 8 kHz streams (rows of 160 samples) fed from another thread through a ring
    /// of `capacity` rows.
    pub fn channel(capacity: usize) -> (ScheduleSender<W>, Self) {
        Self::channel_with_rows(capacity, FRAME_SIZE)
    }

    /// [`Schedule::channel`] for rows of `row_len` stream samples (20 ms at the mixer's rate,
    /// [`super::PeerFeed::frame_len`]).
    pub fn channel_with_rows(capacity: usize, row_len: usize) -> (ScheduleSender<W>, Self) {
        let (tx, rx) = rtrb::RingBuffer::new(capacity.max(1));
        (
            ScheduleSender { tx, dropped: 0 },
            Self {
                incoming: Some(rx),
                row_len: row_len.max(1) as u64,
                ..Self::default()
            },
        )
    }

    /// Adds the row for the frame that starts at stream position `pos`. Rows arrive in order;
    /// an out-of-order row replaces the rows after it (the stream was reset).
    pub fn push(&mut self, pos: u64, row: W) {
        while self.rows.back().is_some_and(|(p, _)| *p >= pos) {
            self.rows.pop_back();
        }
        if self.rows.len() >= KEPT_ROWS {
            self.rows.pop_front();
        }
        self.rows.push_back((pos, row));
    }

    fn drain(&mut self) {
        while let Some((pos, row)) = self.incoming.as_mut().and_then(|c| c.pop().ok()) {
            self.push(pos, row);
        }
    }

    /// The row covering stream position `pos` (`start <= pos < start + row length`), or `None`
    /// when no row covers it. Rows wholly before `pos` are dropped: positions heard only grow.
    pub fn at(&mut self, pos: u64) -> Option<&W> {
        self.drain();
        while self.rows.get(1).is_some_and(|(next, _)| *next <= pos) {
            self.rows.pop_front();
        }
        let (start, row) = self.rows.front()?;
        (*start <= pos && pos < start + self.row_len).then_some(row)
    }

    /// Rows waiting.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::SAMPLE_RATE;
    use std::sync::Arc;

    #[test]
    fn each_buffer_played_wakes_the_refiller() {
        // The mixer parks between looks; the output's callback unparks it, so it refills the
        // ring as soon as a buffer is taken instead of a sleep later.
        let clock = Arc::new(OutputClock::new(48_000));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let c = clock.clone();
        let refiller = std::thread::spawn(move || {
            c.wake_me();
            ready_tx.send(()).unwrap();
            let mut woken = 0;
            let began = Instant::now();
            while woken < 3 && began.elapsed() < Duration::from_secs(60) {
                std::thread::park_timeout(Duration::from_secs(60));
                woken += 1;
            }
            (woken, began.elapsed())
        });
        ready_rx.recv().unwrap();
        for i in 0..3u64 {
            std::thread::sleep(Duration::from_millis(20));
            clock.publish(i * 480, (i + 1) * 480, 480, Instant::now(), Duration::ZERO);
        }
        let (woken, took) = refiller.join().unwrap();
        assert_eq!(woken, 3);
        assert!(
            took < Duration::from_secs(30),
            "parked to the timeout: {took:?}"
        );
    }

    #[test]
    fn heard_frame_follows_the_anchor_and_stops_at_the_ring_end() {
        let a = Anchor {
            ring_frame: 48_000,
            ring_end: 48_480,
            heard_at_ns: 2_000_000_000,
        };
        assert_eq!(heard_ring_frame(a, 48_000, 2_000_000_000), 48_000.0);
        // 5 ms later: 240 frames on.
        assert!((heard_ring_frame(a, 48_000, 2_005_000_000) - 48_240.0).abs() < 1e-6);
        // 10 ms before the anchor: the previous buffer, 480 frames back.
        assert!((heard_ring_frame(a, 48_000, 1_990_000_000) - 47_520.0).abs() < 1e-6);
        // Long after: the ring ran dry, what is heard is silence after the last real frame.
        assert_eq!(heard_ring_frame(a, 48_000, 3_000_000_000), 48_480.0);
    }

    #[test]
    fn published_anchor_accounts_for_latency_and_counts_underruns() {
        let clock = OutputClock::new(48_000);
        assert!(clock.anchor().is_none());
        let t = Instant::now();
        let latency = Duration::from_millis(30);
        // 480-frame buffer, the ring supplied only 400: an underrun of 80 frames.
        clock.publish(0, 400, 480, t + latency, latency);
        clock.set_mapping(SinkMapping {
            mix_start: 0,
            ring_start: 0,
            resampler_delay: 0,
            rate: 48_000,
            mix_rate: SAMPLE_RATE,
        });
        assert_eq!(clock.underruns(), 1);
        assert_eq!(clock.underrun_frames(), 80);
        assert_eq!(clock.frames_played(), 480);
        assert_eq!(clock.latency(), latency);
        // At the callback instant nothing of this buffer is heard yet: clamp at 0.
        assert_eq!(clock.heard_mix_position(t), Some(0));
        // 30 ms + 5 ms after the callback: 5 ms into the buffer = 40 samples at 8 kHz.
        let mix = clock
            .heard_mix_position(t + Duration::from_millis(35))
            .unwrap();
        assert_eq!(mix, 40);
    }

    #[test]
    fn sink_mapping_round_trips_and_skips_the_resampler_delay() {
        let m = SinkMapping {
            mix_start: 8000,
            ring_start: 960,
            resampler_delay: 480,
            rate: 48_000,
            mix_rate: SAMPLE_RATE,
        };
        assert_eq!(m.mix_position(1000.0), None);
        assert_eq!(m.mix_position(1440.0), Some(8000));
        assert_eq!(m.mix_position(1440.0 + 6.0 * 160.0), Some(8160));
        assert_eq!(m.ring_frame(8160), Some(1440.0 + 960.0));
        assert_eq!(m.ring_frame(10), None);
    }

    #[test]
    fn peer_clock_follows_gaps() {
        let mut pc = PeerClock::new(None);
        // Mixed 0..160 from stream 0, then the queue ran dry for a chunk, then 320..480 from 160.
        pc.push(Segment {
            mix_start: 0,
            stream_start: 0,
            len: 160,
        });
        pc.push(Segment {
            mix_start: 160,
            stream_start: 160,
            len: 60,
        });
        pc.push(Segment {
            mix_start: 320,
            stream_start: 220,
            len: 160,
        });
        assert_eq!(pc.stream_position(100), Some(100));
        assert_eq!(pc.stream_position(200), Some(200));
        assert_eq!(pc.stream_position(250), None);
        assert_eq!(pc.last_stream_position(250), Some(219));
        assert_eq!(pc.stream_position(330), Some(230));
        assert_eq!(pc.stream_position(480), None);
        // Contiguous segments were merged.
        assert_eq!(pc.segments.len(), 2);
    }

    #[test]
    fn schedule_picks_the_row_covering_the_heard_sample() {
        let (mut tx, mut s) = Schedule::<&str>::channel(8);
        assert!(tx.send(0, "a"));
        assert!(tx.send(160, "b"));
        assert!(tx.send(320, "c"));
        assert_eq!(s.at(0), Some(&"a"));
        assert_eq!(s.at(159), Some(&"a"));
        assert_eq!(s.at(160), Some(&"b"));
        assert_eq!(s.at(479), Some(&"c"));
        // Past the last row: nothing covers it (the decoder has not sent it).
        assert_eq!(s.at(480), None);
        assert_eq!(s.len(), 1);
        // A full ring drops and counts.
        let (mut tx, _s) = Schedule::<u8>::channel(1);
        assert!(tx.send(0, 1));
        assert!(!tx.send(160, 2));
        assert_eq!(tx.dropped(), 1);
    }

    #[test]
    fn chain_picks_the_weights_row_for_a_played_position_and_latency() {
        // Device at 48 kHz, 40 ms output latency, the sink attached at mix 0 with 480 frames of
        // resampler delay, the peer mixed from mix 800 on (stream 0 at mix 800).
        let clock = OutputClock::new(48_000);
        clock.set_mapping(SinkMapping {
            mix_start: 0,
            ring_start: 0,
            resampler_delay: 480,
            rate: 48_000,
            mix_rate: SAMPLE_RATE,
        });
        let mut pc = PeerClock::new(None);
        pc.push(Segment {
            mix_start: 800,
            stream_start: 0,
            len: 1600,
        });
        let mut sched = Schedule::new();
        for f in 0..10u64 {
            sched.push(f * 160, f);
        }
        let t0 = Instant::now();
        let latency = Duration::from_millis(40);
        // The callback at t0 had consumed 6000 ring frames and wrote 480 more.
        clock.publish(6_000, 6_480, 480, t0 + latency, latency);
        // Ring 6000 -> mix (6000 - 480) / 6 = 920 -> stream 120 -> row 0.
        let now = t0 + latency;
        let mix = clock.heard_mix_position(now).unwrap();
        assert_eq!(mix, 920);
        let pos = pc.stream_position(mix).unwrap();
        assert_eq!(sched.at(pos), Some(&0));
        // 10 ms later: mix 1000 -> stream 200 -> row 1. Before the latency is over, the
        // previous buffer is still heard: 10 ms before -> ring 5520 -> mix 840 -> row 0.
        let later = clock
            .heard_mix_position(now + Duration::from_millis(10))
            .unwrap();
        assert_eq!(later, 1000);
        assert_eq!(sched.at(pc.stream_position(later).unwrap()), Some(&1));
        let earlier = clock
            .heard_mix_position(now - Duration::from_millis(10))
            .unwrap();
        assert_eq!(earlier, 840);
    }
}

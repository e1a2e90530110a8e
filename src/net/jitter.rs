//! A per-peer adaptive jitter buffer, pulled once per 20 ms of output.
//!
//! Time is kept in the ticks of the stream's RTP clock (8000 per second for Speex and G.711,
//! 48000 for Opus, [`JitterBuffer::set_clock`]); playout runs in 20 ms frames ("slots") on a grid
//! starting at the first timestamp seen. A packet lasts any number of ticks: several 20 ms frames
//! (played one by one), or less than one, or a length off the grid (G.711 as GStreamer
//! packetises it: 173.5 ms). A packet belongs to the slot its first tick falls in and is handed
//! out with its offset into that slot; the decoder places it there. Packets of whole frames
//! that the decoder cannot place within a frame (Speex) are put on the nearest slot instead:
//! GStreamer's first Speex packet lasts 120 ticks by its timestamps, and the stream plays on
//! from the grid that packet set.
//!
//! Timing model. For every packet the buffer notes its relative delay `r = arrival - ts/clock`
//! (network transit plus the unknown offset between the two clocks). The smallest `r` over a
//! sliding window is the fastest path (`base`); the spread above it is the jitter to absorb.
//! The target delay is a high quantile of that spread plus a margin, starting at 40 ms and
//! bounded. While playing it tracks how early each packet comes before its playout slot (its
//! slack); when the worst slack nears zero it needs a frame more delay, when even the worst
//! packets come far too early a frame less.
//!
//! Where it corrects. Inserting or dropping 20 ms inside speech is heard, so the decoder's
//! caller says how loud each frame it played is ([`JitterBuffer::played`]) and the buffer
//! makes its corrections inside quiet stretches (a pause of three frames or more): it asks for
//! a quiet frame to be dropped, or inserts a concealed frame after one. Only at the limits (a
//! packet about to be late, or 200 ms more delay than needed) does it correct whatever the
//! audio. Clock drift (a sender whose clock runs faster or slower than the playout's) shows as
//! a steady trend in the slack, measured over the last seconds (`Trend`): against a
//! slow sender the buffer keeps the delay the drift would eat before the next pause is likely
//! (3 s), so that it never has to stretch in speech; against a fast one it sheds the surplus
//! at each pause. The buffer neither grows without bound nor starves.
//!
//! Loss and silence. A frame with no packet is concealed (`Lost`) when the sequence numbers say
//! a packet is missing there; when the next packet follows the last one played in sequence the
//! sender paused (a talk spurt ended: its timestamps moved on, nothing was lost) and the frame is
//! a `Pause`: nothing is played. While nothing at all is buffered the buffer cannot tell the two
//! apart: it conceals for about its own delay (the time a packet in flight may still take), then
//! pauses. `lost` counts what the sequence numbers show missing (RFC 3550), never a pause.
//! Packets arriving after their slot was played are `late` and dropped; repeated sequence
//! numbers are `duplicates`.
//!
//! New streams on the same SSRC. After BYE, a packet that is not a straggler of the old stream
//! starts a new one (a redial with the same SSRC): sequence state starts over and the packet is
//! placed where it arrives, after what of the old stream is still to play. Without
//! BYE, a sequence number far from the last (RFC 3550 A.1: two in a row confirm it) starts a new
//! stream too, and a timestamp that jumps against the sequence (backwards, or ahead of the time
//! that passed by more than the largest delay) re-anchors the timeline where the packet's
//! arrival puts it: a new talk spurt rather than a stream of late packets.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

/// Packets whose slack steers the delay while playing.
const SLACK_WINDOW: usize = 100;
/// Pulls whose timing gives the pull clock's jitter.
const PULL_WINDOW: usize = 50;
/// Seconds of one playout frame.
const FRAME_SECONDS: f64 = 0.02;
/// The clock of a buffer until told otherwise (Speex, G.711).
pub const DEFAULT_CLOCK: u32 = 8000;
/// A packet lasts at most this many frames (longer claims are cut).
const MAX_PACKET_FRAMES: u32 = 64;
/// RFC 3550 A.1: sequence numbers this far ahead of the highest, or this far behind it, are not
/// the stream continuing; two such in a row start a new sequence.
const MAX_DROPOUT: i64 = 3000;
const MAX_MISORDER: i64 = 100;
/// Quiet frames in a row before the buffer corrects inside them: a pause, not a stop's
/// closure within a word.
const QUIET_RUN: u32 = 3;
/// Frames between two corrections inside a pause.
const QUIET_INTERVAL: u32 = 3;
/// The longest the buffer expects speech to go on without a pause, in seconds: against a slow
/// sender it keeps the delay the drift would eat meanwhile.
const ANTICIPATION: f64 = 3.0;
/// Spare delay, in seconds, beyond what the buffer sheds in pauses, at which it drops a frame
/// whatever its loudness (a sound that never pauses, from a fast sender).
const FORCED_SPARE: f64 = 0.2;
/// A drift of the slack faster than this (seconds per second, 0.05 %) is a fast sender: the
/// buffer sheds spare delay in pauses from a lower level than a jitter-free start can show.
const FAST_DRIFT: f64 = 0.0005;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JitterConfig {
    pub initial_delay: Duration,
    pub min_delay: Duration,
    pub max_delay: Duration,
    /// Safety added to the measured jitter quantile.
    pub margin: Duration,
    /// Packets held at most; more are dropped (counted as overflow).
    pub capacity: usize,
    /// Packets whose delays form the jitter estimate.
    pub window: usize,
    /// Output frames between two delay adjustments.
    pub adapt_interval: u32,
    /// With nothing buffered for this long the talk spurt is over and playback stops.
    pub spurt_timeout: Duration,
}

impl Default for JitterConfig {
    fn default() -> Self {
        Self {
            initial_delay: Duration::from_millis(40),
            min_delay: Duration::from_millis(20),
            max_delay: Duration::from_millis(400),
            margin: Duration::from_millis(10),
            capacity: 256,
            window: 150,
            adapt_interval: 10,
            spurt_timeout: Duration::from_millis(300),
        }
    }
}

/// A packet handed out for decoding; it reads as its payload bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Piece {
    pub payload: Vec<u8>,
    /// The payload type it arrived with (a stream may switch codecs).
    pub payload_type: u8,
    /// Where it starts within the frame being played, in clock ticks (0 on the grid).
    pub offset: u32,
}

impl std::ops::Deref for Piece {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        &self.payload
    }
}

/// What to play for the next 20 ms.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Playout {
    /// Decode this packet, which starts in this frame (and its first 20 ms).
    Packet(Piece),
    /// Several packets shorter than a frame start in this frame: decode them in order.
    Pieces(Vec<Piece>),
    /// Play on from the packet(s) handed out before (concealing what they do not cover).
    NextFrame,
    /// The frame is missing: conceal it.
    Lost,
    /// The sender paused here (the talk spurt goes on after a gap in its timestamps): play
    /// nothing, conceal nothing.
    Pause,
    /// A frame inserted to grow the delay (conceal it too).
    Stretch,
    /// Nothing is playing for this peer.
    Silent,
}

/// A received packet, as the buffer files it.
#[derive(Debug, Clone, Copy)]
pub struct Arrival<'a> {
    pub sequence: u16,
    pub timestamp: u32,
    pub marker: bool,
    pub payload_type: u8,
    pub payload: &'a [u8],
    /// How long the packet lasts, in clock ticks.
    pub duration: u32,
    /// The payload is whole frames that play on the 20 ms grid: its timestamp is rounded to
    /// the nearest slot, and it is handed out at offset 0.
    pub on_grid: bool,
    pub at: Instant,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct JitterStats {
    pub received: u64,
    pub duplicates: u64,
    pub late: u64,
    pub reordered: u64,
    pub overflow: u64,
    /// Frames decoded from packets.
    pub played: u64,
    /// Packets the sequence numbers show missing (RFC 3550: expected minus received, over
    /// every stream this SSRC sent).
    pub lost: u64,
    /// Frames concealed because their packet was missing (lost or late) or had not come yet.
    pub missing: u64,
    /// Frames inside a talk spurt where the sender paused (nothing played).
    pub paused: u64,
    /// Frames inserted to grow the delay.
    pub stretched: u64,
    /// Frames skipped to shrink the delay.
    pub dropped: u64,
    /// Of the frames inserted and skipped, those made at the limits of the delay whatever the
    /// audio (no pause came in time); the others were inside pauses.
    pub forced: u64,
    /// The sender's clock against the playout's, in parts per million (positive: the sender
    /// is fast), from the trend of the packets' slack; 0 until it is known.
    pub drift_ppm: f64,
    /// Packets left behind when the stream's clock rate changed (a switch of codec).
    pub flushed: u64,
    /// Talk spurts started.
    pub spurts: u64,
    /// New streams on this SSRC after the first (after BYE, or a new sequence).
    pub restarts: u64,
    /// Timelines re-anchored at a timestamp discontinuity.
    pub rebased: u64,
    /// Packets held back while a far sequence number waits for its successor (RFC 3550 A.1).
    pub probation: u64,
    /// RFC 3550 interarrival jitter in ms.
    pub jitter_ms: f64,
    pub target_delay_ms: f64,
    /// The delay the buffer plays at now (above the fastest packet seen).
    pub current_delay_ms: f64,
    pub buffered_frames: usize,
}

/// How loud a played frame is, as its decoder heard it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loudness {
    /// Silence or near it: dropping it, or adding a frame after it, goes unheard.
    Quiet,
    Audible,
}

/// What the buffer makes of the frame just played ([`JitterBuffer::played`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Correction {
    /// Play it.
    Keep,
    /// Drop it (it is quiet and the delay is more than needed): pop the next frame in its
    /// place, at the same time.
    Drop,
    /// Play it; the next pop inserts a concealed frame after it (the delay is short).
    Insert,
}

/// What the last adaptation asked for, to be done inside a pause.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Want {
    Nothing,
    Grow,
    Shrink,
}

/// Seconds of arrivals one block of the slack trend spans.
const TREND_BLOCK: f64 = 0.25;
/// Blocks the trend is fitted over (12 s), and the fewest that give one (1 s).
const TREND_BLOCKS: usize = 48;
const TREND_MIN_BLOCKS: usize = 4;

/// The trend of a per-packet time over the last seconds: per block of arrivals its smallest
/// value (jitter only adds to it), a least-squares line through the blocks. Of the packets'
/// slack (corrected for the frames the buffer inserted and dropped), the slope is the drift
/// between the sender's clock and the playout clock; of their transit, between the sender's
/// and the system clock the arrivals are timed by.
#[derive(Debug)]
struct Trend {
    block_start: f64,
    block_min: f64,
    blocks: VecDeque<(f64, f64)>,
}

impl Trend {
    fn new() -> Self {
        Self {
            block_start: f64::NAN,
            block_min: f64::INFINITY,
            blocks: VecDeque::with_capacity(TREND_BLOCKS),
        }
    }

    fn clear(&mut self) {
        self.block_start = f64::NAN;
        self.block_min = f64::INFINITY;
        self.blocks.clear();
    }

    /// A packet arriving at `now` (seconds) with `value`.
    fn note(&mut self, now: f64, value: f64) {
        if self.block_start.is_nan() {
            self.block_start = now;
        }
        if now - self.block_start >= TREND_BLOCK {
            if self.blocks.len() == TREND_BLOCKS {
                self.blocks.pop_front();
            }
            self.blocks.push_back((self.block_start, self.block_min));
            self.block_start = now;
            self.block_min = f64::INFINITY;
        }
        self.block_min = self.block_min.min(value);
    }

    /// Seconds gained per second, and its standard error. Of the slack: negative when the
    /// sender's clock is slower than the playout clock (packets come later and later),
    /// positive when it is faster.
    fn fit(&self) -> Option<(f64, f64)> {
        let n = self.blocks.len();
        if n < TREND_MIN_BLOCKS {
            return None;
        }
        let (st, sm) = self
            .blocks
            .iter()
            .fold((0.0, 0.0), |(st, sm), &(t, m)| (st + t, sm + m));
        let (t_mean, m_mean) = (st / n as f64, sm / n as f64);
        let (mut num, mut den) = (0.0, 0.0);
        for &(t, m) in &self.blocks {
            num += (t - t_mean) * (m - m_mean);
            den += (t - t_mean) * (t - t_mean);
        }
        if den <= 0.0 {
            return None;
        }
        let slope = num / den;
        let residual: f64 = self
            .blocks
            .iter()
            .map(|&(t, m)| (m - m_mean - slope * (t - t_mean)).powi(2))
            .sum();
        Some((slope, (residual / (n - 2) as f64 / den).sqrt()))
    }

    /// The drift as far as it is certain: the slope less twice its standard error (0 when
    /// that leaves nothing), so that jitter is not taken for drift.
    fn drift(&self) -> f64 {
        self.fit().map_or(0.0, |(slope, error)| {
            slope.signum() * (slope.abs() - 2.0 * error).max(0.0)
        })
    }
}

/// See [`JitterBuffer::limits`].
struct Limits {
    grow_forced: f64,
    grow_quiet: f64,
    shrink_quiet: f64,
    shrink_forced: f64,
}

#[derive(Debug)]
struct Entry {
    payload: Vec<u8>,
    payload_type: u8,
    duration: u32,
    /// Extended sequence number.
    seq: i64,
}

/// A packet's sequence number against the stream's.
enum SeqCheck {
    /// Extended, and whether it is the newest so far.
    Fresh(i64, bool),
    Duplicate,
    /// Far from the stream; kept out until its successor confirms a new sequence.
    Probation,
    /// Its predecessor was on probation: a new sequence starts here.
    NewSequence,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Playing,
    Ended,
}

/// Extends 16- and 32-bit RTP counters to 64 bits around the last value seen.
fn extend(last: i64, value: u64, bits: u32) -> i64 {
    let modulus = 1i64 << bits;
    let low = last.rem_euclid(modulus);
    let mut diff = value as i64 - low;
    if diff > modulus / 2 {
        diff -= modulus;
    } else if diff < -modulus / 2 {
        diff += modulus;
    }
    last + diff
}

#[derive(Debug)]
pub struct JitterBuffer {
    config: JitterConfig,
    epoch: Instant,
    state: State,
    clock: u32,
    /// Ticks per frame.
    step: i64,
    /// Timestamps this close before a slot's start belong to it (senders rounding their
    /// timestamps); packets starting later in the slot are handed out with their offset.
    tolerance: i64,
    /// Packets by their first tick, counted from `origin_ts`.
    entries: BTreeMap<i64, Entry>,
    origin_ts: Option<i64>,
    last_ts: i64,
    /// Next slot to play.
    next: i64,
    /// The tick up to which the packets handed out so far reach.
    covered: i64,
    /// The 97th percentile of the packets' delays above the fastest (seconds), once known.
    spread: Option<f64>,
    /// How early recent pulls came (see `note_pull`), and the 90th percentile of it.
    pulls_early: VecDeque<f64>,
    pulls_sorted: Vec<f64>,
    pull_jitter: f64,
    last_pull: Option<f64>,
    /// The next pull replaces a dropped frame (it comes at the same time, and is no jitter).
    replacing: bool,
    /// Recent packets' arrival and relative delay (arrival less RTP time), seconds.
    delays: VecDeque<(f64, f64)>,
    /// The relative delays' trend: a sender's clock drifting against ours.
    transit_trend: Trend,
    sorted: Vec<f64>,
    base: f64,
    target: f64,
    since_adjust: u32,
    /// Output time at which slot `play_ref.0` is (or was) played.
    play_ref: (i64, f64),
    /// How early each recent packet arrived before its playout slot, and when, in seconds.
    slack: VecDeque<(f64, f64)>,
    slack_sorted: Vec<f64>,
    /// The delay the corrections added since playout started (seconds): the slack trend
    /// measures without it.
    shifted: f64,
    trend: Trend,
    /// A correction to make inside a pause, asked for by the last pop.
    want: Want,
    /// Quiet frames played in a row.
    quiet_run: u32,
    /// The next pop inserts a frame (a pause is on and the delay is short).
    insert_next: bool,
    /// The last pop handed out received audio (which may be dropped).
    handed_audio: bool,
    last_arrival: f64,
    empty_since: Option<f64>,
    /// Where the sender said its stream starts and ends, in ticks from `origin_ts`.
    start_hint: Option<i64>,
    end_hint: Option<i64>,
    /// The next packet starts a new stream: place it where it arrives.
    anchor_next: bool,
    /// The current stream has started playing.
    stream_played: bool,
    /// The newest packet by sequence: its tick offset and arrival.
    newest: Option<(i64, f64)>,
    /// The extended sequence number of the last packet handed out (or dropped).
    last_out_seq: Option<i64>,
    /// Frames concealed in a row with nothing buffered.
    holes: u32,
    // Sequence bookkeeping (RFC 3550 A.1, A.3) for duplicates and receiver reports.
    seq_base: Option<i64>,
    seq_max: i64,
    seq_seen: u128,
    /// The sender said BYE (a packet not continuing its stream starts a new one).
    ending: bool,
    /// A far sequence number's successor, which would confirm a new sequence.
    probe: Option<u16>,
    /// Packets of the current sequence received, and those lost in earlier ones.
    stream_received: u64,
    lost_prior: u64,
    expected_prior: i64,
    received_prior: u64,
    transit: Option<f64>,
    jitter: f64,
    stats: JitterStats,
}

impl JitterBuffer {
    /// A buffer for a stream on the 8 kHz clock.
    pub fn new(config: JitterConfig, epoch: Instant) -> Self {
        Self::with_clock(config, epoch, DEFAULT_CLOCK)
    }

    /// A buffer for a stream whose RTP clock runs at `clock` Hz (at least 50).
    pub fn with_clock(config: JitterConfig, epoch: Instant, clock: u32) -> Self {
        let clock = clock.max(50);
        let step = i64::from(clock / 50);
        Self {
            config,
            epoch,
            state: State::Idle,
            clock,
            step,
            tolerance: step / 16,
            entries: BTreeMap::new(),
            origin_ts: None,
            last_ts: 0,
            next: 0,
            covered: 0,
            delays: VecDeque::with_capacity(config.window),
            transit_trend: Trend::new(),
            spread: None,
            pulls_early: VecDeque::with_capacity(PULL_WINDOW),
            pulls_sorted: Vec::with_capacity(PULL_WINDOW),
            pull_jitter: 0.0,
            last_pull: None,
            replacing: false,
            sorted: Vec::with_capacity(config.window),
            base: 0.0,
            target: config.initial_delay.as_secs_f64(),
            since_adjust: 0,
            play_ref: (0, 0.0),
            slack: VecDeque::with_capacity(SLACK_WINDOW),
            slack_sorted: Vec::with_capacity(SLACK_WINDOW),
            shifted: 0.0,
            trend: Trend::new(),
            want: Want::Nothing,
            quiet_run: 0,
            insert_next: false,
            handed_audio: false,
            last_arrival: 0.0,
            empty_since: None,
            start_hint: None,
            end_hint: None,
            anchor_next: false,
            stream_played: false,
            newest: None,
            last_out_seq: None,
            holes: 0,
            seq_base: None,
            seq_max: 0,
            seq_seen: 0,
            ending: false,
            probe: None,
            stream_received: 0,
            lost_prior: 0,
            expected_prior: 0,
            received_prior: 0,
            transit: None,
            jitter: 0.0,
            stats: JitterStats::default(),
        }
    }

    pub fn clock(&self) -> u32 {
        self.clock
    }

    /// The stream's clock rate changed (a codec switch, from Speex to Opus say). Before any
    /// packet only the rate changes (the hints an early sender report gave stay). After, the
    /// old timestamps say nothing on the new clock: the buffer starts over as for a new
    /// stream, its packets flushed; sequence numbers and counters carry on.
    pub fn set_clock(&mut self, clock: u32) {
        let clock = clock.max(50);
        if clock == self.clock {
            return;
        }
        self.clock = clock;
        self.step = i64::from(clock / 50);
        self.tolerance = self.step / 16;
        if self.stats.received == 0 {
            return;
        }
        self.reset_timing();
    }

    /// Forgets the timeline (packets buffered are flushed): the next packet starts it anew.
    fn reset_timing(&mut self) {
        self.stats.flushed += self.entries.len() as u64;
        self.entries.clear();
        self.origin_ts = None;
        self.last_ts = 0;
        if self.state != State::Idle {
            self.state = State::Idle;
        }
        self.next = 0;
        self.covered = 0;
        self.delays.clear();
        self.transit_trend.clear();
        self.spread = None;
        self.base = 0.0;
        self.target = self.config.initial_delay.as_secs_f64();
        self.slack.clear();
        self.trend.clear();
        self.empty_since = None;
        self.start_hint = None;
        self.end_hint = None;
        self.transit = None;
        self.newest = None;
        self.holes = 0;
        self.stream_played = false;
    }

    /// A new stream on this SSRC (a redial): sequence state starts over, counters go on, and its
    /// first packet is placed where it arrives, after whatever of the old stream is still to
    /// play.
    fn restart(&mut self) {
        self.lost_prior += self.stream_lost();
        self.seq_base = None;
        self.seq_seen = 0;
        self.probe = None;
        self.ending = false;
        self.stream_received = 0;
        self.expected_prior = 0;
        self.received_prior = 0;
        self.start_hint = None;
        self.end_hint = None;
        if self.state == State::Ended {
            self.state = State::Idle;
        }
        self.newest = None;
        self.anchor_next = self.origin_ts.is_some();
        self.stats.restarts += 1;
    }

    /// Packets missing from the current sequence.
    fn stream_lost(&self) -> u64 {
        match self.seq_base {
            Some(base) => (self.seq_max - base + 1 - self.stream_received as i64).max(0) as u64,
            None => 0,
        }
    }

    fn seconds(&self, t: Instant) -> f64 {
        t.saturating_duration_since(self.epoch).as_secs_f64()
    }

    /// The tick offset of `ts` from the stream's first timestamp, and `ts` extended.
    fn offset_of(&mut self, ts: u32) -> (i64, i64) {
        let ext = match self.origin_ts {
            None => {
                self.origin_ts = Some(i64::from(ts));
                i64::from(ts)
            }
            Some(_) => extend(self.last_ts, u64::from(ts), 32),
        };
        self.last_ts = ext;
        let origin = self.origin_ts.unwrap_or(ext);
        (ext - origin, ext)
    }

    /// The slot a packet starting at tick offset `off` belongs to.
    fn slot_of(&self, off: i64) -> i64 {
        (off + self.tolerance).div_euclid(self.step)
    }

    /// The first slot at or after tick offset `off` (where a stream ending there stops).
    fn slot_after(&self, off: i64) -> i64 {
        (off - self.tolerance).div_euclid(self.step) + 1
    }

    /// The output time at which slot `index` is played, by the playout reference: the
    /// deadline of every packet starting in it, wherever in it the packet starts.
    fn slot_time(&self, index: i64) -> f64 {
        let (ref_index, ref_time) = self.play_ref;
        ref_time + (index - ref_index) as f64 * FRAME_SECONDS
    }

    /// Checks and records a packet's sequence number.
    fn check_sequence(&mut self, seq: u16) -> SeqCheck {
        if self.seq_base.is_none() {
            self.seq_base = Some(i64::from(seq));
            self.seq_max = i64::from(seq);
            self.seq_seen = 1;
            self.probe = None;
            return SeqCheck::Fresh(i64::from(seq), true);
        }
        let ext = extend(self.seq_max, u64::from(seq), 16);
        let ahead = ext - self.seq_max;
        if !(-MAX_MISORDER..=MAX_DROPOUT).contains(&ahead) {
            if self.probe == Some(seq) {
                return SeqCheck::NewSequence;
            }
            self.probe = Some(seq.wrapping_add(1));
            return SeqCheck::Probation;
        }
        self.probe = None;
        if ahead > 0 {
            let shift = ahead as u32;
            self.seq_seen = if shift >= 128 {
                0
            } else {
                self.seq_seen << shift
            } | 1;
            self.seq_max = ext;
            return SeqCheck::Fresh(ext, true);
        }
        let age = (-ahead) as u32;
        if age < 128 {
            if self.seq_seen & (1 << age) != 0 {
                return SeqCheck::Duplicate;
            }
            self.seq_seen |= 1 << age;
        }
        self.stats.reordered += 1;
        SeqCheck::Fresh(ext, false)
    }

    /// After BYE: whether a packet is a straggler of the stream that ended rather than the
    /// start of a new one (its sequence number near the last, its timestamp not past the end).
    fn of_ending_stream(&self, packet: &Arrival<'_>) -> bool {
        if self.seq_base.is_none() {
            return false;
        }
        let ahead = extend(self.seq_max, u64::from(packet.sequence), 16) - self.seq_max;
        if !(-MAX_MISORDER..=16).contains(&ahead) {
            return false;
        }
        let (Some(origin), Some(end)) = (self.origin_ts, self.end_hint) else {
            return true;
        };
        let off = extend(self.last_ts, u64::from(packet.timestamp), 32) - origin;
        (-MAX_DROPOUT * self.step..=end + self.step).contains(&off)
    }

    /// Re-anchors the timeline at a timestamp discontinuity: the packet stamped `ext` (arriving
    /// at `now`) is placed where its arrival puts it, after everything played or buffered.
    fn rebase(&mut self, ext: i64, now: f64) -> i64 {
        let by_arrival = ((now - self.base) * f64::from(self.clock)).round() as i64;
        let buffered = self
            .entries
            .last_key_value()
            .map_or(0, |(&k, e)| k + i64::from(e.duration));
        let off = by_arrival
            .max(buffered)
            .max(self.covered)
            .max(self.next * self.step);
        self.origin_ts = Some(ext - off);
        self.start_hint = None;
        self.end_hint = None;
        self.trend.clear();
        self.transit_trend.clear();
        self.stats.rebased += 1;
        off
    }

    /// Files a received packet holding `frames` whole 20 ms frames.
    pub fn insert(
        &mut self,
        seq: u16,
        ts: u32,
        marker: bool,
        payload: &[u8],
        frames: u32,
        arrival: Instant,
    ) {
        let duration = frames.clamp(1, MAX_PACKET_FRAMES) * (self.clock / 50);
        self.file(Arrival {
            sequence: seq,
            timestamp: ts,
            marker,
            payload_type: 0,
            payload,
            duration,
            on_grid: true,
            at: arrival,
        });
    }

    /// Files a received packet.
    pub fn file(&mut self, packet: Arrival<'_>) {
        let now = self.seconds(packet.at);
        if (self.ending || self.state == State::Ended) && !self.of_ending_stream(&packet) {
            self.restart();
        }
        let (ext_seq, newest) = match self.check_sequence(packet.sequence) {
            SeqCheck::Fresh(ext, newest) => (ext, newest),
            SeqCheck::Duplicate => {
                self.stats.duplicates += 1;
                return;
            }
            SeqCheck::Probation => {
                self.stats.received += 1;
                self.stats.probation += 1;
                return;
            }
            SeqCheck::NewSequence => {
                self.restart();
                match self.check_sequence(packet.sequence) {
                    SeqCheck::Fresh(ext, newest) => (ext, newest),
                    _ => return,
                }
            }
        };
        self.stats.received += 1;
        self.stream_received += 1;
        let ts = i64::from(packet.timestamp);
        let ext_ts = match self.origin_ts {
            None => {
                self.origin_ts = Some(ts);
                ts
            }
            Some(_) => extend(self.last_ts, u64::from(packet.timestamp), 32),
        };
        let clock = f64::from(self.clock);
        let max_delay = self.config.max_delay.as_secs_f64();
        let mut raw = ext_ts - self.origin_ts.unwrap_or(ext_ts);
        if self.anchor_next {
            self.anchor_next = false;
            raw = self.rebase(ext_ts, now);
        } else if let Some((last_off, last_at)) = self.newest {
            let ahead = (raw - last_off) as f64 / clock - (now - last_at);
            if newest && (raw < last_off || ahead > max_delay) {
                raw = self.rebase(ext_ts, now);
            } else if !newest && raw >= last_off {
                // Older than the newest packet but stamped after it: from before a
                // discontinuity.
                self.stats.late += 1;
                return;
            }
        }
        let on_grid = |raw: i64, step: i64| {
            if packet.on_grid {
                (raw + step / 2).div_euclid(step) * step
            } else {
                raw
            }
        };
        let mut off = on_grid(raw, self.step);
        let mut index = self.slot_of(off);
        if newest && packet.marker && self.stream_played && index < self.next {
            // A new talk spurt stamped before what was played: the sender's timestamps did not
            // move on over its pause.
            raw = self.rebase(ext_ts, now);
            off = on_grid(raw, self.step);
            index = self.slot_of(off);
        }
        if self.state == State::Idle && self.stream_played && index < self.next {
            // A straggler of a talk spurt already over (or held up longer than it lasts).
            self.stats.late += 1;
            return;
        }
        if newest {
            self.last_ts = ext_ts;
            self.newest = Some((raw, now));
        }
        self.last_arrival = now;
        self.observe_delay(now, now - raw as f64 / clock);
        self.observe_jitter(now, raw);

        if self.state == State::Playing {
            let max_gap = (max_delay / FRAME_SECONDS) as i64 * 4;
            if index < self.next {
                self.stats.late += 1;
                self.note_slack(index, now);
                return;
            }
            if index > self.next + max_gap
                || (packet.marker && self.entries.is_empty() && index > self.next + 1)
            {
                // A new talk spurt after a pause: start it with fresh timing.
                self.state = State::Idle;
                self.entries.clear();
                self.covered = self.next * self.step;
            }
        }
        if self.entries.contains_key(&off) {
            self.stats.duplicates += 1;
            return;
        }
        if self.state == State::Playing {
            self.note_slack(index, now);
        }
        if self.entries.len() >= self.config.capacity {
            self.stats.overflow += 1;
            return;
        }
        let max = MAX_PACKET_FRAMES * (self.clock / 50);
        self.entries.insert(
            off,
            Entry {
                payload: packet.payload.to_vec(),
                payload_type: packet.payload_type,
                duration: packet.duration.clamp(1, max),
                seq: ext_seq,
            },
        );
    }

    /// A packet for slot `index` arrived at `now` while playing: how early it came.
    fn note_slack(&mut self, index: i64, now: f64) {
        let slack = self.slot_time(index) - now;
        if self.slack.len() == SLACK_WINDOW {
            self.slack.pop_front();
        }
        self.slack.push_back((now, slack));
        self.trend.note(now, slack - self.shifted);
    }

    /// A packet arriving at `now` with relative delay `r`. A sender's clock drifting against
    /// ours moves every packet's delay steadily, which is no jitter: the delays are compared
    /// as projected to now along their trend.
    fn observe_delay(&mut self, now: f64, r: f64) {
        if self.delays.len() == self.config.window {
            self.delays.pop_front();
        }
        self.delays.push_back((now, r));
        self.transit_trend.note(now, r);
        let drift = self.transit_trend.drift();
        let at_now = |&(t, r): &(f64, f64)| r + drift * (now - t);
        self.base = self.delays.iter().map(at_now).fold(f64::INFINITY, f64::min);
        if self.delays.len() < 10 {
            return;
        }
        let base = self.base;
        self.sorted.clear();
        self.sorted
            .extend(self.delays.iter().map(|d| at_now(d) - base));
        self.sorted.sort_by(f64::total_cmp);
        self.spread = Some(self.sorted[(self.sorted.len() - 1) * 97 / 100]);
        self.update_target();
    }

    /// The target delay: the packets' spread and the pull clock's own jitter, plus the margin.
    fn update_target(&mut self) {
        let Some(spread) = self.spread else { return };
        let target = spread + self.pull_jitter + self.config.margin.as_secs_f64();
        self.target = target.clamp(
            self.config.min_delay.as_secs_f64(),
            self.config.max_delay.as_secs_f64(),
        );
    }

    /// A pull at `now`: how much earlier than 20 ms after the last one it came. An output that
    /// takes 40 ms at a time has its frames pulled in pairs, the second 20 ms early: its packet
    /// needs that much more delay.
    fn note_pull(&mut self, now: f64) {
        if let Some(last) = self.last_pull
            && !std::mem::take(&mut self.replacing)
        {
            if self.pulls_early.len() == PULL_WINDOW {
                self.pulls_early.pop_front();
            }
            self.pulls_early
                .push_back((last + FRAME_SECONDS - now).max(0.0));
            self.pulls_sorted.clear();
            self.pulls_sorted.extend(self.pulls_early.iter().copied());
            self.pulls_sorted.sort_by(f64::total_cmp);
            self.pull_jitter = self.pulls_sorted[(self.pulls_sorted.len() - 1) * 9 / 10];
            self.update_target();
        }
        self.last_pull = Some(now);
    }

    fn observe_jitter(&mut self, now: f64, off: i64) {
        let transit = now * f64::from(self.clock) - off as f64;
        if let Some(prev) = self.transit {
            let d = (transit - prev).abs();
            self.jitter += (d - self.jitter) / 16.0;
        }
        self.transit = Some(transit);
    }

    /// The sender said where its stream starts (an SR sent before its first packet).
    pub fn hint_start(&mut self, ts: u32) {
        // (One announced while the last stream is ending says nothing on its timeline.)
        if !self.ending && self.state != State::Ended && !self.stream_played {
            let (off, _) = self.offset_of(ts);
            self.start_hint = Some(off);
        }
    }

    /// The sender said where its stream ends (the SR sent with its BYE): play up to there.
    pub fn hint_end(&mut self, ts: u32) {
        let (off, _) = self.offset_of(ts);
        self.end_hint = Some(off);
        self.ending = true;
    }

    /// The sender said BYE: the next packet that does not continue this stream starts a new
    /// one.
    pub fn bye(&mut self) {
        self.ending = true;
    }

    /// True once the stream has ended (BYE played out) and nothing more will come.
    pub fn ended(&self) -> bool {
        self.state == State::Ended
    }

    /// Idle and nothing waiting: the peer is silent.
    pub fn idle(&self) -> bool {
        self.state != State::Playing && self.entries.is_empty()
    }

    fn delay_at(&self, now: f64, index: i64) -> f64 {
        now - (index * self.step) as f64 / f64::from(self.clock) - self.base
    }

    /// The packet starting the slot to be played next, if it is already here: after a `Lost`,
    /// the packet that follows the lost frame (Opus carries FEC for it). With its payload type.
    pub fn upcoming(&self) -> Option<(u8, &[u8])> {
        let lo = self.next * self.step;
        self.entries
            .range(lo - self.tolerance..=lo + self.tolerance)
            .next()
            .map(|(_, e)| (e.payload_type, e.payload.as_slice()))
    }

    /// Whether a packet starts in slot `index`.
    fn has_slot(&self, index: i64) -> bool {
        let lo = index * self.step - self.tolerance;
        self.entries.range(lo..lo + self.step).next().is_some()
    }

    /// What to play for the 20 ms of output starting at `now` (on the output clock).
    pub fn pop(&mut self, now: Instant) -> Playout {
        let now = self.seconds(now);
        self.note_pull(now);
        self.want = Want::Nothing;
        self.handed_audio = false;
        match self.state {
            State::Ended => return Playout::Silent,
            State::Idle => {
                let Some((&first, _)) = self.entries.first_key_value() else {
                    return self.check_end(Playout::Silent);
                };
                let first = self.slot_of(first);
                let start = match self.start_hint.map(|h| self.slot_of(h)) {
                    Some(h) if h <= first && first - h <= 10 => h,
                    _ => first,
                };
                if self.delay_at(now, start) < self.target - 0.5 * FRAME_SECONDS {
                    return Playout::Silent;
                }
                self.slack.clear();
                self.trend.clear();
                self.shifted = 0.0;
                self.quiet_run = 0;
                self.insert_next = false;
                self.start_hint = None;
                self.state = State::Playing;
                self.next = start;
                self.covered = start * self.step;
                self.since_adjust = 0;
                self.empty_since = None;
                self.holes = 0;
                self.stats.spurts += 1;
                self.stream_played = true;
            }
            State::Playing => {}
        }
        let lo = self.next * self.step;
        if let Some(end) = self.end_hint
            && self.next >= self.slot_after(end)
            && self.covered <= lo
        {
            return self.check_end(Playout::Silent);
        }
        if self.covered >= lo + self.step {
            self.next += 1;
            self.stats.played += 1;
            self.handed_audio = true;
            return Playout::NextFrame;
        }
        // Drop entries that fell behind (a skip or a resync moved past them).
        while let Some((&k, _)) = self.entries.first_key_value() {
            if self.slot_of(k) >= self.next {
                break;
            }
            if let Some((_, e)) = self.entries.pop_first() {
                self.handed_out(e.seq);
            }
            self.stats.late += 1;
        }
        if self.entries.is_empty() {
            let since = *self.empty_since.get_or_insert(now);
            if now - since >= self.config.spurt_timeout.as_secs_f64() {
                self.state = State::Idle;
                return Playout::Silent;
            }
        } else {
            self.empty_since = None;
        }
        self.play_ref = (self.next, now);
        self.stats.current_delay_ms = self.delay_at(now, self.next) * 1000.0;
        self.since_adjust = self.since_adjust.saturating_add(1);
        let room = self.delay_at(now, self.next) < self.config.max_delay.as_secs_f64();
        if std::mem::take(&mut self.insert_next) && room {
            // Asked for after a quiet frame (`played`).
            return self.stretch(now);
        }
        if self.since_adjust >= QUIET_INTERVAL && self.slack.len() >= 10 {
            // The worst slack, each packet's projected to now along the drift: against a
            // drifting sender the oldest packets' slack is no longer what the buffer keeps.
            let drift = self.trend.drift();
            self.slack_sorted.clear();
            self.slack_sorted
                .extend(self.slack.iter().map(|&(t, s)| s + drift * (now - t)));
            self.slack_sorted.sort_by(f64::total_cmp);
            let low = self.slack_sorted[self.slack_sorted.len() / 50];
            let limits = self.limits();
            let due = self.since_adjust >= self.config.adapt_interval;
            if low < limits.grow_forced && due && room {
                self.stats.forced += 1;
                return self.stretch(now);
            }
            if low < limits.grow_quiet && room {
                self.want = Want::Grow;
            } else if self.slack.len() >= SLACK_WINDOW / 2 && low > limits.shrink_quiet {
                // Shrinking waits for a fuller picture: start-up bursts look like spare delay.
                self.want = Want::Shrink;
                if due && low > limits.shrink_forced && self.has_slot(self.next + 1) {
                    self.stats.forced += 1;
                    self.skip(now);
                }
            }
        }
        let lo = self.next * self.step;
        let mut pieces = Vec::new();
        let end = lo + self.step - self.tolerance;
        while let Some(entry) = self.entries.first_entry() {
            let off = *entry.key();
            if off >= end {
                break;
            }
            let e = entry.remove();
            self.handed_out(e.seq);
            self.covered = self.covered.max(off + i64::from(e.duration));
            pieces.push(Piece {
                payload: e.payload,
                payload_type: e.payload_type,
                offset: u32::try_from(off - lo).unwrap_or(0),
            });
        }
        let partly_covered = self.covered > lo;
        self.next += 1;
        if pieces.is_empty() && !partly_covered {
            return self.missing(self.next - 1);
        }
        self.holes = 0;
        self.stats.played += 1;
        self.handed_audio = true;
        match pieces.len() {
            0 => Playout::NextFrame,
            1 => Playout::Packet(pieces.remove(0)),
            _ => Playout::Pieces(pieces),
        }
    }

    /// Where the buffer corrects its delay, by the worst slack (seconds): below `grow_forced`
    /// it inserts a frame at once, below `grow_quiet` in the next pause; above `shrink_quiet`
    /// it drops a quiet frame, above `shrink_forced` any frame.
    fn limits(&self) -> Limits {
        let margin = self.config.margin.as_secs_f64();
        // A drift three standard errors from none, at the slope measured.
        let drift = self
            .trend
            .fit()
            .filter(|&(slope, error)| slope.abs() > 3.0 * error)
            .map_or(0.0, |(slope, _)| slope);
        let grow_forced = 0.25 * margin;
        // Against a slow sender: the delay the drift eats before the next pause is likely (and
        // some, however slow it is, so that there is a pause to grow in before the limit).
        let grow_quiet = if drift < 0.0 {
            grow_forced + (-drift * ANTICIPATION).clamp(0.5 * margin, 4.0 * FRAME_SECONDS)
        } else {
            grow_forced
        };
        // Without drift, only more spare delay than a jitter-free link can show: playout starts
        // on a 20 ms output tick (up to a frame above the target) and whole frames are rounded
        // onto the grid (up to half a frame early). A fast sender's surplus is shed from lower
        // down, a frame above where the buffer would grow.
        let shrink_quiet = if drift > FAST_DRIFT {
            grow_quiet + margin + FRAME_SECONDS
        } else {
            (margin + 3.0 * FRAME_SECONDS).max(grow_quiet + margin + FRAME_SECONDS)
        };
        Limits {
            grow_forced,
            grow_quiet,
            shrink_quiet,
            shrink_forced: shrink_quiet + FORCED_SPARE,
        }
    }

    /// Inserts a frame (concealed by the decoder): 20 ms more delay.
    fn stretch(&mut self, now: f64) -> Playout {
        self.since_adjust = 0;
        self.stats.stretched += 1;
        self.slack.iter_mut().for_each(|(_, s)| *s += FRAME_SECONDS);
        self.shifted += FRAME_SECONDS;
        self.play_ref = (self.next, now + FRAME_SECONDS);
        Playout::Stretch
    }

    /// Skips the next slot's packets without playing them: 20 ms less delay.
    fn skip(&mut self, now: f64) {
        self.since_adjust = 0;
        self.slack.iter_mut().for_each(|(_, s)| *s -= FRAME_SECONDS);
        self.shifted -= FRAME_SECONDS;
        while let Some((&k, _)) = self.entries.first_key_value() {
            if self.slot_of(k) > self.next {
                break;
            }
            if let Some((_, e)) = self.entries.pop_first() {
                self.handed_out(e.seq);
            }
        }
        self.next += 1;
        self.play_ref = (self.next, now);
        self.stats.dropped += 1;
    }

    /// How loud the frame just handed out played (its decoder knows; the buffer does not).
    /// Inside a pause the buffer makes the corrections its delay needs: it asks for this frame
    /// to be dropped (the caller pops the next one in its place, at the same time) or inserts
    /// one after it. Received audio only is dropped, and only when what follows is here.
    pub fn played(&mut self, loudness: Loudness) -> Correction {
        if loudness == Loudness::Audible || self.state != State::Playing {
            self.quiet_run = 0;
            return Correction::Keep;
        }
        self.quiet_run = self.quiet_run.saturating_add(1);
        if self.quiet_run < QUIET_RUN {
            return Correction::Keep;
        }
        let next_here = self.covered >= (self.next + 1) * self.step || self.has_slot(self.next);
        match std::mem::replace(&mut self.want, Want::Nothing) {
            Want::Grow => {
                self.insert_next = true;
                Correction::Insert
            }
            Want::Shrink if self.handed_audio && next_here => {
                self.since_adjust = 0;
                self.slack.iter_mut().for_each(|(_, s)| *s -= FRAME_SECONDS);
                self.shifted -= FRAME_SECONDS;
                self.stats.played -= 1;
                self.stats.dropped += 1;
                self.handed_audio = false;
                self.replacing = true;
                Correction::Drop
            }
            _ => Correction::Keep,
        }
    }

    fn handed_out(&mut self, seq: i64) {
        self.last_out_seq = Some(seq);
    }

    /// A frame no packet covers (slot `index`): lost (conceal it) or a pause of the sender
    /// (play nothing).
    fn missing(&mut self, index: i64) -> Playout {
        let lost = match (self.entries.first_key_value(), self.last_out_seq) {
            // The next packet follows the last one in sequence: nothing is missing.
            (Some((_, e)), Some(last)) => {
                self.holes = 0;
                e.seq != last + 1
            }
            (Some(_), None) => {
                self.holes = 0;
                true
            }
            // Nothing here yet: a packet still in flight, or the sender stopped. Packets are
            // still due before the end the sender announced, and a sender whose newer packets
            // came too late has not stopped; otherwise conceal for as long as the buffer's
            // delay would wait for a late packet, then rest.
            (None, last) => {
                let hold = (self.target / FRAME_SECONDS).ceil().max(1.0) as u32;
                self.holes += 1;
                self.holes <= hold
                    || self.end_hint.is_some_and(|e| index < self.slot_after(e))
                    || last.is_some_and(|l| self.seq_base.is_some() && self.seq_max > l)
            }
        };
        if lost {
            self.stats.missing += 1;
            Playout::Lost
        } else {
            self.stats.paused += 1;
            Playout::Pause
        }
    }

    fn check_end(&mut self, otherwise: Playout) -> Playout {
        if let Some(end) = self.end_hint
            && (self.state == State::Playing || self.entries.is_empty())
            && (self.next >= self.slot_after(end) || !self.stream_played)
        {
            self.state = State::Ended;
            self.entries.clear();
        } else if self.state == State::Playing {
            self.state = State::Idle;
        }
        otherwise
    }

    /// The highest sequence number received in the current stream.
    pub fn highest_sequence(&self) -> Option<u16> {
        self.seq_base.map(|_| self.seq_max as u16)
    }

    /// New streams started on this SSRC after the first.
    pub fn restarts(&self) -> u64 {
        self.stats.restarts
    }

    pub fn stats(&self) -> JitterStats {
        let step = self.step as u64;
        JitterStats {
            jitter_ms: self.jitter / f64::from(self.clock) * 1000.0,
            drift_ppm: self.trend.fit().map_or(0.0, |(slope, _)| slope * 1e6),
            target_delay_ms: self.target * 1000.0,
            buffered_frames: self
                .entries
                .values()
                .map(|e| u64::from(e.duration).div_ceil(step) as usize)
                .sum(),
            lost: self.lost_prior + self.stream_lost(),
            ..self.stats
        }
    }

    /// Counts for an RTCP report block: (fraction lost /256 since the last call, cumulative
    /// lost, extended highest sequence, jitter in timestamp units).
    pub fn report(&mut self) -> Option<(u8, u32, u32, u32)> {
        let base = self.seq_base?;
        let expected = self.seq_max - base + 1;
        let received = self.stream_received;
        let lost = self.lost_prior as i64 + (expected - received as i64).max(0);
        let expected_interval = expected - self.expected_prior;
        let received_interval = received as i64 - self.received_prior as i64;
        self.expected_prior = expected;
        self.received_prior = received;
        let lost_interval = expected_interval - received_interval;
        let fraction = if expected_interval <= 0 || lost_interval <= 0 {
            0
        } else {
            ((lost_interval << 8) / expected_interval).min(255) as u8
        };
        Some((
            fraction,
            lost.min(0x7f_ffff) as u32,
            self.seq_max as u32,
            self.jitter as u32,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME: Duration = Duration::from_millis(20);

    /// Drives a buffer with packets sent every `send_period` and pulled every 20 ms of the
    /// output clock; `delay(i)` is packet i's network delay, `None` when lost.
    fn simulate(
        n: usize,
        send_period: Duration,
        delay: impl Fn(usize) -> Option<Duration>,
        pulls: usize,
    ) -> (Vec<Playout>, JitterStats) {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        let mut arrivals: Vec<(Instant, usize)> = (0..n)
            .filter_map(|i| delay(i).map(|d| (t0 + send_period * i as u32 + d, i)))
            .collect();
        arrivals.sort();
        let mut out = Vec::new();
        let mut a = 0;
        for k in 0..pulls {
            let now = t0 + FRAME * k as u32;
            while a < arrivals.len() && arrivals[a].0 <= now {
                let i = arrivals[a].1;
                jb.insert(
                    1000u16.wrapping_add(i as u16),
                    (i as u32).wrapping_mul(160).wrapping_add(u32::MAX - 5000),
                    i == 0,
                    &[i as u8],
                    1,
                    arrivals[a].0,
                );
                a += 1;
            }
            out.push(jb.pop(now));
        }
        (out, jb.stats())
    }

    fn played(out: &[Playout]) -> Vec<u8> {
        out.iter()
            .filter_map(|p| match p {
                Playout::Packet(v) => Some(v[0]),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn steady_stream_plays_in_order_after_initial_delay() {
        let (out, stats) = simulate(100, FRAME, |_| Some(Duration::from_millis(5)), 200);
        let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
        assert!((2..=3).contains(&first), "{first}");
        assert_eq!(played(&out), (0..100).map(|i| i as u8).collect::<Vec<_>>());
        // Nothing lost; after the stream one frame is concealed (nothing is buffered: a packet
        // might still come within the buffer's 20 ms), then the sender has paused.
        let last = out
            .iter()
            .rposition(|p| matches!(p, Playout::Packet(_)))
            .unwrap();
        assert!(out[..last].iter().all(|p| !matches!(p, Playout::Lost)));
        assert_eq!(out[last + 1], Playout::Lost);
        assert_eq!(out[last + 2], Playout::Pause);
        assert_eq!((stats.lost, stats.missing), (0, 1));
        assert_eq!(stats.stretched + stats.dropped, 0);
        assert!(stats.jitter_ms < 0.5);
        // After the stream, the spurt times out to silence.
        assert_eq!(*out.last().unwrap(), Playout::Silent);
    }

    #[test]
    fn reordering_and_duplicates_within_the_delay_are_absorbed() {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        for &i in &[0u32, 2, 1, 1, 3] {
            jb.insert(i as u16, i * 160, false, &[i as u8], 1, t0);
        }
        let s = jb.stats();
        assert_eq!((s.received, s.duplicates, s.reordered), (4, 1, 1));
        let mut got = Vec::new();
        for k in 0..8 {
            if let Playout::Packet(p) = jb.pop(t0 + FRAME * (2 + k)) {
                got.push(p[0]);
            }
        }
        assert_eq!(got, vec![0, 1, 2, 3]);
    }

    #[test]
    fn losses_are_concealed_and_late_packets_dropped() {
        // Every 10th packet lost; packet 50 arrives 300 ms late.
        let (out, stats) = simulate(
            200,
            FRAME,
            |i| match i {
                _ if i % 10 == 5 => None,
                50 => Some(Duration::from_millis(300)),
                _ => Some(Duration::from_millis(2)),
            },
            260,
        );
        // 20 lost (the late one was received); those, the late one and the frame concealed
        // after the end are missing.
        assert_eq!(stats.lost, 20, "{stats:?}");
        assert_eq!(stats.missing, 22, "{stats:?}");
        assert!(stats.late >= 1);
        let start = out.iter().position(|p| *p != Playout::Silent).unwrap();
        let end = out
            .iter()
            .rposition(|p| !matches!(p, Playout::Silent | Playout::Pause))
            .unwrap();
        // Continuous: no silence in the middle of the spurt.
        assert!(
            out[start..=end]
                .iter()
                .all(|p| !matches!(p, Playout::Silent | Playout::Pause))
        );
    }

    #[test]
    fn target_follows_jitter_and_stays_bounded() {
        // Delays 0..60 ms in a fixed pseudo-random pattern.
        let (_, stats) = simulate(
            500,
            FRAME,
            |i| Some(Duration::from_millis(((i * 37) % 61) as u64)),
            560,
        );
        assert!(
            stats.target_delay_ms > 55.0 && stats.target_delay_ms < 90.0,
            "{stats:?}"
        );
        let late_share = stats.late as f64 / 500.0;
        assert!(late_share < 0.05, "{stats:?}");
        let (_, wild) = simulate(
            300,
            FRAME,
            |i| Some(Duration::from_millis(((i * 7919) % 2000) as u64)),
            500,
        );
        assert!(wild.target_delay_ms <= 400.0 + 1e-9, "{wild:?}");
    }

    /// A drifting sender: `n` one-frame packets sent every `period` (19.8 ms: its clock is 1 %
    /// fast) over a link of `delay(i)`, pulled every 20 ms and each frame played told as loud
    /// (`loud(i)` for packet i's frame; concealment as loud as the frame before it).
    fn drifting(
        n: usize,
        period: Duration,
        delay: impl Fn(usize) -> Duration,
        loud: impl Fn(usize) -> bool,
    ) -> Drifted {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        let mut arrivals: Vec<(Instant, usize)> = (0..n)
            .map(|i| (t0 + period * i as u32 + delay(i), i))
            .collect();
        arrivals.sort();
        let mut run = Drifted::default();
        let mut a = 0;
        let mut last_loud = false;
        let pulls = (n as f64 * period.as_secs_f64() / 0.02) as usize + 50;
        for k in 0..pulls {
            let now = t0 + FRAME * k as u32;
            while a < arrivals.len() && arrivals[a].0 <= now {
                let i = arrivals[a].1;
                jb.insert(
                    i as u16,
                    i as u32 * 160,
                    i == 0,
                    &(i as u32).to_le_bytes(),
                    1,
                    arrivals[a].0,
                );
                a += 1;
            }
            let mut playout = jb.pop(now);
            loop {
                let (index, is_loud) = match &playout {
                    Playout::Packet(p) => {
                        let i = u32::from_le_bytes(p[..4].try_into().unwrap()) as usize;
                        (Some(i), loud(i))
                    }
                    Playout::Stretch => {
                        run.inserted_after_loud += u32::from(last_loud);
                        (None, last_loud)
                    }
                    Playout::Lost | Playout::NextFrame => (None, last_loud),
                    Playout::Silent | Playout::Pause => break,
                    Playout::Pieces(_) => unreachable!("one frame per packet"),
                };
                last_loud = is_loud;
                let loudness = if is_loud {
                    Loudness::Audible
                } else {
                    Loudness::Quiet
                };
                let correction = jb.played(loudness);
                if let Some(i) = index {
                    let latency = (now - (t0 + period * i as u32)).as_secs_f64();
                    if correction == Correction::Drop {
                        run.dropped.push(i);
                    } else {
                        run.played.push(i);
                        if now > t0 + Duration::from_secs(5) {
                            run.latency.0 = run.latency.0.min(latency);
                            run.latency.1 = run.latency.1.max(latency);
                        }
                    }
                }
                if correction != Correction::Drop {
                    break;
                }
                playout = jb.pop(now);
            }
        }
        run.stats = jb.stats();
        run
    }

    #[derive(Debug)]
    struct Drifted {
        /// Packet indices played and dropped, in order.
        played: Vec<usize>,
        dropped: Vec<usize>,
        /// Frames inserted right after a loud frame.
        inserted_after_loud: u32,
        /// The shortest and longest time from a packet's sending to its playout, after 5 s.
        latency: (f64, f64),
        stats: JitterStats,
    }

    impl Default for Drifted {
        fn default() -> Self {
            Self {
                played: Vec::new(),
                dropped: Vec::new(),
                inserted_after_loud: 0,
                latency: (f64::INFINITY, 0.0),
                stats: JitterStats::default(),
            }
        }
    }

    /// Speech-like loudness: talk of 1.2 to 2.9 s between pauses of 0.2 to 0.6 s (a fixed
    /// pseudo-random pattern); frame `i` is loud inside the talk.
    fn speech_with_pauses(i: usize) -> bool {
        let mut start = 0;
        for k in 0.. {
            let talk = 60 + (k * 37) % 86;
            let pause = 10 + (k * 13) % 21;
            if i < start + talk {
                return true;
            }
            if i < start + talk + pause {
                return false;
            }
            start += talk + pause;
        }
        unreachable!()
    }

    /// A few milliseconds of jitter.
    fn small_jitter(i: usize) -> Duration {
        Duration::from_micros(3000 + ((i * 7919) % 5000) as u64)
    }

    #[test]
    fn drift_is_corrected_inside_pauses_never_in_speech() {
        // 45 s of speech with pauses from a sender 1 % fast (packets every 19.8 ms) and 1 %
        // slow (20.2 ms): about 22 frames too many or too few. Each loud frame is played, once,
        // and nothing is inserted after one: every correction falls in a pause. (Before, the
        // buffer skipped 15 frames per 30 s wherever the delay happened to cross its limit,
        // mostly in speech.)
        let n = 2250;
        for (period, what) in [(19_800, "fast"), (20_200, "slow")] {
            let run = drifting(
                n,
                Duration::from_micros(period),
                small_jitter,
                speech_with_pauses,
            );
            let s = &run.stats;
            let what = format!("{what}: {s:?} latency {:?}", run.latency);
            // Every loud frame played, once, in order; what was not played was quiet.
            let loud: Vec<usize> = (0..n).filter(|&i| speech_with_pauses(i)).collect();
            let played_loud: Vec<usize> = run
                .played
                .iter()
                .copied()
                .filter(|&i| speech_with_pauses(i))
                .collect();
            let lost_loud: Vec<&usize> = loud.iter().filter(|i| !run.played.contains(i)).collect();
            assert!(
                lost_loud.is_empty(),
                "loud frames not played {lost_loud:?}; {what}"
            );
            assert_eq!(played_loud, loud, "{what}");
            assert!(
                run.dropped.iter().all(|&i| !speech_with_pauses(i)),
                "{what}"
            );
            assert_eq!(run.inserted_after_loud, 0, "{what}");
            assert_eq!((s.forced, s.late, s.lost), (0, 0, 0), "{what}");
            // The drift was measured, and corrected: the latency stays within two frames
            // and a half (the pauses come every 1.4 to 3.5 s; 1 % of that is up to 35 ms).
            assert!((s.drift_ppm.abs() - 10_000.0).abs() < 500.0, "{what}");
            let corrections = if period < 20_000 {
                s.dropped
            } else {
                s.stretched
            };
            assert!(corrections >= 18, "{what}");
            assert!(run.latency.1 - run.latency.0 < 0.05, "{what}");
            assert!(run.latency.1 < 0.1, "{what}");
            eprintln!("{what}");
        }
    }

    #[test]
    fn a_slight_drift_is_corrected_inside_pauses_too() {
        // 300 ppm, as between two sound cards' crystals (the PulseAudio null sink's against
        // the system clock measured about 200 ppm), over 4 minutes: 3.6 frames to insert or
        // drop, each in a pause, none forced in speech.
        for (period, what) in [(19_994, "fast"), (20_006, "slow")] {
            let run = drifting(
                12_000,
                Duration::from_micros(period),
                small_jitter,
                speech_with_pauses,
            );
            let s = &run.stats;
            let what = format!("{what}: {s:?} latency {:?}", run.latency);
            assert_eq!((s.forced, s.late, s.lost), (0, 0, 0), "{what}");
            assert_eq!(run.inserted_after_loud, 0, "{what}");
            assert!(
                run.dropped.iter().all(|&i| !speech_with_pauses(i)),
                "{what}"
            );
            assert!(s.stretched + s.dropped >= 2, "{what}");
            assert!(run.latency.1 < 0.1, "{what}");
        }
    }

    #[test]
    fn a_sound_that_never_pauses_is_corrected_only_at_the_limits() {
        // 1 % fast and slow again, loud throughout: no pause to hide a correction in. The
        // buffer waits as long as it can: against the slow sender it inserts a frame only when
        // a packet is about to be late (none is), against the fast one it skips a frame only
        // with 200 ms more delay than a pause would keep.
        for (period, what) in [(19_800, "fast"), (20_200, "slow")] {
            let run = drifting(1500, Duration::from_micros(period), small_jitter, |_| true);
            let s = &run.stats;
            let what = format!("{what}: {s:?} latency {:?}", run.latency);
            assert_eq!(s.forced, s.stretched + s.dropped, "{what}");
            assert_eq!((s.late, s.lost), (0, 0), "{what}");
            if period < 20_000 {
                assert!(s.dropped >= 3, "{what}");
                assert!(run.latency.1 < 0.35, "{what}");
            } else {
                assert!(s.stretched >= 10, "{what}");
                assert!(run.latency.1 < 0.1, "{what}");
            }
        }
    }

    #[test]
    fn end_hint_stops_exactly_and_start_hint_covers_a_lost_first_packet() {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        jb.hint_start(0);
        for i in 1..10u32 {
            jb.insert(i as u16, i * 160, false, &[i as u8], 1, t0 + FRAME * i);
        }
        jb.hint_end(10 * 160);
        let mut out = Vec::new();
        for k in 0..30 {
            out.push(jb.pop(t0 + FRAME * k));
        }
        let audible: Vec<_> = out.iter().filter(|p| **p != Playout::Silent).collect();
        assert_eq!(audible.len(), 10);
        assert_eq!(*audible[0], Playout::Lost);
        assert!(jb.ended());
    }

    #[test]
    fn multi_frame_packets_play_every_frame() {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        jb.insert(1, 0, true, &[1], 3, t0);
        jb.insert(2, 480, false, &[2], 3, t0 + FRAME * 3);
        let mut out = Vec::new();
        for k in 0..12 {
            out.push(jb.pop(t0 + FRAME * (2 + k)));
        }
        let kinds: Vec<_> = out
            .iter()
            .filter(|p| **p != Playout::Silent)
            .take(6)
            .map(|p| match p {
                Playout::Packet(v) => v[0],
                Playout::NextFrame => 0,
                _ => 9,
            })
            .collect();
        assert_eq!(kinds, vec![1, 0, 0, 2, 0, 0]);
    }

    /// The same as `simulate` on an RTP clock of `clock` Hz, with each packet's payload type
    /// and duration, so that streams of any codec can be compared.
    fn simulate_at(
        clock: u32,
        n: usize,
        send_period: Duration,
        delay: impl Fn(usize) -> Option<Duration>,
        pulls: usize,
    ) -> (Vec<Playout>, JitterStats) {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::with_clock(JitterConfig::default(), t0, clock);
        let step = clock / 50;
        let mut arrivals: Vec<(Instant, usize)> = (0..n)
            .filter_map(|i| delay(i).map(|d| (t0 + send_period * i as u32 + d, i)))
            .collect();
        arrivals.sort();
        let mut out = Vec::new();
        let mut a = 0;
        for k in 0..pulls {
            let now = t0 + FRAME * k as u32;
            while a < arrivals.len() && arrivals[a].0 <= now {
                let i = arrivals[a].1;
                jb.file(Arrival {
                    sequence: 1000u16.wrapping_add(i as u16),
                    timestamp: (i as u32)
                        .wrapping_mul(step)
                        .wrapping_add(u32::MAX - 30 * step),
                    marker: i == 0,
                    payload_type: 96,
                    payload: &[i as u8],
                    duration: step,
                    on_grid: false,
                    at: arrivals[a].0,
                });
                a += 1;
            }
            out.push(jb.pop(now));
        }
        (out, jb.stats())
    }

    /// Playout decisions without the payload type, which differs between the clocks.
    fn decisions(out: &[Playout]) -> Vec<(char, u8)> {
        out.iter()
            .map(|p| match p {
                Playout::Packet(piece) => ('P', piece[0]),
                Playout::Pieces(_) => ('M', 0),
                Playout::NextFrame => ('N', 0),
                Playout::Lost => ('L', 0),
                Playout::Stretch => ('S', 0),
                Playout::Silent => ('-', 0),
                Playout::Pause => ('_', 0),
            })
            .collect()
    }

    #[test]
    fn a_48k_clock_plays_exactly_as_8k() {
        // Steady, lossy with a late packet, jittery, and drifting both ways: Opus's 960 ticks
        // per frame give the same decisions as Speex's 160.
        let lossy = |i: usize| match i {
            _ if i % 10 == 5 => None,
            50 => Some(Duration::from_millis(300)),
            _ => Some(Duration::from_millis(2)),
        };
        let jittery = |i: usize| Some(Duration::from_millis(((i * 37) % 61) as u64));
        type Delay<'a> = &'a dyn Fn(usize) -> Option<Duration>;
        let cases: [(usize, Duration, Delay, usize); 5] = [
            (100, FRAME, &|_| Some(Duration::from_millis(5)), 200),
            (200, FRAME, &lossy, 260),
            (500, FRAME, &jittery, 560),
            (
                1500,
                Duration::from_micros(19_800),
                &|_| Some(FRAME / 4),
                1500,
            ),
            (
                1500,
                Duration::from_micros(20_200),
                &|_| Some(FRAME / 4),
                1550,
            ),
        ];
        for (n, period, delay, pulls) in cases {
            let (a, sa) = simulate_at(8000, n, period, delay, pulls);
            let (b, sb) = simulate_at(48_000, n, period, delay, pulls);
            assert_eq!(decisions(&a), decisions(&b));
            assert_eq!(
                (sa.played, sa.lost, sa.late, sa.stretched, sa.dropped),
                (sb.played, sb.lost, sb.late, sb.stretched, sb.dropped)
            );
            assert!((sa.jitter_ms - sb.jitter_ms).abs() < 0.01, "{sa:?} {sb:?}");
            assert!((sa.target_delay_ms - sb.target_delay_ms).abs() < 1e-6);
        }
        // And at 48 kHz on its own, the steady stream is played whole, after the initial delay.
        let (out, stats) = simulate_at(48_000, 100, FRAME, |_| Some(Duration::from_millis(5)), 200);
        assert_eq!(played(&out), (0..100).map(|i| i as u8).collect::<Vec<_>>());
        assert_eq!(stats.stretched + stats.dropped, 0);
        let mut jb = JitterBuffer::with_clock(JitterConfig::default(), Instant::now(), 48_000);
        assert_eq!(jb.report(), None);
        assert_eq!(jb.clock(), 48_000);
    }

    /// Files packets of `sizes` ticks back to back (sent in real time), pulls every 20 ms, and
    /// returns what was played.
    fn play_sizes(clock: u32, sizes: &[u32], pulls: u32) -> (Vec<Playout>, JitterStats) {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::with_clock(JitterConfig::default(), t0, clock);
        let mut at = 0u32;
        let mut sent = Vec::new();
        for (i, &size) in sizes.iter().enumerate() {
            let when = t0 + Duration::from_secs_f64(f64::from(at) / f64::from(clock));
            sent.push((when, i as u16, at, size));
            at += size;
        }
        let mut out = Vec::new();
        let mut s = 0;
        for k in 0..pulls {
            let now = t0 + FRAME * k;
            while s < sent.len() && sent[s].0 <= now {
                let (when, seq, ts, size) = sent[s];
                jb.file(Arrival {
                    sequence: seq,
                    timestamp: ts,
                    marker: seq == 0,
                    payload_type: 0,
                    payload: &[seq as u8],
                    duration: size,
                    on_grid: false,
                    at: when,
                });
                s += 1;
            }
            out.push(jb.pop(now));
        }
        (out, jb.stats())
    }

    #[test]
    fn packets_shorter_than_a_frame_come_together() {
        // Opus at 10 ms: two packets per frame, the second half a frame in.
        let (out, stats) = play_sizes(48_000, &[480; 40], 40);
        let pieces: Vec<&Vec<Piece>> = out
            .iter()
            .filter_map(|p| match p {
                Playout::Pieces(v) => Some(v),
                _ => None,
            })
            .collect();
        assert_eq!(pieces.len(), 20, "{out:?}");
        for (k, v) in pieces.iter().enumerate() {
            assert_eq!(v.len(), 2);
            assert_eq!((v[0].offset, v[1].offset), (0, 480));
            assert_eq!((v[0][0], v[1][0]), (2 * k as u8, 2 * k as u8 + 1));
        }
        assert_eq!(stats.played, 20);
        // Only the tail after the stream is concealed.
        let last = out
            .iter()
            .rposition(|p| matches!(p, Playout::Pieces(_)))
            .unwrap();
        assert!(out[..last].iter().all(|p| *p != Playout::Lost));
    }

    #[test]
    fn packets_off_the_grid_carry_their_offset() {
        // GStreamer's default PCMU packetisation: 1388 and 660 samples, taking turns.
        let sizes: Vec<u32> = (0..21)
            .map(|i| if i % 2 == 0 { 1388 } else { 660 })
            .collect();
        let total: u32 = sizes.iter().sum();
        let (out, stats) = play_sizes(8000, &sizes, total / 160 + 40);
        let mut start = 0u32;
        let mut starts = Vec::new();
        for &s in &sizes {
            starts.push(start);
            start += s;
        }
        // Every packet is handed out once, in the slot its start falls in, at its offset.
        let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
        let mut seen = 0;
        for (k, p) in out.iter().enumerate() {
            if let Playout::Packet(piece) = p {
                let slot = (k - first) as u32;
                let at = starts[usize::from(piece[0])];
                assert_eq!(slot, at / 160, "{out:?}");
                assert_eq!(piece.offset, at % 160);
                seen += 1;
            }
        }
        assert_eq!(seen, sizes.len());
        // Played without a gap, every frame of the stream (the packets' later frames as
        // NextFrame), then only the concealed tail after it.
        let last = out
            .iter()
            .rposition(|p| matches!(p, Playout::Packet(_) | Playout::NextFrame))
            .unwrap();
        assert!(
            out[first..=last]
                .iter()
                .all(|p| matches!(p, Playout::Packet(_) | Playout::NextFrame))
        );
        assert_eq!((last + 1 - first) as u32, total.div_ceil(160));
        assert_eq!(stats.played as u32, total.div_ceil(160));
    }

    #[test]
    fn whole_frames_off_the_grid_are_rounded_onto_it() {
        // GStreamer's Speex: the first packet's timestamp says it lasts 120 ticks, the rest
        // follow every 160 from there.
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        for i in 0..30u32 {
            let ts = if i == 0 { 0 } else { 120 + (i - 1) * 160 };
            jb.insert(i as u16, ts, i == 0, &[i as u8], 1, t0 + FRAME * i);
        }
        let mut out = Vec::new();
        for k in 0..40 {
            out.push(jb.pop(t0 + FRAME * k));
        }
        assert_eq!(played(&out), (0..30).collect::<Vec<u8>>());
        let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
        assert!(
            out[first..first + 30]
                .iter()
                .all(|p| matches!(p, Playout::Packet(piece) if piece.offset == 0))
        );
    }

    #[test]
    fn a_stream_off_the_grid_keeps_its_delay() {
        // GStreamer's Opus: the first packet stamped 648 ticks long, the rest 960 apart, so
        // every later packet starts 13.5 ms into its slot. Its deadline is still the slot's
        // start: the buffer must not take the 13.5 ms for spare delay and skip frames.
        let t0 = Instant::now();
        let mut jb = JitterBuffer::with_clock(JitterConfig::default(), t0, 48_000);
        let n = 500u32;
        let mut out = Vec::new();
        let mut sent = 0u32;
        for k in 0..n + 20 {
            // The output clock ticks 9 ms after the packets: playout starts at 49 ms of delay.
            let now = t0 + FRAME * k + Duration::from_millis(9);
            while sent < n {
                let ts = if sent == 0 { 0 } else { 648 + (sent - 1) * 960 };
                // Sent at its timestamp, as GStreamer does from a file, 0..6 ms of network
                // jitter on top.
                let at = t0
                    + Duration::from_secs_f64(f64::from(ts) / 48_000.0)
                    + Duration::from_millis(u64::from(sent * 37 % 7));
                if at > now {
                    break;
                }
                jb.file(Arrival {
                    sequence: sent as u16,
                    timestamp: ts,
                    marker: sent == 0,
                    payload_type: 96,
                    payload: &[sent as u8],
                    duration: 960,
                    on_grid: false,
                    at,
                });
                sent += 1;
            }
            out.push(jb.pop(now));
        }
        let s = jb.stats();
        assert_eq!((s.dropped, s.stretched, s.late), (0, 0, 0), "{s:?}");
        let last = out
            .iter()
            .rposition(|p| matches!(p, Playout::Packet(_)))
            .unwrap();
        let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
        assert!(
            out[first..=last]
                .iter()
                .all(|p| matches!(p, Playout::Packet(_) | Playout::Pieces(_)))
        );
    }

    #[test]
    fn the_packet_after_a_loss_is_offered_for_fec() {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::with_clock(JitterConfig::default(), t0, 48_000);
        for i in [0u32, 1, 3, 4] {
            jb.file(Arrival {
                sequence: i as u16,
                timestamp: i * 960,
                marker: i == 0,
                payload_type: 96,
                payload: &[i as u8],
                duration: 960,
                on_grid: false,
                at: t0,
            });
        }
        let mut seen = Vec::new();
        for k in 0..6 {
            match jb.pop(t0 + FRAME * (2 + k)) {
                Playout::Lost => seen.push(jb.upcoming().map(|(pt, p)| (pt, p[0]))),
                Playout::Packet(p) => assert_eq!(p.payload_type, 96),
                _ => {}
            }
        }
        assert_eq!(seen[0], Some((96, 3)));
    }

    #[test]
    fn a_clock_change_restarts_the_stream_and_keeps_an_early_start_hint() {
        let t0 = Instant::now();
        // The sender's first report comes before its first packet, on the buffer's old clock.
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        jb.hint_start(5000);
        jb.set_clock(48_000);
        for i in 1..10u32 {
            jb.file(Arrival {
                sequence: i as u16,
                timestamp: 5000 + i * 960,
                marker: false,
                payload_type: 96,
                payload: &[i as u8],
                duration: 960,
                on_grid: false,
                at: t0 + FRAME * i,
            });
        }
        let mut out = Vec::new();
        for k in 0..8 {
            out.push(jb.pop(t0 + FRAME * k));
        }
        // The first packet was lost; the hint makes its frame concealed rather than skipped.
        let audible: Vec<_> = out.iter().filter(|p| **p != Playout::Silent).collect();
        assert_eq!(*audible[0], Playout::Lost);
        // Mid-stream the codec switches to one on the 8 kHz clock: buffered packets are flushed
        // and the new stream plays from its own start.
        jb.set_clock(8000);
        assert!(jb.stats().flushed > 0);
        let t1 = t0 + FRAME * 8;
        for i in 0..20u32 {
            jb.file(Arrival {
                sequence: 20 + i as u16,
                timestamp: 777 + i * 160,
                marker: i == 0,
                payload_type: 0,
                payload: &[100 + i as u8],
                duration: 160,
                on_grid: true,
                at: t1 + FRAME * i,
            });
        }
        let mut got = Vec::new();
        for k in 0..40 {
            if let Playout::Packet(p) = jb.pop(t1 + FRAME * k) {
                got.push(p[0]);
            }
        }
        assert_eq!(got, (100..120).collect::<Vec<u8>>());
    }

    #[test]
    fn sequence_and_timestamp_wrap() {
        assert_eq!(extend(65535, 0, 16), 65536);
        assert_eq!(extend(65536, 65535, 16), 65535);
        assert_eq!(extend(i64::from(u32::MAX), 5, 32), i64::from(u32::MAX) + 6);
    }

    /// A packet as sent: when (seconds from the start), sequence number, timestamp, marker.
    #[derive(Clone, Copy)]
    struct Sent {
        at: f64,
        seq: u16,
        ts: u32,
        marker: bool,
    }

    /// Sends `packets` over a link of constant `delay` to a Speex buffer (whole frames, 8 kHz)
    /// pulled every 20 ms from `phase` on, `pulls` times; packet payloads are their index.
    /// `before_pull(k, jb)` runs before pull k (to give hints).
    fn link(
        packets: &[Sent],
        delay: Duration,
        phase: Duration,
        pulls: u32,
        mut before_pull: impl FnMut(u32, &mut JitterBuffer),
    ) -> (Vec<Playout>, JitterStats) {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        let mut out = Vec::new();
        let mut next = 0;
        for k in 0..pulls {
            let now = t0 + phase + FRAME * k;
            while let Some(p) = packets.get(next) {
                let at = t0 + Duration::from_secs_f64(p.at) + delay;
                if at > now {
                    break;
                }
                jb.file(Arrival {
                    sequence: p.seq,
                    timestamp: p.ts,
                    marker: p.marker,
                    payload_type: 110,
                    payload: &(next as u32).to_le_bytes(),
                    duration: 160,
                    on_grid: true,
                    at,
                });
                next += 1;
            }
            before_pull(k, &mut jb);
            let mut playout = jb.pop(now);
            // Ten quiet frames a second (packets 40 to 49 of every 50): the buffer may correct
            // its delay in them (a dropped frame is replaced by the next, as the receiver does).
            if let Playout::Packet(p) = &playout {
                let quiet = u32::from_le_bytes(p[..4].try_into().unwrap()) % 50 >= 40;
                let loudness = if quiet {
                    Loudness::Quiet
                } else {
                    Loudness::Audible
                };
                if jb.played(loudness) == Correction::Drop {
                    playout = jb.pop(now);
                }
            }
            out.push(playout);
        }
        (out, jb.stats())
    }

    /// The packet indices handed out, in order.
    fn indices(out: &[Playout]) -> Vec<u32> {
        out.iter()
            .filter_map(|p| match p {
                Playout::Packet(v) => Some(u32::from_le_bytes(v[..4].try_into().unwrap())),
                _ => None,
            })
            .collect()
    }

    /// `n` packets of one frame each, sent in real time, starting at `seq` and `ts`; GStreamer's
    /// `rtpspeexpay` stamps its first packet 120 ticks long (`first_step`).
    fn stream(n: u32, seq: u16, ts: u32, first_step: u32, from: f64) -> Vec<Sent> {
        (0..n)
            .map(|i| {
                let tick = if i == 0 {
                    0
                } else {
                    first_step + (i - 1) * 160
                };
                Sent {
                    at: from + f64::from(tick) / 8000.0,
                    seq: seq.wrapping_add(i as u16),
                    ts: ts.wrapping_add(tick),
                    marker: i == 0,
                }
            })
            .collect()
    }

    #[test]
    fn a_jitter_free_stream_plays_every_frame_whatever_the_tick_phase() {
        // GStreamer's Speex (first step 120) and lipcall's own (160), 20 s each, against every
        // phase of the output clock: every frame played once, in order, none skipped, none
        // claimed lost. (Skipping used to take the start-up delay for spare: a frame of speech
        // was dropped about 1 s in, in most phases.)
        for first_step in [120, 160] {
            for phase_ms in 0..20 {
                let packets = stream(1000, 65_000, 4_000_000_000, first_step, 0.0);
                let (out, stats) = link(
                    &packets,
                    Duration::from_micros(700),
                    Duration::from_millis(phase_ms),
                    1040,
                    |_, _| {},
                );
                let what = format!("step {first_step}, phase {phase_ms} ms: {stats:?}");
                assert!(indices(&out) == (0..1000).collect::<Vec<_>>(), "{what}");
                assert_eq!(
                    (stats.dropped, stats.stretched, stats.late),
                    (0, 0, 0),
                    "{what}"
                );
                assert_eq!(stats.lost, 0, "{what}");
                // Only the frame after the end is concealed: nothing more came.
                assert!(stats.missing <= 1, "{what}");
                let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
                assert!(
                    out[first..first + 1000]
                        .iter()
                        .all(|p| matches!(p, Playout::Packet(piece) if piece.offset == 0)),
                    "{what}"
                );
            }
        }
    }

    /// A sender that stops between talk spurts: `spurts` of (frames, gap frames after), the
    /// timestamp moving on over each gap, sequence numbers consecutive, a marker on each
    /// spurt's first packet.
    fn talk_spurts(spurts: &[(u32, u32)]) -> Vec<Sent> {
        let mut out = Vec::new();
        let mut frame = 0u32;
        let mut seq = 30_000u16;
        for &(len, gap) in spurts {
            for i in 0..len {
                out.push(Sent {
                    at: f64::from(frame) * 0.02,
                    seq,
                    ts: 1000 + frame * 160,
                    marker: i == 0,
                });
                seq = seq.wrapping_add(1);
                frame += 1;
            }
            frame += gap;
        }
        out
    }

    #[test]
    fn silence_between_talk_spurts_is_no_loss() {
        // 525 frames of speech in spurts with gaps of 20 ms to 1 s (the sender's VAD), on a
        // jitter-free link: nothing is lost, every frame plays, a gap is silence. Only where
        // nothing at all is buffered (the gap's start) is one frame concealed, since a packet
        // could still be on its way.
        let spurts = [
            (40, 1),
            (30, 2),
            (25, 5),
            (50, 14),
            (35, 9),
            (60, 40),
            (45, 3),
            (80, 20),
            (70, 50),
            (90, 7),
        ];
        let total: u32 = spurts.iter().map(|s| s.0).sum();
        assert_eq!(total, 525);
        let packets = talk_spurts(&spurts);
        let frames: u32 = spurts.iter().map(|s| s.0 + s.1).sum();
        let (out, stats) = link(
            &packets,
            Duration::from_millis(1),
            Duration::from_millis(7),
            frames + 40,
            |_, _| {},
        );
        assert_eq!(indices(&out), (0..total).collect::<Vec<_>>(), "{stats:?}");
        assert_eq!(stats.lost, 0, "{stats:?}");
        assert_eq!((stats.dropped, stats.late), (0, 0), "{stats:?}");
        assert!(stats.missing <= spurts.len() as u64, "{stats:?}");
        // Gaps of one or two frames: the next spurt's first packet is already buffered and
        // follows in sequence, so nothing at all is concealed there.
        let kinds: Vec<char> = out
            .iter()
            .map(|p| match p {
                Playout::Packet(_) => 'P',
                Playout::Lost => 'L',
                Playout::Pause => '_',
                _ => ' ',
            })
            .collect::<Vec<_>>();
        let text: String = kinds.iter().collect();
        let start = text.find('P').unwrap();
        assert!(text[start..].starts_with(&format!("{}_{}", "P".repeat(40), "P".repeat(30))));
        // Real loss inside spurts is still loss: every 10th packet dropped.
        let lossy: Vec<Sent> = packets
            .iter()
            .enumerate()
            .filter(|(i, _)| i % 10 != 5)
            .map(|(_, p)| *p)
            .collect();
        let (out, stats) = link(
            &lossy,
            Duration::from_millis(1),
            Duration::from_millis(7),
            frames + 40,
            |_, _| {},
        );
        assert_eq!(stats.lost, 52, "{stats:?}");
        assert_eq!(indices(&out).len(), lossy.len());
        assert!(stats.missing >= 52 && stats.missing <= 52 + spurts.len() as u64);
    }

    #[test]
    fn holes_are_concealed_while_packets_are_still_due() {
        // The last two packets are lost but the sender's BYE said where the stream ends: both
        // frames are concealed (with nothing buffered, a frame past the hold used to pause).
        let mut packets = stream(150, 7, 0, 160, 0.0);
        packets.truncate(148);
        let (out, stats) = link(
            &packets,
            Duration::from_millis(1),
            Duration::from_millis(5),
            200,
            |k, jb| {
                if k == 140 {
                    jb.hint_end(150 * 160);
                }
            },
        );
        let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
        assert!(
            out[first..first + 148]
                .iter()
                .all(|p| matches!(p, Playout::Packet(_)))
        );
        assert_eq!(
            out[first + 148..first + 150],
            [Playout::Lost, Playout::Lost],
            "{stats:?}"
        );
        assert!(out[first + 150..].iter().all(|p| *p == Playout::Silent));
        // A stall: the packets sent from 2 s on are held and come all at once at 2.42 s, with
        // the one sent then. Before they come, the hole looks like a pause; once late ones
        // have come the sender has clearly not paused: the frames are concealed, not silent.
        let mut stalled = stream(200, 7, 0, 160, 0.0);
        for p in &mut stalled[100..=121] {
            p.at = 2.42;
        }
        let (out, stats) = link(
            &stalled,
            Duration::from_millis(1),
            Duration::from_millis(5),
            260,
            |_, _| {},
        );
        // Pulls from tick 122 on see the burst.
        assert!(
            out[122..195]
                .iter()
                .all(|p| !matches!(p, Playout::Pause | Playout::Silent)),
            "{stats:?}"
        );
        assert!(stats.late > 0);
    }

    #[test]
    fn a_stream_after_bye_on_the_same_ssrc_plays() {
        // A call ends with BYE (its end marked by the last SR, or not), and the same SSRC calls
        // again: new sequence numbers and timestamps, a second later or right away (its first
        // packet comes while the old stream's last frame is still to play). Both play whole;
        // the second is a new stream.
        for (with_end, again) in [(true, 3.0), (false, 3.0), (true, 2.0), (false, 2.0)] {
            let mut packets = stream(100, 500, 90_000, 160, 0.0);
            packets.extend(stream(100, 41_000, 7_000_000, 160, again));
            let (out, stats) = link(
                &packets,
                Duration::from_millis(1),
                Duration::ZERO,
                260,
                |k, jb| {
                    if k == 100 {
                        if with_end {
                            jb.hint_end(90_000 + 100 * 160);
                        } else {
                            jb.bye();
                        }
                    }
                    if k == 140 {
                        // The redial's first SR, before its first packet: no use on the old
                        // stream's timeline.
                        jb.hint_start(7_000_000);
                    }
                },
            );
            let what = format!("end {with_end}, again at {again} s: {stats:?}");
            assert_eq!(indices(&out), (0..200).collect::<Vec<_>>(), "{what}");
            assert_eq!(
                (stats.restarts, stats.lost, stats.late),
                (1, 0, 0),
                "{what}"
            );
            assert_eq!((stats.received, stats.flushed), (200, 0), "{what}");
        }
    }

    #[test]
    fn timestamp_jumps_start_a_new_talk_spurt_not_late_packets() {
        // The sequence goes on while the timestamps jump back 5 s, or ahead 10 s (a sender
        // that restarted its clock): every packet still plays, continuously.
        for jump in [-40_000i64, 80_000] {
            let mut packets = stream(100, 100, 1_000_000, 160, 0.0);
            let more = stream(100, 200, (1_000_000 + 100 * 160 + jump) as u32, 160, 2.0);
            packets.extend(more.into_iter().map(|p| Sent { marker: false, ..p }));
            let (out, stats) = link(
                &packets,
                Duration::from_millis(1),
                Duration::from_millis(3),
                240,
                |_, _| {},
            );
            assert_eq!(
                indices(&out),
                (0..200).collect::<Vec<_>>(),
                "jump {jump}: {stats:?}"
            );
            assert_eq!(
                (stats.late, stats.lost, stats.rebased),
                (0, 0, 1),
                "{stats:?}"
            );
            let first = out.iter().position(|p| *p != Playout::Silent).unwrap();
            assert!(
                out[first..first + 200]
                    .iter()
                    .all(|p| matches!(p, Playout::Packet(_))),
                "jump {jump}"
            );
        }
        // A straggler from before the jump back, arriving after it, is dropped as late and
        // does not disturb the stream.
        let mut packets = stream(100, 100, 1_000_000, 160, 0.0);
        packets.extend(stream(100, 200, 900_000, 160, 2.0));
        packets.insert(
            150,
            Sent {
                at: 2.9,
                seq: 198,
                ts: 1_000_000 + 98 * 160,
                marker: false,
            },
        );
        let (out, stats) = link(
            &packets,
            Duration::from_millis(1),
            Duration::from_millis(3),
            240,
            |_, _| {},
        );
        let played = indices(&out);
        assert_eq!(played.len(), 200, "{stats:?}");
        assert!(!played.contains(&150));
        assert_eq!(stats.duplicates + stats.late, 1, "{stats:?}");
    }

    #[test]
    fn a_talk_spurt_whose_timestamps_did_not_move_on_plays() {
        // A sender that pauses 1 s without advancing its timestamps: the next spurt (marker
        // bit) continues the old timestamps and looks 1 s late. It starts a new talk spurt.
        let mut packets = stream(100, 100, 1_000_000, 160, 0.0);
        packets.extend(stream(100, 200, 1_000_000 + 100 * 160, 160, 3.0));
        let (out, stats) = link(
            &packets,
            Duration::from_millis(1),
            Duration::from_millis(3),
            300,
            |_, _| {},
        );
        assert_eq!(indices(&out), (0..200).collect::<Vec<_>>(), "{stats:?}");
        assert_eq!(
            (stats.late, stats.lost, stats.rebased),
            (0, 0, 1),
            "{stats:?}"
        );
    }

    #[test]
    fn a_new_sequence_without_bye_is_a_new_stream() {
        // The same SSRC restarts with new sequence numbers and timestamps and says nothing: the
        // far sequence number waits for its successor (RFC 3550 A.1), then the new stream plays.
        let mut packets = stream(100, 100, 1_000_000, 160, 0.0);
        packets.extend(stream(100, 30_000, 50_000, 160, 2.5));
        let (out, stats) = link(
            &packets,
            Duration::from_millis(1),
            Duration::from_millis(3),
            240,
            |_, _| {},
        );
        let played = indices(&out);
        assert_eq!(played[..100], (0..100).collect::<Vec<_>>()[..]);
        assert_eq!(
            played[100..],
            (101..200).collect::<Vec<_>>()[..],
            "{stats:?}"
        );
        assert_eq!((stats.restarts, stats.probation, stats.lost), (1, 1, 0));
    }
}

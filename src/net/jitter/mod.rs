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
//! Starts, stalls and a busy machine. A stream that stalls with nothing buffered in the first
//! frames of a talk spurt is waited for (a subscription whose first packet came through ahead
//! of the rest), and packets that come after a stall, following the last one played, resume
//! the stream from where it stopped instead of being dropped as late; a lone stall's packets
//! are left out of the spread (spikes count only when they repeat, `estimator`) and the delay
//! it added is shed in the next pauses. A packet filed before
//! its slot is pulled came in time even when stamped after the slot's tick (a puller held up
//! by a busy machine): it asks for delay in a pause, never a frame inserted in speech. Drift
//! comes from a robust fit that leaves a stall's blocks out (`trend`).
//!
//! New streams on the same SSRC. After BYE, a packet that is not a straggler of the old stream
//! starts a new one (a redial with the same SSRC): sequence state starts over and the packet is
//! placed where it arrives, after what of the old stream is still to play. Without
//! BYE, a sequence number far from the last (RFC 3550 A.1: two in a row confirm it) starts a new
//! stream too, and a timestamp that jumps against the sequence (backwards, or ahead of the time
//! that passed by more than the largest delay) re-anchors the timeline where the packet's
//! arrival puts it: a new talk spurt rather than a stream of late packets.

mod arrival;
mod corrector;
mod estimator;
mod packets;
mod stats;
mod timeline;
mod trend;

#[cfg(test)]
mod load_tests;
#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::time::Instant;

use corrector::{Adjust, Corrector};
use estimator::DelayEstimator;
use packets::FRAME_SECONDS;
pub use packets::{Arrival, Correction, JitterConfig, Loudness, Piece, Playout};
use stats::Interarrival;
pub use stats::JitterStats;
use timeline::{Sequence, Timeline};

/// The clock of a buffer until told otherwise (Speex, G.711).
pub const DEFAULT_CLOCK: u32 = 8000;
/// A packet lasts at most this many frames (longer claims are cut).
const MAX_PACKET_FRAMES: u32 = 64;
/// Frames at the start of a talk spurt in which a stream that stalls with nothing buffered is
/// waited for rather than concealed: its next packets are held up (a subscription or a
/// re-join whose first packet came through ahead of the rest), not lost.
const START_FRAMES: u32 = 4;
/// The most frames a start waits for in all.
const START_WAIT: u32 = 20;
/// A packet this much later (seconds) than its timestamp's step from the newest before it
/// says was held up before it reached us: counted and logged (kernel-stamped arrivals: our own
/// thread's starvation does not show).
pub const HELD_UPSTREAM: f64 = 0.25;

#[derive(Debug)]
struct Entry {
    payload: Vec<u8>,
    payload_type: u8,
    duration: u32,
    /// Extended sequence number.
    seq: i64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Playing,
    Ended,
}

#[derive(Debug)]
pub struct JitterBuffer {
    config: JitterConfig,
    epoch: Instant,
    state: State,
    timeline: Timeline,
    sequence: Sequence,
    delay: DelayEstimator,
    corrector: Corrector,
    interarrival: Interarrival,
    /// Packets by their first tick, counted from the timeline's origin.
    entries: BTreeMap<i64, Entry>,
    /// Next slot to play.
    next: i64,
    /// The tick up to which the packets handed out so far reach.
    covered: i64,
    /// Output time at which slot `play_ref.0` is (or was) played.
    play_ref: (i64, f64),
    /// The latest arrival filed (seconds): a pull that finds the packet cannot have come
    /// before it, whatever time it was asked for (a pulling thread starved behind its ticks).
    latest_arrival: f64,
    empty_since: Option<f64>,
    /// Where the sender said its stream starts and ends, in ticks from the origin.
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
    /// Frames handed out since the talk spurt started, and frames waited for in it.
    spurt_frames: u32,
    start_waits: u32,
    /// The sender said BYE (a packet not continuing its stream starts a new one).
    ending: bool,
    stats: JitterStats,
}

impl JitterBuffer {
    /// A buffer for a stream on the 8 kHz clock.
    pub fn new(config: JitterConfig, epoch: Instant) -> Self {
        Self::with_clock(config, epoch, DEFAULT_CLOCK)
    }

    /// A buffer for a stream whose RTP clock runs at `clock` Hz (at least 50).
    pub fn with_clock(config: JitterConfig, epoch: Instant, clock: u32) -> Self {
        Self {
            config,
            epoch,
            state: State::Idle,
            timeline: Timeline::new(clock),
            sequence: Sequence::default(),
            delay: DelayEstimator::new(config),
            corrector: Corrector::new(&config),
            interarrival: Interarrival::default(),
            entries: BTreeMap::new(),
            next: 0,
            covered: 0,
            play_ref: (0, 0.0),
            latest_arrival: f64::NEG_INFINITY,
            empty_since: None,
            start_hint: None,
            end_hint: None,
            anchor_next: false,
            stream_played: false,
            newest: None,
            last_out_seq: None,
            holes: 0,
            spurt_frames: 0,
            start_waits: 0,
            ending: false,
            stats: JitterStats::default(),
        }
    }

    pub fn clock(&self) -> u32 {
        self.timeline.clock
    }

    /// The stream's clock rate changed (a codec switch, from Speex to Opus say). Before any
    /// packet only the rate changes (the hints an early sender report gave stay). After, the
    /// old timestamps say nothing on the new clock: the buffer starts over as for a new
    /// stream, its packets flushed; sequence numbers and counters carry on.
    pub fn set_clock(&mut self, clock: u32) {
        if !self.timeline.set_clock(clock) || self.stats.received == 0 {
            return;
        }
        self.reset_timing();
    }

    /// Forgets the timeline (packets buffered are flushed): the next packet starts it anew.
    fn reset_timing(&mut self) {
        self.stats.flushed += self.entries.len() as u64;
        self.entries.clear();
        self.timeline.reset();
        if self.state != State::Idle {
            self.state = State::Idle;
        }
        self.next = 0;
        self.covered = 0;
        self.delay.reset();
        self.corrector.forget_slack();
        self.empty_since = None;
        self.start_hint = None;
        self.end_hint = None;
        self.interarrival.reset();
        self.newest = None;
        self.holes = 0;
        self.stream_played = false;
    }

    fn seconds(&self, t: Instant) -> f64 {
        t.saturating_duration_since(self.epoch).as_secs_f64()
    }

    /// The output time at which slot `index` is played, by the playout reference: the
    /// deadline of every packet starting in it, wherever in it the packet starts.
    fn slot_time(&self, index: i64) -> f64 {
        let (ref_index, ref_time) = self.play_ref;
        ref_time + (index - ref_index) as f64 * FRAME_SECONDS
    }

    /// The sender said where its stream starts (an SR sent before its first packet).
    pub fn hint_start(&mut self, ts: u32) {
        // (One announced while the last stream is ending says nothing on its timeline.)
        if !self.ending && self.state != State::Ended && !self.stream_played {
            let (off, _) = self.timeline.offset_of(ts);
            self.start_hint = Some(off);
        }
    }

    /// The sender said where its stream ends (the SR sent with its BYE): play up to there.
    pub fn hint_end(&mut self, ts: u32) {
        let (off, _) = self.timeline.offset_of(ts);
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
        now - self.timeline.seconds(index * self.timeline.step) - self.delay.base()
    }

    /// The packet starting the slot to be played next, if it is already here: after a `Lost`,
    /// the packet that follows the lost frame (Opus carries FEC for it). With its payload type.
    pub fn upcoming(&self) -> Option<(u8, &[u8])> {
        let lo = self.next * self.timeline.step;
        let tolerance = self.timeline.tolerance;
        self.entries
            .range(lo - tolerance..=lo + tolerance)
            .next()
            .map(|(_, e)| (e.payload_type, e.payload.as_slice()))
    }

    /// Whether a packet starts in slot `index`.
    fn has_slot(&self, index: i64) -> bool {
        slot_filled(&self.entries, &self.timeline, index)
    }

    /// What to play for the 20 ms of output starting at `now` (on the output clock).
    pub fn pop(&mut self, now: Instant) -> Playout {
        let out = self.pop_at(self.seconds(now));
        if tracing::enabled!(tracing::Level::TRACE) {
            let kind = match &out {
                Playout::Packet(_) | Playout::Pieces(_) => "audio",
                Playout::NextFrame => "next",
                Playout::Lost => "lost",
                Playout::Pause => "pause",
                Playout::Stretch => "stretch",
                Playout::Silent => "silent",
            };
            tracing::trace!(
                at = self.seconds(now),
                next = self.next,
                kind,
                base = self.delay.base(),
                target = self.delay.target(),
                "jitter pop"
            );
        }
        out
    }

    fn pop_at(&mut self, now: f64) -> Playout {
        self.delay.note_pull(now);
        self.corrector.begin_pop();
        match self.state {
            State::Ended => return Playout::Silent,
            State::Idle => {
                let Some((&first, _)) = self.entries.first_key_value() else {
                    return self.check_end(Playout::Silent);
                };
                let first = self.timeline.slot_of(first);
                let start = match self.start_hint.map(|h| self.timeline.slot_of(h)) {
                    Some(h) if h <= first && first - h <= 10 => h,
                    _ => first,
                };
                if self.delay_at(now, start) < self.delay.target() - 0.5 * FRAME_SECONDS {
                    return Playout::Silent;
                }
                let above = self.delay_at(now, start) - self.delay.target();
                self.corrector.start(self.delay.base(), above);
                self.start_hint = None;
                self.state = State::Playing;
                self.next = start;
                self.covered = start * self.timeline.step;
                self.empty_since = None;
                self.holes = 0;
                self.spurt_frames = 0;
                self.start_waits = 0;
                self.stats.spurts += 1;
                self.stream_played = true;
            }
            State::Playing => {}
        }
        let step = self.timeline.step;
        let lo = self.next * step;
        if let Some(end) = self.end_hint
            && self.next >= self.timeline.slot_after(end)
            && self.covered <= lo
        {
            return self.check_end(Playout::Silent);
        }
        if self.covered >= lo + step {
            self.next += 1;
            self.stats.played += 1;
            self.corrector.handed_audio();
            return Playout::NextFrame;
        }
        // Drop entries that fell behind (a skip or a resync moved past them).
        while let Some((&k, _)) = self.entries.first_key_value() {
            if self.timeline.slot_of(k) >= self.next {
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
        // A pull asked for a tick its thread reached late finds packets that came after that
        // tick: they were in time, and the slots after it are played that much later.
        let pulled = now.max(self.latest_arrival);
        self.play_ref = (self.next, pulled);
        self.stats.current_delay_ms = self.delay_at(now, self.next) * 1000.0;
        let room = self.delay_at(now, self.next) < self.config.max_delay.as_secs_f64();
        let (entries, timeline, next) = (&self.entries, &self.timeline, self.next);
        let can_skip = || slot_filled(entries, timeline, next + 1);
        let timing = (self.delay.base(), self.delay.pull_jitter());
        match self.corrector.adapt(now, room, timing, can_skip) {
            Adjust::Stretch => return self.stretch(pulled),
            Adjust::ForcedStretch => {
                self.stats.forced += 1;
                return self.stretch(pulled);
            }
            Adjust::ForcedSkip => {
                self.stats.forced += 1;
                self.skip(pulled);
            }
            Adjust::None => {
                if room && self.delay_at(now, self.next) < self.delay.target() - FRAME_SECONDS {
                    self.corrector.below_target();
                }
            }
        }
        let lo = self.next * step;
        let mut pieces = Vec::new();
        let end = lo + step - self.timeline.tolerance;
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
        self.spurt_frames = self.spurt_frames.saturating_add(1);
        self.stats.played += 1;
        self.corrector.handed_audio();
        match pieces.len() {
            0 => Playout::NextFrame,
            1 => Playout::Packet(pieces.remove(0)),
            _ => Playout::Pieces(pieces),
        }
    }

    /// Inserts a frame (concealed by the decoder): 20 ms more delay.
    fn stretch(&mut self, now: f64) -> Playout {
        self.corrector.grew();
        self.stats.stretched += 1;
        self.play_ref = (self.next, now + FRAME_SECONDS);
        Playout::Stretch
    }

    /// Skips the next slot's packets without playing them: 20 ms less delay.
    fn skip(&mut self, now: f64) {
        self.corrector.shrank();
        while let Some((&k, _)) = self.entries.first_key_value() {
            if self.timeline.slot_of(k) > self.next {
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
        let playing = self.state == State::Playing;
        let next_here =
            self.covered >= (self.next + 1) * self.timeline.step || self.has_slot(self.next);
        let correction = self.corrector.played(loudness, playing, next_here);
        if correction == Correction::Drop {
            self.stats.played -= 1;
            self.stats.dropped += 1;
            self.delay.replace_next_pull();
        }
        correction
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
            // At a spurt's start the stream's next packets are held up rather than lost: wait
            // for them (a frame inserted, the slot stays next), up to the largest delay.
            (None, Some(_))
                if self.spurt_frames < START_FRAMES && self.start_waits < START_WAIT =>
            {
                self.start_waits += 1;
                self.next = index;
                self.play_ref.1 += FRAME_SECONDS;
                self.corrector.grew();
                self.stats.stretched += 1;
                return Playout::Stretch;
            }
            (None, last) => {
                let hold = (self.delay.target() / FRAME_SECONDS).ceil().max(1.0) as u32;
                self.holes += 1;
                self.holes <= hold
                    || self
                        .end_hint
                        .is_some_and(|e| index < self.timeline.slot_after(e))
                    || last.is_some_and(|l| self.sequence.beyond(l))
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
            && (self.next >= self.timeline.slot_after(end) || !self.stream_played)
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
        self.sequence.highest()
    }

    /// New streams started on this SSRC after the first.
    pub fn restarts(&self) -> u64 {
        self.stats.restarts
    }

    pub fn stats(&self) -> JitterStats {
        let step = self.timeline.step as u64;
        JitterStats {
            jitter_ms: self.interarrival.ticks() / f64::from(self.timeline.clock) * 1000.0,
            drift_ppm: self.corrector.drift_ppm(),
            target_delay_ms: self.delay.target() * 1000.0,
            buffered_frames: self
                .entries
                .values()
                .map(|e| u64::from(e.duration).div_ceil(step) as usize)
                .sum(),
            lost: self.sequence.lost(),
            ..self.stats
        }
    }

    /// Counts for an RTCP report block: (fraction lost /256 since the last call, cumulative
    /// lost, extended highest sequence, jitter in timestamp units).
    pub fn report(&mut self) -> Option<(u8, u32, u32, u32)> {
        self.sequence.report(self.interarrival.ticks() as u32)
    }
}

/// Whether a packet of `entries` starts in slot `index` of `timeline`.
fn slot_filled(entries: &BTreeMap<i64, Entry>, timeline: &Timeline, index: i64) -> bool {
    let lo = index * timeline.step - timeline.tolerance;
    entries.range(lo..lo + timeline.step).next().is_some()
}

//! The arrival side of the jitter buffer: where a received packet is filed (its sequence
//! checked, its timestamp placed on the timeline, a new stream or talk spurt told apart from
//! a straggler).

use std::time::Instant;

use super::packets::FRAME_SECONDS;
use super::timeline::{MAX_DROPOUT, MAX_MISORDER, SeqCheck};
use super::{Arrival, Entry, HELD_UPSTREAM, JitterBuffer, MAX_PACKET_FRAMES, State};

impl JitterBuffer {
    /// A new stream on this SSRC (a redial): sequence state starts over, counters go on, and its
    /// first packet is placed where it arrives, after whatever of the old stream is still to
    /// play.
    fn restart(&mut self) {
        self.sequence.restart();
        self.ending = false;
        self.start_hint = None;
        self.end_hint = None;
        if self.state == State::Ended {
            self.state = State::Idle;
        }
        self.newest = None;
        self.anchor_next = self.timeline.origin_ts.is_some();
        self.stats.restarts += 1;
    }

    /// Checks and records a packet's sequence number.
    fn check_sequence(&mut self, seq: u16) -> SeqCheck {
        let check = self.sequence.check(seq);
        if let SeqCheck::Fresh(_, false) = check {
            self.stats.reordered += 1;
        }
        check
    }

    /// After BYE: whether a packet is a straggler of the stream that ended rather than the
    /// start of a new one (its sequence number near the last, its timestamp not past the end).
    fn of_ending_stream(&self, packet: &Arrival<'_>) -> bool {
        if !self.sequence.started() {
            return false;
        }
        let ahead = self.sequence.ahead(packet.sequence);
        if !(-MAX_MISORDER..=16).contains(&ahead) {
            return false;
        }
        let (Some(origin), Some(end)) = (self.timeline.origin_ts, self.end_hint) else {
            return true;
        };
        let off = self.timeline.extended(packet.timestamp) - origin;
        let step = self.timeline.step;
        (-MAX_DROPOUT * step..=end + step).contains(&off)
    }

    /// Re-anchors the timeline at a timestamp discontinuity: the packet stamped `ext` (arriving
    /// at `now`) is placed where its arrival puts it, after everything played or buffered.
    fn rebase(&mut self, ext: i64, now: f64) -> i64 {
        let by_arrival =
            ((now - self.delay.base()) * f64::from(self.timeline.clock)).round() as i64;
        let buffered = self
            .entries
            .last_key_value()
            .map_or(0, |(&k, e)| k + i64::from(e.duration));
        let off = by_arrival
            .max(buffered)
            .max(self.covered)
            .max(self.next * self.timeline.step);
        self.timeline.origin_ts = Some(ext - off);
        self.start_hint = None;
        self.end_hint = None;
        self.corrector.clear_trend();
        self.delay.clear_trend();
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
        let duration = frames.clamp(1, MAX_PACKET_FRAMES) * (self.timeline.clock / 50);
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

    /// A packet that came but carries nothing to play (a payload type no codec is mapped to,
    /// such as a phone's telephone-event): its sequence number is accounted as received, so
    /// that it is not counted lost, and its slot is concealed like any gap.
    pub fn unplayable(&mut self, seq: u16) {
        if let SeqCheck::Fresh(..) = self.check_sequence(seq) {
            self.sequence.count_received();
        }
    }

    /// Files a received packet.
    pub fn file(&mut self, packet: Arrival<'_>) {
        let now = self.seconds(packet.at);
        self.latest_arrival = self.latest_arrival.max(now);
        tracing::trace!(
            seq = packet.sequence,
            ts = packet.timestamp,
            at = now,
            "jitter arrival"
        );
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
        self.sequence.count_received();
        let ts = i64::from(packet.timestamp);
        let ext_ts = match self.timeline.origin_ts {
            None => {
                self.timeline.origin_ts = Some(ts);
                ts
            }
            Some(_) => self.timeline.extended(packet.timestamp),
        };
        let max_delay = self.config.max_delay.as_secs_f64();
        let mut raw = ext_ts - self.timeline.origin_ts.unwrap_or(ext_ts);
        if self.anchor_next {
            self.anchor_next = false;
            raw = self.rebase(ext_ts, now);
        } else if let Some((last_off, last_at)) = self.newest {
            let ahead = self.timeline.seconds(raw - last_off) - (now - last_at);
            if newest && -ahead >= HELD_UPSTREAM {
                self.stats.held_upstream += 1;
                tracing::debug!(
                    held_ms = (-ahead * 1000.0).round(),
                    at = now,
                    "jitter: the stream was held up before this receiver"
                );
            }
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
        let step = self.timeline.step;
        let mut off = on_grid(raw, step);
        let mut index = self.timeline.slot_of(off);
        if newest && packet.marker && self.stream_played && index < self.next {
            // A new talk spurt stamped before what was played: the sender's timestamps did not
            // move on over its pause.
            raw = self.rebase(ext_ts, now);
            off = on_grid(raw, step);
            index = self.timeline.slot_of(off);
        }
        if index < self.next && self.resumes(ext_seq, index) {
            // The stream resumes after a stall (its sender's, or a path's): what was played
            // since its last packet was concealment and pauses, nothing is buffered, and this
            // packet follows that one. Play on from it rather than drop it and what follows as
            // late: the stall's length goes into the delay, shed in the next pauses.
            self.resume_at(index);
        }
        if self.state == State::Idle && self.stream_played && index < self.next {
            // A straggler of a talk spurt already over (or held up longer than it lasts).
            self.stats.late += 1;
            return;
        }
        if newest {
            self.timeline.last_ts = ext_ts;
            self.newest = Some((raw, now));
        }
        self.delay.observe(now, now - self.timeline.seconds(raw));
        self.interarrival.observe(now, raw, self.timeline.clock);

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
                self.covered = self.next * step;
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
        let max = MAX_PACKET_FRAMES * (self.timeline.clock / 50);
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

    /// Whether the packet `seq` for slot `index`, behind the next slot to play, continues the
    /// stream after a stall: it follows the last packet handed out, nothing is buffered, and
    /// the delay it adds stays within the largest.
    fn resumes(&self, seq: i64, index: i64) -> bool {
        let most = (self.config.max_delay.as_secs_f64() / FRAME_SECONDS) as i64;
        self.stream_played
            && self.entries.is_empty()
            && self.last_out_seq == Some(seq - 1)
            && self.next - index <= most
            && self.covered <= index * self.timeline.step
    }

    /// Plays on from slot `index` at the time the next slot was to play.
    fn resume_at(&mut self, index: i64) {
        let at = self.slot_time(self.next);
        self.corrector.resumed(self.next - index);
        for _ in index..self.next {
            self.corrector.grew();
            self.stats.stretched += 1;
        }
        self.next = index;
        self.play_ref = (index, at);
        self.holes = 0;
        self.stats.resumed += 1;
    }

    /// A packet for slot `index` arrived at `now` while playing: how early it came.
    fn note_slack(&mut self, index: i64, now: f64) {
        let slack = self.slot_time(index) - now;
        // A packet filed before its slot was pulled came in time, whatever its stamp says: a
        // stamp after the slot's tick is the puller running late, a busy machine (the receiving
        // thread stamps what the same starvation held up), not a packet to grow the delay for
        // at once.
        let in_time = index >= self.next || self.state != State::Playing;
        self.corrector.note_slack(now, slack, in_time);
    }
}

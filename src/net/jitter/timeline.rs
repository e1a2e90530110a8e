//! The sequence timeline: where a packet belongs. Its timestamp, on the stream's RTP clock,
//! gives the 20 ms slot it plays in ([`Timeline`]); its sequence number tells a duplicate, a
//! reordered packet, a new stream and what was lost ([`Sequence`], RFC 3550 A.1 and A.3).

/// RFC 3550 A.1: sequence numbers this far ahead of the highest, or this far behind it, are not
/// the stream continuing; two such in a row start a new sequence.
pub(super) const MAX_DROPOUT: i64 = 3000;
pub(super) const MAX_MISORDER: i64 = 100;

/// Extends 16- and 32-bit RTP counters to 64 bits around the last value seen.
pub(super) fn extend(last: i64, value: u64, bits: u32) -> i64 {
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

/// The stream's clock and its grid of 20 ms slots, counted from the first timestamp seen.
#[derive(Debug)]
pub(super) struct Timeline {
    pub clock: u32,
    /// Ticks per frame.
    pub step: i64,
    /// Timestamps this close before a slot's start belong to it (senders rounding their
    /// timestamps); packets starting later in the slot are handed out with their offset.
    pub tolerance: i64,
    /// The extended timestamp that tick offset 0 stands for.
    pub origin_ts: Option<i64>,
    /// The newest extended timestamp, around which the next is extended.
    pub last_ts: i64,
}

impl Timeline {
    /// A timeline on a clock of `clock` Hz (at least 50).
    pub fn new(clock: u32) -> Self {
        let mut timeline = Self {
            clock: 0,
            step: 0,
            tolerance: 0,
            origin_ts: None,
            last_ts: 0,
        };
        timeline.set_clock(clock);
        timeline
    }

    /// Whether the clock changed.
    pub fn set_clock(&mut self, clock: u32) -> bool {
        let clock = clock.max(50);
        if clock == self.clock {
            return false;
        }
        self.clock = clock;
        self.step = i64::from(clock / 50);
        self.tolerance = self.step / 16;
        true
    }

    /// Forgets the origin: the next timestamp starts the timeline anew.
    pub fn reset(&mut self) {
        self.origin_ts = None;
        self.last_ts = 0;
    }

    /// `ts` extended around the newest timestamp.
    pub fn extended(&self, ts: u32) -> i64 {
        extend(self.last_ts, u64::from(ts), 32)
    }

    /// The tick offset of `ts` from the stream's first timestamp, and `ts` extended.
    pub fn offset_of(&mut self, ts: u32) -> (i64, i64) {
        let ext = match self.origin_ts {
            None => {
                self.origin_ts = Some(i64::from(ts));
                i64::from(ts)
            }
            Some(_) => self.extended(ts),
        };
        self.last_ts = ext;
        let origin = self.origin_ts.unwrap_or(ext);
        (ext - origin, ext)
    }

    /// The slot a packet starting at tick offset `off` belongs to.
    pub fn slot_of(&self, off: i64) -> i64 {
        (off + self.tolerance).div_euclid(self.step)
    }

    /// The first slot at or after tick offset `off` (where a stream ending there stops).
    pub fn slot_after(&self, off: i64) -> i64 {
        (off - self.tolerance).div_euclid(self.step) + 1
    }

    /// Seconds of `ticks`.
    pub fn seconds(&self, ticks: i64) -> f64 {
        ticks as f64 / f64::from(self.clock)
    }
}

/// A packet's sequence number against the stream's.
pub(super) enum SeqCheck {
    /// Extended, and whether it is the newest so far (if not, it came reordered).
    Fresh(i64, bool),
    Duplicate,
    /// Far from the stream; kept out until its successor confirms a new sequence.
    Probation,
    /// Its predecessor was on probation: a new sequence starts here.
    NewSequence,
}

/// Sequence bookkeeping (RFC 3550 A.1, A.3) for duplicates, new streams and receiver reports.
#[derive(Debug, Default)]
pub(super) struct Sequence {
    base: Option<i64>,
    max: i64,
    /// The last 128 sequence numbers up to `max` seen, one bit each.
    seen: u128,
    /// A far sequence number's successor, which would confirm a new sequence.
    probe: Option<u16>,
    /// Packets of the current sequence received, and those lost in earlier ones.
    received: u64,
    lost_prior: u64,
    expected_prior: i64,
    received_prior: u64,
}

impl Sequence {
    /// Checks and records a packet's sequence number.
    pub fn check(&mut self, seq: u16) -> SeqCheck {
        if self.base.is_none() {
            self.base = Some(i64::from(seq));
            self.max = i64::from(seq);
            self.seen = 1;
            self.probe = None;
            return SeqCheck::Fresh(i64::from(seq), true);
        }
        let ext = extend(self.max, u64::from(seq), 16);
        let ahead = ext - self.max;
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
            self.seen = if shift >= 128 { 0 } else { self.seen << shift } | 1;
            self.max = ext;
            return SeqCheck::Fresh(ext, true);
        }
        let age = (-ahead) as u32;
        if age < 128 {
            if self.seen & (1 << age) != 0 {
                return SeqCheck::Duplicate;
            }
            self.seen |= 1 << age;
        }
        SeqCheck::Fresh(ext, false)
    }

    /// A packet of the current sequence was filed.
    pub fn count_received(&mut self) {
        self.received += 1;
    }

    /// A new stream: its sequence starts over, what the old one lost is kept.
    pub fn restart(&mut self) {
        self.lost_prior += self.stream_lost();
        self.base = None;
        self.seen = 0;
        self.probe = None;
        self.received = 0;
        self.expected_prior = 0;
        self.received_prior = 0;
    }

    pub fn started(&self) -> bool {
        self.base.is_some()
    }

    /// How far `seq` is ahead of the highest sequence number (behind: negative).
    pub fn ahead(&self, seq: u16) -> i64 {
        extend(self.max, u64::from(seq), 16) - self.max
    }

    /// Whether a packet after the extended sequence number `seq` has come.
    pub fn beyond(&self, seq: i64) -> bool {
        self.base.is_some() && self.max > seq
    }

    /// The highest sequence number received in the current stream.
    pub fn highest(&self) -> Option<u16> {
        self.base.map(|_| self.max as u16)
    }

    /// Packets missing from the current sequence.
    fn stream_lost(&self) -> u64 {
        match self.base {
            Some(base) => (self.max - base + 1 - self.received as i64).max(0) as u64,
            None => 0,
        }
    }

    /// Packets missing over every stream.
    pub fn lost(&self) -> u64 {
        self.lost_prior + self.stream_lost()
    }

    /// Counts for an RTCP report block: (fraction lost /256 since the last call, cumulative
    /// lost, extended highest sequence, `jitter`).
    pub fn report(&mut self, jitter: u32) -> Option<(u8, u32, u32, u32)> {
        let base = self.base?;
        let expected = self.max - base + 1;
        let received = self.received;
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
            self.max as u32,
            jitter,
        ))
    }
}

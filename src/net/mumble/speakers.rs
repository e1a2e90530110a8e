//! The users a Mumble client knows, and each speaker's voice handed to its own receiver: the
//! packets go in as RTP on the 48 kHz clock (one sequence number per packet, the marker on the
//! first of a talk spurt), so the jitter buffer and Opus decoder every other transport uses
//! play them.

use std::time::Instant;

use crate::codec::any::{Codec, PayloadMap};
use crate::net::peer::{PeerReceiver, PlayedFrame, ReceiverStats};
use crate::net::rtp::{Rtp, RtpHeader};

/// 48 kHz ticks of Mumble's 10 ms sequence step.
const TICKS_PER_STEP: u32 = 480;

/// Where a speaker's packets are on the RTP timeline we give its receiver.
#[derive(Debug, Default)]
struct Timeline {
    /// Mumble sequence and RTP sequence/timestamp of the last packet.
    last: Option<(u64, u16, u32)>,
    arrival: Option<Instant>,
    ended: bool,
}

impl Timeline {
    /// RTP sequence, timestamp and marker for a packet of `steps` 10 ms steps at Mumble
    /// sequence `sequence`.
    fn place(&mut self, sequence: u64, steps: u64, now: Instant) -> (u16, u32, bool) {
        let steps = steps.max(1);
        let placed = match self.last {
            Some((last, seq, ts)) if !self.ended && sequence > last => {
                let ahead = sequence - last;
                let packets = ahead.div_ceil(steps).max(1);
                (
                    seq.wrapping_add(packets as u16),
                    ts.wrapping_add((ahead as u32).wrapping_mul(TICKS_PER_STEP)),
                    false,
                )
            }
            Some((_, seq, ts)) => {
                // A new talk spurt (or a sender that restarted its count): placed after the
                // last by the time that passed, never overlapping it.
                let gap = self
                    .arrival
                    .map_or(0, |a| now.saturating_duration_since(a).as_millis());
                let gap_steps = (gap / 10).max(steps as u128) as u32;
                (
                    seq.wrapping_add(1),
                    ts.wrapping_add(gap_steps.wrapping_mul(TICKS_PER_STEP)),
                    true,
                )
            }
            None => (0, 0, true),
        };
        self.last = Some((sequence, placed.0, placed.1));
        self.arrival = Some(now);
        placed
    }
}

/// A user of the server.
#[derive(Default)]
pub struct User {
    pub name: String,
    pub channel: u32,
    receiver: Option<PeerReceiver>,
    timeline: Timeline,
    /// Left the server (its buffered audio still plays out).
    pub gone: bool,
    /// Muted themselves (Mumble's self-mute).
    pub self_mute: bool,
}

impl User {
    /// Files one Opus packet of this user (Mumble sequence `sequence`, `last` of its talk
    /// spurt); the receiver is made by `receiver` on the first.
    pub fn file(
        &mut self,
        session: u32,
        sequence: u64,
        frame: &[u8],
        last: bool,
        now: Instant,
        receiver: impl FnOnce() -> PeerReceiver,
    ) {
        if frame.is_empty() {
            self.timeline.ended |= last;
            return;
        }
        let codec = Codec::Opus;
        let ticks = codec.payload_duration(frame).unwrap_or(codec.frame_ticks());
        let steps = u64::from(ticks.div_ceil(TICKS_PER_STEP));
        let (rtp_sequence, timestamp, marker) = self.timeline.place(sequence, steps, now);
        self.timeline.ended = last;
        let payload_type = PayloadMap::default().payload_type(codec).unwrap_or(96);
        self.receiver.get_or_insert_with(receiver).insert(
            &Rtp {
                header: RtpHeader {
                    marker,
                    payload_type,
                    sequence: rtp_sequence,
                    timestamp,
                    ssrc: session,
                },
                payload: frame,
            },
            now,
        );
    }

    /// The next 20 ms of this user, if it is playing.
    pub fn pull(&mut self, now: Instant) -> Option<PlayedFrame> {
        self.receiver.as_mut()?.pull(now)
    }

    /// Reception, once the user spoke.
    pub fn stats(&self) -> Option<ReceiverStats> {
        self.receiver.as_ref().map(PeerReceiver::stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn packets_of_a_spurt_take_consecutive_sequence_numbers() {
        let t0 = Instant::now();
        let mut t = Timeline::default();
        assert_eq!(t.place(0, 2, t0), (0, 0, true));
        assert_eq!(t.place(2, 2, t0), (1, 960, false));
        // One packet lost: the sequence number skips one.
        assert_eq!(t.place(6, 2, t0), (3, 2880, false));
        // A sender that restarted its count after a pause: a new spurt, placed after the last
        // by the time that passed.
        t.ended = true;
        let (seq, ts, marker) = t.place(0, 2, t0 + Duration::from_millis(500));
        assert_eq!((seq, marker), (4, true));
        assert_eq!(ts, 2880 + 50 * 480);
    }
}

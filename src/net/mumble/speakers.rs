//! The users a Mumble client knows, and each speaker's voice handed to its own receiver: the
//! packets go in as RTP on the 48 kHz clock (one sequence number per packet, the marker on the
//! first of a talk spurt), so the jitter buffer and Opus decoder every other transport uses
//! play them. Receivers are few ([`MAX_SPEAKERS`]) and go once their speaker left and played
//! out, so that a server cannot make the client keep one per user it ever named.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use crate::codec::any::{Codec, PayloadMap};
use crate::net::peer::{PeerReceiver, PlayedFrame, ReceiverStats};
use crate::net::rtp::{Rtp, RtpHeader};
use crate::net::transport::{PeerFrame, PeerId};

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

/// A user of the server, as its presence shows.
#[derive(Debug, Default)]
pub struct User {
    pub name: String,
    pub channel: u32,
    /// Muted themselves (Mumble's self-mute).
    pub self_mute: bool,
    /// Reception of their earlier voice, whose receiver was let go to make room for another
    /// speaker's.
    pub heard: Option<Box<ReceiverStats>>,
}

/// The most speakers with a receiver (a jitter buffer and a decoder) at a time, as a direct
/// session's peers.
pub const MAX_SPEAKERS: usize = 32;
/// The most speakers who left listed for the summary; the others are counted.
pub const MAX_DEPARTED: usize = 64;
/// How long a speaker who left keeps their receiver, for their buffered audio to play out.
const PLAYOUT: Duration = Duration::from_secs(1);
/// A speaker still there whose receiver may be let go for a new one: quiet this long.
const QUIET: Duration = Duration::from_secs(5);

/// Someone who spoke: their voice's receiver.
pub struct Speaker {
    pub name: String,
    receiver: PeerReceiver,
    timeline: Timeline,
    /// When they left the server (their buffered audio still plays out).
    pub left: Option<Instant>,
}

impl Speaker {
    pub fn new(name: String, receiver: PeerReceiver) -> Self {
        Self {
            name,
            receiver,
            timeline: Timeline::default(),
            left: None,
        }
    }

    /// Files one Opus packet of this speaker (session `session`, Mumble sequence `sequence`,
    /// `last` of its talk spurt).
    pub fn file(&mut self, session: u32, sequence: u64, frame: &[u8], last: bool, now: Instant) {
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
        self.receiver.insert(
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

    /// The next 20 ms of this speaker, if they are playing.
    pub fn pull(&mut self, now: Instant) -> Option<PlayedFrame> {
        self.receiver.pull(now)
    }

    pub fn stats(&self) -> ReceiverStats {
        self.receiver.stats()
    }
}

/// Where the room for a new speaker came from.
pub enum Room {
    Free,
    /// The receiver of this speaker (still there, quiet) was let go: their reception so far.
    LetGo(u32, Box<ReceiverStats>),
    /// None: every receiver is busy.
    Full,
}

/// Everyone who spoke: at most [`MAX_SPEAKERS`] with a receiver; those who left, once their
/// audio played out, as a line of the summary ([`MAX_DEPARTED`] of them, the rest counted).
#[derive(Default)]
pub struct Speakers {
    live: BTreeMap<u32, Speaker>,
    departed: VecDeque<(u32, String, ReceiverStats)>,
    unlisted: u64,
}

impl Speakers {
    pub fn get_mut(&mut self, session: u32) -> Option<&mut Speaker> {
        self.live.get_mut(&session)
    }

    pub fn live(&self) -> impl Iterator<Item = (u32, &Speaker)> {
        self.live.iter().map(|(&s, speaker)| (s, speaker))
    }

    /// Those who left, oldest first, with how many more are not listed.
    pub fn departed(&self) -> (&VecDeque<(u32, String, ReceiverStats)>, u64) {
        (&self.departed, self.unlisted)
    }

    /// Makes room for one more receiver if there is none: a speaker who left goes first, else
    /// the one quiet longest if quiet for [`QUIET`].
    pub fn make_room(&mut self, now: Instant) -> Room {
        if self.live.len() < MAX_SPEAKERS {
            return Room::Free;
        }
        if let Some(&gone) = self
            .live
            .iter()
            .find(|(_, s)| s.left.is_some())
            .map(|(s, _)| s)
        {
            self.retire(gone);
            return Room::Free;
        }
        let quietest = self
            .live
            .iter()
            .map(|(&s, speaker)| (speaker.timeline.arrival, s))
            .min();
        match quietest {
            Some((heard, session))
                if heard.is_none_or(|t| now.saturating_duration_since(t) > QUIET) =>
            {
                match self.live.remove(&session) {
                    Some(speaker) => Room::LetGo(session, Box::new(speaker.stats())),
                    None => Room::Full,
                }
            }
            _ => Room::Full,
        }
    }

    pub fn insert(&mut self, session: u32, speaker: Speaker) {
        if let Some(old) = self.live.insert(session, speaker) {
            self.depart(session, old.name, old.receiver.stats());
        }
    }

    /// The speaker left the server: their receiver plays out what it holds, then goes.
    pub fn leave(&mut self, session: u32, now: Instant) {
        if let Some(speaker) = self.live.get_mut(&session) {
            speaker.left.get_or_insert(now);
        }
    }

    /// A session id the server gave to a newcomer: a speaker who had it and left goes now.
    pub fn reissued(&mut self, session: u32) {
        if self.live.get(&session).is_some_and(|s| s.left.is_some()) {
            self.retire(session);
        }
    }

    /// Everyone left (the connection is gone).
    pub fn leave_all(&mut self, now: Instant) {
        for speaker in self.live.values_mut() {
            speaker.left.get_or_insert(now);
        }
    }

    /// Everyone's receiver goes (a new connection: its session ids are new).
    pub fn retire_all(&mut self) {
        for (session, speaker) in std::mem::take(&mut self.live) {
            self.depart(session, speaker.name, speaker.receiver.stats());
        }
    }

    fn retire(&mut self, session: u32) {
        if let Some(speaker) = self.live.remove(&session) {
            self.depart(session, speaker.name, speaker.receiver.stats());
        }
    }

    /// Lists one who spoke and has gone.
    pub fn depart(&mut self, session: u32, name: String, stats: ReceiverStats) {
        if self.departed.len() == MAX_DEPARTED {
            self.departed.pop_front();
            self.unlisted += 1;
        }
        self.departed.push_back((session, name, stats));
    }

    /// The next 20 ms of every speaker playing; those who left and have nothing more to play
    /// (or left [`PLAYOUT`] ago) go.
    pub fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        let mut done = Vec::new();
        for (&session, speaker) in &mut self.live {
            let frame = speaker.pull(now);
            let played_out = speaker
                .left
                .is_some_and(|t| frame.is_none() || now.saturating_duration_since(t) > PLAYOUT);
            if played_out {
                done.push(session);
            }
            if let Some(frame) = frame {
                out.push(PeerFrame {
                    peer: PeerId::Mumble(session),
                    frame,
                });
            }
        }
        for session in done {
            self.retire(session);
        }
    }

    /// Those who left more than [`PLAYOUT`] ago go (when nothing pulls their audio).
    pub fn expire(&mut self, now: Instant) {
        let done: Vec<u32> = self
            .live
            .iter()
            .filter(|(_, s)| {
                s.left
                    .is_some_and(|t| now.saturating_duration_since(t) > PLAYOUT)
            })
            .map(|(&session, _)| session)
            .collect();
        for session in done {
            self.retire(session);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

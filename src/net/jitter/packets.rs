//! What the buffer is configured with, takes in and hands out.

use std::time::{Duration, Instant};

/// One frame of playout, in seconds.
pub(super) const FRAME_SECONDS: f64 = 0.02;

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

/// How loud a played frame is, as its decoder heard it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loudness {
    /// Silence or near it: dropping it, or adding a frame after it, goes unheard.
    Quiet,
    Audible,
}

/// What the buffer makes of the frame just played ([`super::JitterBuffer::played`]).
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

//! Per-peer queues at the mixer's rate and the mixer that sums them, a piece (10 ms) or a
//! frame (20 ms) at a time.
//!
//! The mixer runs at the output device's rate (48 kHz without a device), so each peer is
//! resampled once, from its codec's own rate, as its decoded frames are queued
//! ([`PeerFeed::push_frame`]): a fullband Opus peer is heard fullband. The engine thread pushes
//! into each peer's ring ([`PeerFeed`]); the mixer thread pops a chunk from every peer, applies
//! volume and mute, sums and clips, and resamples only where the device's rate is not the
//! mixer's (an output switched to another rate). Nothing here runs in the device callback, so
//! peers come and go through plain ownership moves. Positions (mix and stream) count samples at
//! the mixer's rate.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

use rubato::audioadapter_buffers::direct::InterleavedSlice;
use rubato::{Fft, FixedSync, Resampler};

use super::clock::{PeerClock, Segment};
use super::error::AudioError;
use super::resample::{FrameResampler, fft_resampler};
use super::ringtone::{RingSwitch, Ringtone};
use crate::vocab::{FRAME_SIZE, FrameAudio, MAX_FRAME_SAMPLES, SAMPLE_RATE, energy_db};

/// Samples of an 8 kHz mix produced per step (one Speex frame, 20 ms).
pub const CHUNK: usize = FRAME_SIZE;
/// The mixer's rate where the device's cannot be one (no device, or a rate whose 20 ms is not a
/// whole number of samples, or above 48 kHz).
pub const DEFAULT_MIX_RATE: u32 = 48_000;

/// The rate a mixer runs at for a device at `device_rate`: the device's own where 20 ms of it is
/// a whole number of samples, up to 48 kHz (no resampling after the mix), else 48 kHz.
pub fn mix_rate_for(device_rate: u32) -> u32 {
    if crate::vocab::audio::valid_rate(device_rate) {
        device_rate
    } else {
        DEFAULT_MIX_RATE
    }
}

/// Samples in 20 ms at `rate`.
pub fn frame_len(rate: u32) -> usize {
    rate as usize / 50
}

/// Below -56 dBFS (an RMS of 50): a frame whose absence goes unheard.
fn near_silent(pcm: &[i16]) -> bool {
    const QUIET_DB: f32 = -56.33;
    !pcm.is_empty() && energy_db(pcm) < QUIET_DB
}

/// Samples in one piece a mixer at `rate` mixes ([`Mixer::piece_len`]).
pub fn piece_len(rate: u32) -> usize {
    if rate.is_multiple_of(100) {
        rate as usize / 100
    } else {
        frame_len(rate)
    }
}
/// Peers the mixer holds without growing its table.
pub const MAX_PEERS: usize = 64;

/// Identifies a remote peer within one playback engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PeerId(pub u32);

/// Per-peer settings the UI changes and the mixer reads: plain atomics.
#[derive(Debug)]
pub struct PeerControls {
    volume_bits: AtomicU32,
    muted: AtomicBool,
    /// Samples pushed by the decoder that did not fit in the queue.
    overflow: AtomicU64,
    /// Samples of silence the mixer inserted because the queue was empty while the peer was
    /// active (only counted after the peer's first sample).
    starved: AtomicU64,
    /// Segments the reader was too slow to take (the lip-sync mapping lost them).
    lost_segments: AtomicU64,
    /// Samples of near-silent frames not queued, to shed a queue's surplus.
    shed: AtomicU64,
}

impl Default for PeerControls {
    fn default() -> Self {
        Self {
            volume_bits: AtomicU32::new(1.0f32.to_bits()),
            muted: AtomicBool::new(false),
            overflow: AtomicU64::new(0),
            starved: AtomicU64::new(0),
            lost_segments: AtomicU64::new(0),
            shed: AtomicU64::new(0),
        }
    }
}

impl PeerControls {
    /// Linear gain, clamped to 0..=4 (NaN becomes 0).
    pub fn set_volume(&self, v: f32) {
        let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 4.0) };
        self.volume_bits.store(v.to_bits(), Ordering::Relaxed);
    }

    pub fn volume(&self) -> f32 {
        f32::from_bits(self.volume_bits.load(Ordering::Relaxed))
    }

    pub fn set_muted(&self, m: bool) {
        self.muted.store(m, Ordering::Relaxed);
    }

    pub fn muted(&self) -> bool {
        self.muted.load(Ordering::Relaxed)
    }

    pub fn overflow(&self) -> u64 {
        self.overflow.load(Ordering::Relaxed)
    }

    pub fn starved(&self) -> u64 {
        self.starved.load(Ordering::Relaxed)
    }

    pub fn lost_segments(&self) -> u64 {
        self.lost_segments.load(Ordering::Relaxed)
    }

    /// Samples of near-silent frames left out to bring a queue back to its lead.
    pub fn shed(&self) -> u64 {
        self.shed.load(Ordering::Relaxed)
    }
}

/// The decoder thread's end of a peer's queue. Never blocks: what does not fit is dropped and
/// counted.
#[derive(Debug)]
pub struct PeerFeed {
    id: PeerId,
    tx: rtrb::Producer<i16>,
    written: u64,
    controls: Arc<PeerControls>,
    /// The mixer's rate: what the queue holds.
    rate: u32,
    /// The peer's frames to the mixer's rate, made for the rate its frames come at.
    resampler: Option<FrameResampler>,
}

impl PeerFeed {
    pub fn id(&self) -> PeerId {
        self.id
    }

    /// The mixer's rate, at which the queue's samples and stream positions count.
    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// Samples in 20 ms at the mixer's rate.
    pub fn frame_len(&self) -> usize {
        frame_len(self.rate)
    }

    /// Queues samples at the mixer's rate. Returns the stream position of the first sample queued
    /// (tag the frame's weights with it) and how many were queued.
    pub fn push(&mut self, pcm: &[i16]) -> (u64, usize) {
        let start = self.written;
        let (done, _rest) = self.tx.push_partial_slice(pcm);
        let n = done.len();
        self.written += n as u64;
        if n < pcm.len() {
            self.controls
                .overflow
                .fetch_add((pcm.len() - n) as u64, Ordering::Relaxed);
        }
        (start, n)
    }

    /// Queues a frame pulled on the mixer's demand ([`super::FramePacer`]), which puts it
    /// `ahead` frames ahead of the mixer. The first frame of a peer that starts, or speaks again
    /// after a silence (`resuming`), comes after enough silence to put it there too; a queue
    /// already `ahead + 2` frames long (an output that takes nothing) takes nothing more. A
    /// queue holding a piece or a frame more than `ahead` asks (the mixer played silence for
    /// this peer while its frame was on the way, or the peer started with the mixer half-way
    /// through a frame, and its stream has run that much later since) sheds the surplus: of a
    /// near-silent frame only what follows it is queued, or nothing. The stream position of
    /// the frame's first sample queued, or `None` if none was. `pcm` is at the mixer's rate.
    pub fn push_paced(&mut self, pcm: &[i16], ahead: usize, resuming: bool) -> Option<u64> {
        const SILENCE: [i16; MAX_FRAME_SAMPLES] = [0; MAX_FRAME_SAMPLES];
        let frame = self.frame_len();
        let queued = self.queued();
        if queued >= (ahead + 2) * frame {
            return None;
        }
        let piece = piece_len(self.rate);
        let surplus = queued.saturating_sub(ahead.saturating_sub(1) * frame);
        let shed = (surplus.min(frame) / piece * piece).min(pcm.len());
        if !resuming && shed > 0 && near_silent(pcm) {
            self.controls.shed.fetch_add(shed as u64, Ordering::Relaxed);
            return (shed < pcm.len()).then(|| self.push(&pcm[shed..]).0);
        }
        if resuming {
            let mut pad = (ahead.saturating_sub(1) * frame).saturating_sub(queued);
            while pad > 0 {
                let n = pad.min(frame);
                self.push(&SILENCE[..n]);
                pad -= n;
            }
        }
        Some(self.push(pcm).0)
    }

    /// [`PeerFeed::push_paced`] for a decoded frame at its codec's own rate: resampled once to
    /// the mixer's. The position returned is where the frame's first sample is heard in the
    /// stream, the resampler's delay included (tag the frame's weights with it). Allocates only
    /// when the peer's rate changes (a new resampler). A frame the resampler refuses is queued
    /// as silence, so that the stream keeps its time.
    pub fn push_frame(&mut self, audio: &FrameAudio, ahead: usize, resuming: bool) -> Option<u64> {
        let mut out = [0i16; MAX_FRAME_SAMPLES];
        let out = &mut out[..self.frame_len()];
        // The resampler puts the frame's audio this many samples after where it is queued.
        let mut delay = 0;
        if audio.rate() == self.rate {
            let n = out.len().min(audio.samples().len());
            out[..n].copy_from_slice(&audio.samples()[..n]);
        } else {
            if self
                .resampler
                .as_ref()
                .is_none_or(|r| r.from_rate() != audio.rate())
            {
                self.resampler = FrameResampler::new(audio.rate(), self.rate).ok();
            }
            match self.resampler.as_mut() {
                Some(r) => {
                    delay = r.delay() as u64;
                    if let Err(e) = r.process_into(audio.samples(), out) {
                        tracing::debug!("peer {:?}: frame not resampled: {e}", self.id);
                    }
                }
                None => tracing::debug!(
                    "peer {:?}: no resampler from {} Hz: silence",
                    self.id,
                    audio.rate()
                ),
            }
        }
        self.push_paced(out, ahead, resuming).map(|pos| pos + delay)
    }

    /// Stream position of the next sample to be queued.
    pub fn position(&self) -> u64 {
        self.written
    }

    /// Samples waiting in the queue.
    pub fn queued(&self) -> usize {
        self.tx.buffer().capacity() - self.tx.slots()
    }

    /// False once the mixer dropped the other end (peer removed or engine stopped).
    pub fn is_connected(&self) -> bool {
        !self.tx.is_abandoned()
    }
}

/// The mixer's end of a peer.
#[derive(Debug)]
pub struct MixerPeer {
    id: PeerId,
    rx: rtrb::Consumer<i16>,
    controls: Arc<PeerControls>,
    stream_pos: u64,
    segments: rtrb::Producer<Segment>,
    /// The last mix took samples from it.
    fed: bool,
}

impl MixerPeer {
    pub fn id(&self) -> PeerId {
        self.id
    }
}

/// Creates the three ends of a peer of an 8 kHz mixer: the decoder's feed, the mixer's queue
/// and the reader's clock. `queue` is the queue's capacity in samples.
pub fn peer_channel(
    id: PeerId,
    queue: usize,
    controls: Arc<PeerControls>,
) -> (PeerFeed, MixerPeer, PeerClock) {
    peer_channel_at(id, SAMPLE_RATE, queue, controls)
}

/// [`peer_channel`] for a mixer at `rate`; `queue` in samples at that rate.
pub fn peer_channel_at(
    id: PeerId,
    rate: u32,
    queue: usize,
    controls: Arc<PeerControls>,
) -> (PeerFeed, MixerPeer, PeerClock) {
    let (tx, rx) = rtrb::RingBuffer::new(queue.max(frame_len(rate)));
    // Segments are per chunk: room for 10 s unread before the mapping loses any.
    let (seg_tx, seg_rx) = rtrb::RingBuffer::new(500);
    (
        PeerFeed {
            id,
            tx,
            written: 0,
            controls: controls.clone(),
            rate,
            resampler: None,
        },
        MixerPeer {
            id,
            rx,
            controls,
            stream_pos: 0,
            segments: seg_tx,
            fed: false,
        },
        PeerClock::new(Some(seg_rx)),
    )
}

/// What a mixer has mixed so far, for the thread that feeds its peers: the output's demand
/// (see [`super::pacer::FramePacer`]). A clone reads the same count.
#[derive(Debug, Clone)]
pub struct MixProgress(Arc<Progress>);

#[derive(Debug)]
struct Progress {
    samples: AtomicU64,
    frame_len: u64,
    /// The thread that pulls the peers' frames, woken as each frame is mixed.
    puller: std::sync::OnceLock<std::thread::Thread>,
}

impl MixProgress {
    fn new(frame_len: usize) -> Self {
        Self(Arc::new(Progress {
            samples: AtomicU64::new(0),
            frame_len: frame_len.max(1) as u64,
            puller: std::sync::OnceLock::new(),
        }))
    }

    /// Whole 20 ms frames mixed.
    pub fn chunks(&self) -> u64 {
        self.samples() / self.0.frame_len
    }

    /// Samples mixed, at the mixer's rate.
    pub fn samples(&self) -> u64 {
        self.0.samples.load(Ordering::Acquire)
    }

    /// Unparks the calling thread each time the mixer finishes a frame, so that a puller
    /// parked between polls ([`std::thread::park_timeout`]) queues the next one at once. The
    /// first thread to ask is the one woken.
    pub fn wake_me(&self) {
        let _ = self.0.puller.set(std::thread::current());
    }

    fn advance(&self, to: u64) {
        let before = self.0.samples.swap(to, Ordering::AcqRel);
        if before / self.0.frame_len != to / self.0.frame_len
            && let Some(t) = self.0.puller.get()
        {
            t.unpark();
        }
    }
}

/// Sums the peers' streams into one mix, 20 ms at a time, at its rate.
#[derive(Debug)]
pub struct Mixer {
    peers: Vec<MixerPeer>,
    position: u64,
    progress: MixProgress,
    rate: u32,
    /// Added to the mix while its switch is on (a call rings).
    ringtone: Ringtone,
    ring: RingSwitch,
}

impl Default for Mixer {
    fn default() -> Self {
        Self::new()
    }
}

impl Mixer {
    /// An 8 kHz mixer.
    pub fn new() -> Self {
        Self::at_rate(SAMPLE_RATE)
    }

    /// A mixer at `rate` (20 ms of it a whole number of samples, at most 48 kHz; others mix at
    /// [`DEFAULT_MIX_RATE`]).
    pub fn at_rate(rate: u32) -> Self {
        let rate = if crate::vocab::audio::valid_rate(rate) {
            rate
        } else {
            DEFAULT_MIX_RATE
        };
        let ring = RingSwitch::default();
        Self {
            peers: Vec::with_capacity(MAX_PEERS),
            position: 0,
            progress: MixProgress::new(frame_len(rate)),
            rate,
            ringtone: Ringtone::new(rate, ring.clone()),
            ring,
        }
    }

    /// Turns its ringtone on and off from another thread.
    pub fn ring_switch(&self) -> RingSwitch {
        self.ring.clone()
    }

    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// Samples per chunk (20 ms at the mixer's rate).
    pub fn chunk_len(&self) -> usize {
        frame_len(self.rate)
    }

    /// Samples the mixer thread mixes at a time: 10 ms (half a frame) where that is a whole
    /// number of samples, else 20 ms. Topping the output ring up in halves keeps it shorter.
    pub fn piece_len(&self) -> usize {
        piece_len(self.rate)
    }

    /// True when a peer that was heard in the last piece has less than `len` samples queued:
    /// its next frame is probably on its way from the puller (mixing now would put a gap in
    /// its stream), or its talk spurt has ended.
    pub fn awaits_peer(&self, len: usize) -> bool {
        self.peers.iter().any(|p| p.fed && p.rx.slots() < len)
    }

    /// Its count of samples and frames mixed, readable from other threads.
    pub fn progress(&self) -> MixProgress {
        self.progress.clone()
    }

    /// Adds a peer; gives it back when the table is full.
    pub fn add(&mut self, peer: MixerPeer) -> Result<(), Box<MixerPeer>> {
        if self.peers.len() >= MAX_PEERS {
            return Err(Box::new(peer));
        }
        self.peers.push(peer);
        Ok(())
    }

    pub fn remove(&mut self, id: PeerId) -> Option<MixerPeer> {
        let i = self.peers.iter().position(|p| p.id == id)?;
        Some(self.peers.swap_remove(i))
    }

    pub fn peer_count(&self) -> usize {
        self.peers.len()
    }

    /// Mix position of the next chunk (samples mixed so far, at the mixer's rate).
    pub fn position(&self) -> u64 {
        self.position
    }

    /// Mixes the next `out.len()` samples into `out` (in -1..=1, clipped): a chunk
    /// ([`Mixer::chunk_len`]) or a piece ([`Mixer::piece_len`]). Every peer's queue is read even
    /// when muted, so its stream keeps time with what the others hear.
    pub fn mix(&mut self, out: &mut [f32]) {
        let chunk_len = out.len();
        out.fill(0.0);
        let mix_start = self.position;
        for p in &mut self.peers {
            let gain = if p.controls.muted() {
                0.0
            } else {
                p.controls.volume() / 32768.0
            };
            let n = p.rx.slots().min(chunk_len);
            if let Ok(chunk) = p.rx.read_chunk(n) {
                let (a, b) = chunk.as_slices();
                for (o, &s) in out.iter_mut().zip(a.iter().chain(b)) {
                    *o += f32::from(s) * gain;
                }
                chunk.commit_all();
            }
            if n > 0 {
                let seg = Segment {
                    mix_start,
                    stream_start: p.stream_pos,
                    len: n as u32,
                };
                if p.segments.push(seg).is_err() {
                    p.controls.lost_segments.fetch_add(1, Ordering::Relaxed);
                }
            }
            p.fed = n > 0;
            if n < chunk_len && p.stream_pos + n as u64 > 0 {
                p.controls
                    .starved
                    .fetch_add((chunk_len - n) as u64, Ordering::Relaxed);
            }
            p.stream_pos += n as u64;
        }
        self.ringtone.add_to(out);
        for o in out.iter_mut() {
            *o = o.clamp(-1.0, 1.0);
        }
        self.position += chunk_len as u64;
        self.progress.advance(self.position);
    }
}

/// The mixer's rate -> the device's, one chunk (20 ms, or a piece) at a time, into a buffer
/// allocated once; a copy where the two are equal.
pub struct Upsampler {
    resampler: Option<Fft<f32>>,
    out: Vec<f32>,
    rate: u32,
    chunk: usize,
}

impl std::fmt::Debug for Upsampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Upsampler")
            .field("rate", &self.rate)
            .finish()
    }
}

impl Upsampler {
    /// From an 8 kHz mix to `rate`.
    pub fn new(rate: u32) -> Result<Self, AudioError> {
        Self::between(SAMPLE_RATE, rate)
    }

    /// From a mix at `from` to a device at `to`, 20 ms at a time.
    pub fn between(from: u32, to: u32) -> Result<Self, AudioError> {
        Self::in_pieces(from, to, frame_len(from))
    }

    /// From a mix at `from` to a device at `to`, `chunk` samples at a time (the mixer's piece).
    pub fn in_pieces(from: u32, to: u32, chunk: usize) -> Result<Self, AudioError> {
        let chunk = chunk.max(1);
        let resampler = fft_resampler(from, to, chunk, FixedSync::Input)?;
        let max = resampler.as_ref().map_or(chunk, |r| r.output_frames_max());
        Ok(Self {
            resampler,
            out: vec![0.0; max],
            rate: to,
            chunk,
        })
    }

    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// Output frames of delay the resampler adds.
    pub fn delay(&self) -> usize {
        self.resampler.as_ref().map_or(0, |r| r.output_delay())
    }

    /// Output frames the next chunk will produce.
    pub fn next_len(&self) -> usize {
        self.resampler
            .as_ref()
            .map_or(self.chunk, |r| r.output_frames_next())
    }

    /// Resamples one chunk (the length it was made for, at the mixer's rate); the returned
    /// slice lives until the next call.
    pub fn process(&mut self, input: &[f32]) -> Result<&[f32], AudioError> {
        let err = |e: &dyn std::fmt::Display| AudioError::Resampler(e.to_string());
        let chunk = self.chunk;
        if input.len() < chunk {
            return Err(AudioError::Resampler(format!(
                "{} samples for a chunk of {chunk}",
                input.len()
            )));
        }
        let Some(r) = self.resampler.as_mut() else {
            self.out[..chunk].copy_from_slice(&input[..chunk]);
            return Ok(&self.out[..chunk]);
        };
        let frames_out = self.out.len();
        let inp = InterleavedSlice::new(&input[..chunk], 1, chunk).map_err(|e| err(&e))?;
        let mut outp =
            InterleavedSlice::new_mut(&mut self.out[..], 1, frames_out).map_err(|e| err(&e))?;
        let (_, n) = r
            .process_into_buffer(&inp, &mut outp, None)
            .map_err(|e| err(&e))?;
        Ok(&self.out[..n])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peer(id: u32) -> (PeerFeed, MixerPeer, PeerClock, Arc<PeerControls>) {
        let c = Arc::new(PeerControls::default());
        let (f, m, k) = peer_channel(PeerId(id), 8000, c.clone());
        (f, m, k, c)
    }

    #[test]
    fn mixer_sums_with_volume_and_mute_and_clips() {
        let mut mixer = Mixer::new();
        let (mut fa, ma, _ka, ca) = peer(1);
        let (mut fb, mb, _kb, cb) = peer(2);
        let (mut fc, mc, _kc, cc) = peer(3);
        mixer.add(ma).unwrap();
        mixer.add(mb).unwrap();
        mixer.add(mc).unwrap();
        fa.push(&[8192; CHUNK]); // 0.25
        fb.push(&[4096; CHUNK]); // 0.125
        fc.push(&[16384; CHUNK]); // 0.5, muted
        ca.set_volume(2.0);
        cb.set_volume(0.5);
        cc.set_muted(true);
        let mut out = [0.0; CHUNK];
        mixer.mix(&mut out);
        assert!(
            out.iter().all(|&s| (s - (0.5 + 0.0625)).abs() < 1e-6),
            "{}",
            out[0]
        );
        // The muted peer's queue was still drained.
        assert_eq!(fc.queued(), 0);

        // Loud peers clip at full scale, both ways.
        fa.push(&[30000; CHUNK]);
        fb.push(&[30000; CHUNK]);
        cb.set_volume(4.0);
        mixer.mix(&mut out);
        assert!(out.iter().all(|&s| s == 1.0));
        fa.push(&[-30000; CHUNK]);
        fb.push(&[-30000; CHUNK]);
        mixer.mix(&mut out);
        assert!(out.iter().all(|&s| s == -1.0));
        assert_eq!(mixer.position(), 3 * CHUNK as u64);
        cc.set_volume(f32::NAN);
        assert_eq!(cc.volume(), 0.0);
    }

    #[test]
    fn queue_overflow_and_starvation_are_counted_and_mapped() {
        let c = Arc::new(PeerControls::default());
        let (mut feed, mp, mut clock) = peer_channel(PeerId(7), CHUNK, c.clone());
        let mut mixer = Mixer::new();
        mixer.add(mp).unwrap();
        let mut out = [0.0; CHUNK];
        // Nothing queued yet: silence, no starvation counted before the first sample.
        mixer.mix(&mut out);
        assert_eq!(c.starved(), 0);
        // Queue holds one chunk: the second push overflows by 40.
        assert_eq!(feed.push(&[100; 120]), (0, 120));
        assert_eq!(feed.push(&[100; 80]), (120, 40));
        assert_eq!(c.overflow(), 40);
        mixer.mix(&mut out);
        mixer.mix(&mut out); // runs dry: 160 starved
        assert_eq!(c.starved(), 160);
        feed.push(&[5; 100]);
        mixer.mix(&mut out); // 60 short
        assert_eq!(c.starved(), 220);
        assert_eq!(clock.stream_position(CHUNK as u64 + 5), Some(5));
        assert_eq!(clock.stream_position(2 * CHUNK as u64 + 5), None);
        assert_eq!(clock.stream_position(3 * CHUNK as u64 + 99), Some(259));
        assert_eq!(clock.stream_position(3 * CHUNK as u64 + 100), None);
        drop(mixer);
        assert!(!feed.is_connected());
    }

    #[test]
    fn a_paced_queue_keeps_its_lead_and_stops_growing() {
        let c = Arc::new(PeerControls::default());
        let (mut feed, mp, _clock) = peer_channel(PeerId(8), 8000, c);
        let mut mixer = Mixer::new();
        mixer.add(mp).unwrap();
        let mut out = [0.0; CHUNK];
        // The first frame comes after a frame of silence: two ahead of the mixer.
        assert_eq!(feed.push_paced(&[100; CHUNK], 2, true), Some(CHUNK as u64));
        assert_eq!(feed.queued(), 2 * CHUNK);
        mixer.mix(&mut out);
        assert!(out.iter().all(|&s| s == 0.0));
        assert_eq!(
            feed.push_paced(&[100; CHUNK], 2, false),
            Some(2 * CHUNK as u64)
        );
        assert_eq!(feed.queued(), 2 * CHUNK);
        // The mixer takes two at once: two more, no silence between.
        mixer.mix(&mut out);
        mixer.mix(&mut out);
        feed.push_paced(&[100; CHUNK], 2, false);
        feed.push_paced(&[100; CHUNK], 2, false);
        assert_eq!(feed.queued(), 2 * CHUNK);
        // Speaking again with a frame still queued: silence up to one frame only.
        mixer.mix(&mut out);
        assert_eq!(
            feed.push_paced(&[100; CHUNK], 2, true),
            Some(5 * CHUNK as u64)
        );
        // Nothing taken: it stops at four frames.
        for _ in 0..5 {
            feed.push_paced(&[100; CHUNK], 2, false);
        }
        assert_eq!(feed.queued(), 4 * CHUNK);
    }

    #[test]
    fn a_48_khz_mixer_hears_each_peer_at_its_own_band() {
        // A 16 kHz peer (G.722, Speex WB) with a 6 kHz tone, an 8 kHz peer, a 48 kHz peer with
        // a 15 kHz tone: each resampled once into its queue, positions counted at 48 kHz.
        let mut mixer = Mixer::at_rate(48_000);
        let tone = |rate: u32, freq: f64, f: usize| {
            let n = rate as usize / 50;
            let pcm: Vec<i16> = (0..n)
                .map(|i| {
                    let t = (f * n + i) as f64 / f64::from(rate);
                    (8000.0 * (2.0 * std::f64::consts::PI * freq * t).sin()) as i16
                })
                .collect();
            FrameAudio::from_slice(rate, &pcm)
        };
        let peers = [(16_000u32, 6000.0), (8000, 1000.0), (48_000, 15_000.0)];
        let mut feeds = Vec::new();
        for (i, _) in peers.iter().enumerate() {
            let c = Arc::new(PeerControls::default());
            c.set_volume(if i == 0 { 1.0 } else { 0.0 });
            let (f, m, _) = peer_channel_at(PeerId(i as u32), 48_000, 48_000, c);
            mixer.add(m).unwrap();
            feeds.push(f);
        }
        let mut out = Vec::new();
        let mut chunk = [0.0f32; 960];
        let mut first = [0u64; 3];
        for f in 0..50 {
            for (i, (feed, &(rate, freq))) in feeds.iter_mut().zip(&peers).enumerate() {
                let pos = feed.push_frame(&tone(rate, freq, f), 2, f == 0).unwrap();
                // The first frame after one frame of silence (two ahead; a resampled peer's
                // later by its resampler's delay), then 960 a frame.
                if f == 0 {
                    first[i] = pos;
                }
                assert_eq!(pos, first[i] + 960 * f as u64);
            }
            mixer.mix(&mut chunk);
            out.extend_from_slice(&chunk);
        }
        assert_eq!(first[2], 960, "the 48 kHz peer is not resampled");
        assert!(first[0] > 960 && first[1] > 960);
        assert_eq!(mixer.position(), 50 * 960);
        let steady = &out[48_000 / 4..];
        let a = tone_amplitude(steady, 48_000.0, 6000.0);
        assert!((a - 8000.0 / 32768.0).abs() < 0.02, "6 kHz at {a}");
        assert!(tone_amplitude(steady, 48_000.0, 1000.0) < 0.005);
    }

    #[test]
    fn a_resampled_peer_is_heard_at_the_position_its_frame_was_tagged_with() {
        // A click at the start of frame 10 of an 8 kHz and of a 16 kHz peer: in a 48 kHz mix it
        // begins where the position push_frame returned for that frame says (the resampler's
        // delay included), within a millisecond, so the mouth's row is shown with it.
        for rate in [8000u32, 16_000, 44_100, 48_000] {
            let mut mixer = Mixer::at_rate(48_000);
            let (mut feed, m, _) =
                peer_channel_at(PeerId(1), 48_000, 48_000, Arc::new(PeerControls::default()));
            mixer.add(m).unwrap();
            let n = rate as usize / 50;
            let mut out = Vec::new();
            let mut chunk = [0.0f32; 960];
            let mut tagged = 0;
            for f in 0..20 {
                let mut pcm = vec![0i16; n];
                if f == 10 {
                    pcm[..n / 4].fill(20_000);
                }
                let pos = feed
                    .push_frame(&FrameAudio::from_slice(rate, &pcm), 2, f == 0)
                    .unwrap();
                if f == 10 {
                    tagged = pos;
                }
                mixer.mix(&mut chunk);
                out.extend_from_slice(&chunk);
            }
            let onset = out.iter().position(|s| s.abs() > 0.3).unwrap() as i64;
            let off_ms = (onset - tagged as i64) as f64 / 48.0;
            assert!(
                off_ms.abs() <= 1.0,
                "{rate} Hz: heard {off_ms:.2} ms after its tag"
            );
        }
    }

    #[test]
    fn a_mixer_mixes_half_frames_and_knows_when_a_heard_peer_waits_for_its_next_frame() {
        let mut mixer = Mixer::at_rate(48_000);
        assert_eq!((mixer.chunk_len(), mixer.piece_len()), (960, 480));
        // 22.05 kHz has no whole 10 ms: it mixes whole frames.
        assert_eq!(Mixer::at_rate(22_050).piece_len(), 441);
        let progress = mixer.progress();
        let c = Arc::new(PeerControls::default());
        let (mut feed, mp, mut clock) = peer_channel_at(PeerId(1), 48_000, 48_000, c.clone());
        mixer.add(mp).unwrap();
        let mut piece = [0.0f32; 480];
        // Never heard: nothing to wait for.
        assert!(!mixer.awaits_peer(480));
        assert_eq!(feed.push_paced(&[1000; 960], 1, true), Some(0));
        mixer.mix(&mut piece);
        assert_eq!((progress.samples(), progress.chunks()), (480, 0));
        assert!(!mixer.awaits_peer(480), "half a frame still queued");
        mixer.mix(&mut piece);
        assert_eq!((progress.samples(), progress.chunks()), (960, 1));
        assert!(
            mixer.awaits_peer(480),
            "heard, and its next frame not queued"
        );
        assert_eq!(feed.push_paced(&[2000; 960], 1, false), Some(960));
        assert!(!mixer.awaits_peer(480));
        mixer.mix(&mut piece);
        assert!(piece.iter().all(|&s| (s - 2000.0 / 32768.0).abs() < 1e-6));
        assert_eq!(clock.stream_position(960 + 5), Some(965));
        // Mixed without it (its talk spurt ended): no longer awaited.
        mixer.mix(&mut piece);
        mixer.mix(&mut piece);
        assert_eq!(c.starved(), 480);
        assert!(!mixer.awaits_peer(480));
    }

    /// A 48 kHz mixer with one 48 kHz peer: its feed, the mixer, its controls and its clock.
    fn one_peer_at_48_khz(id: u32) -> (PeerFeed, Mixer, Arc<PeerControls>, PeerClock) {
        let c = Arc::new(PeerControls::default());
        let (feed, mp, clock) = peer_channel_at(PeerId(id), 48_000, 48_000, c.clone());
        let mut mixer = Mixer::at_rate(48_000);
        mixer.add(mp).unwrap();
        (feed, mixer, c, clock)
    }

    #[test]
    fn a_queue_left_a_frame_long_by_a_starved_mix_sheds_it_in_a_quiet_frame() {
        let (mut feed, mut mixer, c, _clock) = one_peer_at_48_khz(2);
        let mut frame = [0.0f32; 960];
        feed.push_paced(&[3000; 960], 1, true);
        mixer.mix(&mut frame);
        // The puller was held up: the mixer played a frame of silence for this peer, so the
        // frame pulled now finds the next already queued behind it, a frame more than the lead.
        mixer.mix(&mut frame);
        assert_eq!(c.starved(), 960);
        feed.push_paced(&[3000; 960], 1, false);
        feed.push_paced(&[3000; 960], 1, false);
        assert_eq!(feed.queued(), 2 * 960);
        mixer.mix(&mut frame);
        // Speech is kept whatever the surplus; the next near-silent frame (codec noise) is shed.
        assert!(feed.push_paced(&[3000; 960], 1, false).is_some());
        mixer.mix(&mut frame);
        let noise: Vec<i16> = (0..960).map(|i| [-30, 20, 40, -10][i % 4]).collect();
        assert_eq!(feed.push_paced(&noise, 1, false), None);
        assert_eq!((c.shed(), feed.queued()), (960, 960));
        // Back at its lead: quiet frames are queued again.
        mixer.mix(&mut frame);
        assert!(feed.push_paced(&noise, 1, false).is_some());
        assert_eq!(c.shed(), 960);
    }

    #[test]
    fn a_peer_that_starts_half_way_through_a_mixed_frame_sheds_the_half_in_a_quiet_frame() {
        let (mut feed, mut mixer, c, _clock) = one_peer_at_48_khz(4);
        let mut piece = [0.0f32; 480];
        mixer.mix(&mut piece);
        // Its first frame comes with the mixer a piece into its frame: from then on each frame
        // is pulled with half the last still queued, 10 ms of latency for the whole call.
        feed.push_paced(&[3000; 960], 1, true);
        mixer.mix(&mut piece);
        assert_eq!(feed.push_paced(&[3000; 960], 1, false), Some(960));
        assert_eq!(feed.queued(), 1440);
        mixer.mix(&mut piece);
        mixer.mix(&mut piece);
        // A near-silent frame: its first half is shed, its second queued where it is heard.
        let noise: Vec<i16> = (0..960).map(|i| [-30, 20, 40, -10][i % 4]).collect();
        assert_eq!(feed.push_paced(&noise, 1, false), Some(1920));
        assert_eq!((c.shed(), feed.queued()), (480, 960));
        // In step with the mixer again: nothing more is shed.
        mixer.mix(&mut piece);
        mixer.mix(&mut piece);
        assert_eq!(feed.queued(), 0);
        assert_eq!(feed.push_paced(&noise, 1, false), Some(2400));
        assert_eq!(c.shed(), 480);
    }

    #[test]
    fn peers_come_and_go() {
        let mut mixer = Mixer::new();
        for i in 0..MAX_PEERS as u32 {
            mixer.add(peer(i).1).unwrap();
        }
        assert!(mixer.add(peer(999).1).is_err());
        assert!(mixer.remove(PeerId(3)).is_some());
        assert!(mixer.remove(PeerId(3)).is_none());
        assert_eq!(mixer.peer_count(), MAX_PEERS - 1);
    }

    /// Magnitude of `freq` in `x` at `rate` (single-bin DFT), normalised to amplitude.
    fn tone_amplitude(x: &[f32], rate: f32, freq: f32) -> f32 {
        let (mut re, mut im) = (0.0f64, 0.0f64);
        for (i, &s) in x.iter().enumerate() {
            let ph = 2.0 * std::f64::consts::PI * f64::from(freq) * i as f64 / f64::from(rate);
            re += f64::from(s) * ph.cos();
            im += f64::from(s) * ph.sin();
        }
        (2.0 * (re * re + im * im).sqrt() / x.len() as f64) as f32
    }

    #[test]
    fn upsampling_keeps_a_tone_at_48k_and_44k1() {
        for rate in [48_000u32, 44_100] {
            let mut up = Upsampler::new(rate).unwrap();
            let mut out = Vec::new();
            for c in 0..50 {
                let mut chunk = [0.0f32; CHUNK];
                for (i, s) in chunk.iter_mut().enumerate() {
                    let n = (c * CHUNK + i) as f32;
                    *s = 0.5 * (2.0 * std::f32::consts::PI * 1000.0 * n / 8000.0).sin();
                }
                let expected = up.next_len();
                let o = up.process(&chunk).unwrap();
                assert_eq!(o.len(), expected);
                out.extend_from_slice(o);
            }
            // Steady state, past the delay: the 1 kHz tone at amplitude 0.5, nothing at 3 kHz.
            let steady = &out[rate as usize / 4..];
            let a = tone_amplitude(steady, rate as f32, 1000.0);
            assert!((a - 0.5).abs() < 0.02, "{rate}: {a}");
            assert!(tone_amplitude(steady, rate as f32, 3000.0) < 0.01);
        }
    }
}

//! Per-peer 8 kHz queues and the mixer that sums them, then resamples to the device rate.
//!
//! The decoder thread of each peer pushes PCM into its own ring ([`PeerFeed`]); the mixer thread
//! pops a chunk from every peer, applies volume and mute, sums, clips and resamples. Nothing
//! here runs in the device callback, so peers come and go through plain ownership moves.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

use rubato::audioadapter_buffers::direct::InterleavedSlice;
use rubato::{Fft, FixedSync, Resampler};

use super::clock::{PeerClock, Segment};
use super::error::AudioError;
use super::resample::fft_resampler;
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// Samples of the 8 kHz mix produced per step (one Speex frame, 20 ms).
pub const CHUNK: usize = FRAME_SIZE;
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
}

impl Default for PeerControls {
    fn default() -> Self {
        Self {
            volume_bits: AtomicU32::new(1.0f32.to_bits()),
            muted: AtomicBool::new(false),
            overflow: AtomicU64::new(0),
            starved: AtomicU64::new(0),
            lost_segments: AtomicU64::new(0),
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
}

/// The decoder thread's end of a peer's queue. Never blocks: what does not fit is dropped and
/// counted.
#[derive(Debug)]
pub struct PeerFeed {
    id: PeerId,
    tx: rtrb::Producer<i16>,
    written: u64,
    controls: Arc<PeerControls>,
}

impl PeerFeed {
    pub fn id(&self) -> PeerId {
        self.id
    }

    /// Queues decoded samples. Returns the stream position of the first sample queued (tag the
    /// frame's weights with it) and how many were queued.
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
    /// already `ahead + 2` frames long (an output that takes nothing) takes nothing more. The
    /// stream position of the frame's first sample, or `None` if it was not queued.
    pub fn push_paced(&mut self, pcm: &[i16], ahead: usize, resuming: bool) -> Option<u64> {
        const SILENCE: [i16; CHUNK] = [0; CHUNK];
        let queued = self.queued();
        if queued >= (ahead + 2) * CHUNK {
            return None;
        }
        if resuming {
            let mut pad = (ahead.saturating_sub(1) * CHUNK).saturating_sub(queued);
            while pad > 0 {
                let n = pad.min(CHUNK);
                self.push(&SILENCE[..n]);
                pad -= n;
            }
        }
        Some(self.push(pcm).0)
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
}

impl MixerPeer {
    pub fn id(&self) -> PeerId {
        self.id
    }
}

/// Creates the three ends of a peer: the decoder's feed, the mixer's queue and the reader's
/// clock. `queue` is the queue's capacity in 8 kHz samples.
pub fn peer_channel(
    id: PeerId,
    queue: usize,
    controls: Arc<PeerControls>,
) -> (PeerFeed, MixerPeer, PeerClock) {
    let (tx, rx) = rtrb::RingBuffer::new(queue.max(CHUNK));
    // Segments are per chunk: room for 10 s unread before the mapping loses any.
    let (seg_tx, seg_rx) = rtrb::RingBuffer::new(500);
    (
        PeerFeed {
            id,
            tx,
            written: 0,
            controls: controls.clone(),
        },
        MixerPeer {
            id,
            rx,
            controls,
            stream_pos: 0,
            segments: seg_tx,
        },
        PeerClock::new(Some(seg_rx)),
    )
}

/// The chunks a mixer has mixed so far, for the thread that feeds its peers: the output's
/// demand (see [`super::pacer::FramePacer`]). A clone reads the same count.
#[derive(Debug, Clone, Default)]
pub struct MixProgress(Arc<AtomicU64>);

impl MixProgress {
    pub fn chunks(&self) -> u64 {
        self.0.load(Ordering::Acquire)
    }
}

/// Sums the peers' 8 kHz streams into one mix, chunk by chunk.
#[derive(Debug)]
pub struct Mixer {
    peers: Vec<MixerPeer>,
    position: u64,
    progress: MixProgress,
}

impl Default for Mixer {
    fn default() -> Self {
        Self::new()
    }
}

impl Mixer {
    pub fn new() -> Self {
        Self {
            peers: Vec::with_capacity(MAX_PEERS),
            position: 0,
            progress: MixProgress::default(),
        }
    }

    /// Its count of chunks mixed, readable from other threads.
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

    /// Mix position of the next chunk (8 kHz samples mixed so far).
    pub fn position(&self) -> u64 {
        self.position
    }

    /// Mixes the next chunk into `out` (in -1..=1, clipped). Every peer's queue is read even
    /// when muted, so its stream keeps time with what the others hear.
    pub fn mix(&mut self, out: &mut [f32; CHUNK]) {
        out.fill(0.0);
        let mix_start = self.position;
        for p in &mut self.peers {
            let gain = if p.controls.muted() {
                0.0
            } else {
                p.controls.volume() / 32768.0
            };
            let n = p.rx.slots().min(CHUNK);
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
            if n < CHUNK && p.stream_pos + n as u64 > 0 {
                p.controls
                    .starved
                    .fetch_add((CHUNK - n) as u64, Ordering::Relaxed);
            }
            p.stream_pos += n as u64;
        }
        for o in out.iter_mut() {
            *o = o.clamp(-1.0, 1.0);
        }
        self.position += CHUNK as u64;
        self.progress
            .0
            .store(self.position / CHUNK as u64, Ordering::Release);
    }
}

/// 8 kHz -> device rate, one [`CHUNK`] at a time, into a buffer allocated once.
pub struct Upsampler {
    resampler: Option<Fft<f32>>,
    out: Vec<f32>,
    rate: u32,
}

impl std::fmt::Debug for Upsampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Upsampler")
            .field("rate", &self.rate)
            .finish()
    }
}

impl Upsampler {
    pub fn new(rate: u32) -> Result<Self, AudioError> {
        let resampler = fft_resampler(SAMPLE_RATE, rate, CHUNK, FixedSync::Input)?;
        let max = resampler.as_ref().map_or(CHUNK, |r| r.output_frames_max());
        Ok(Self {
            resampler,
            out: vec![0.0; max],
            rate,
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
            .map_or(CHUNK, |r| r.output_frames_next())
    }

    /// Resamples one chunk; the returned slice lives until the next call.
    pub fn process(&mut self, input: &[f32; CHUNK]) -> Result<&[f32], AudioError> {
        let err = |e: &dyn std::fmt::Display| AudioError::Resampler(e.to_string());
        let Some(r) = self.resampler.as_mut() else {
            self.out[..CHUNK].copy_from_slice(input);
            return Ok(&self.out[..CHUNK]);
        };
        let frames_out = self.out.len();
        let inp = InterleavedSlice::new(&input[..], 1, CHUNK).map_err(|e| err(&e))?;
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

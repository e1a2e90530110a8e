//! Microphone capture: device callback -> ring -> frames at the encoder's rate (48 kHz for
//! Opus, 16 kHz for G.722 and Speex wideband, 8 kHz for the narrowband codecs) and of the
//! encoder's length (20 ms, or Opus's 10 ms).
//!
//! The callback ([`InputFeeder`]) converts whatever the device delivers to f32 mono, updates the
//! level meter (atomics), pushes into an rtrb ring (on a full ring it drops and counts) and
//! wakes the reader's thread. The encoder thread's side ([`FrameReader`]) resamples in one step
//! to the encoder's rate with buffers allocated once and hands out frames of the length the
//! encoder takes, each gated by mute and push-to-talk: a 10 ms packet leaves as soon as its
//! 10 ms are in, not with the next one.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use cpal::traits::{DeviceTrait, StreamTrait};
use cpal::{FromSample, Sample, SizedSample};
use rubato::audioadapter_buffers::direct::InterleavedSlice;
use rubato::{Fft, FixedSync, Resampler};

use super::devices::{self, DeviceChoice, Direction};
use super::error::AudioError;
use super::resample::fft_resampler;
use crate::vocab::{FRAME_SIZE, SAMPLE_RATE};

/// The frame lengths the reader hands out, ms: the 20 ms of every codec, Opus's 10.
const FRAME_MS: [u8; 2] = [10, 20];

/// Level floor: what silence reads as.
pub const LEVEL_FLOOR_DBFS: f32 = -100.0;

#[derive(Debug)]
struct MicShared {
    peak_bits: AtomicU32,
    rms_bits: AtomicU32,
    muted: AtomicBool,
    push_to_talk: AtomicBool,
    talk_pressed: AtomicBool,
    dropped: AtomicU64,
    lost: AtomicBool,
    errors: AtomicU64,
    /// The thread that reads frames, woken after every device buffer.
    reader: OnceLock<std::thread::Thread>,
}

impl Default for MicShared {
    fn default() -> Self {
        Self {
            peak_bits: AtomicU32::new(LEVEL_FLOOR_DBFS.to_bits()),
            rms_bits: AtomicU32::new(LEVEL_FLOOR_DBFS.to_bits()),
            muted: AtomicBool::new(false),
            push_to_talk: AtomicBool::new(false),
            talk_pressed: AtomicBool::new(false),
            dropped: AtomicU64::new(0),
            lost: AtomicBool::new(false),
            errors: AtomicU64::new(0),
            reader: OnceLock::new(),
        }
    }
}

/// The microphone's level over the last device buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    pub peak_dbfs: f32,
    pub rms_dbfs: f32,
}

/// The UI's handle on the microphone: meter, mute, push-to-talk. Cheap to clone, all atomics.
#[derive(Debug, Clone, Default)]
pub struct MicControls(Arc<MicShared>);

impl MicControls {
    pub fn level(&self) -> Level {
        Level {
            peak_dbfs: f32::from_bits(self.0.peak_bits.load(Ordering::Relaxed)),
            rms_dbfs: f32::from_bits(self.0.rms_bits.load(Ordering::Relaxed)),
        }
    }

    pub fn set_muted(&self, m: bool) {
        self.0.muted.store(m, Ordering::Relaxed);
    }

    pub fn muted(&self) -> bool {
        self.0.muted.load(Ordering::Relaxed)
    }

    /// In push-to-talk mode the voice goes out only while the talk key is held.
    pub fn set_push_to_talk(&self, on: bool) {
        self.0.push_to_talk.store(on, Ordering::Relaxed);
    }

    pub fn push_to_talk(&self) -> bool {
        self.0.push_to_talk.load(Ordering::Relaxed)
    }

    pub fn set_talk_pressed(&self, down: bool) {
        self.0.talk_pressed.store(down, Ordering::Relaxed);
    }

    /// Whether frames read now go out.
    pub fn transmitting(&self) -> bool {
        !self.muted() && (!self.push_to_talk() || self.0.talk_pressed.load(Ordering::Relaxed))
    }

    /// Device samples dropped because the ring was full (the encoder side fell behind).
    pub fn dropped(&self) -> u64 {
        self.0.dropped.load(Ordering::Relaxed)
    }

    /// True once the device reported that it is gone.
    pub fn lost(&self) -> bool {
        self.0.lost.load(Ordering::Relaxed)
    }
}

fn dbfs(x: f32) -> f32 {
    if x > 0.0 {
        (20.0 * x.log10()).max(LEVEL_FLOOR_DBFS)
    } else {
        LEVEL_FLOOR_DBFS
    }
}

/// The capture callback's state. `feed` never blocks, locks or allocates.
#[derive(Debug)]
pub struct InputFeeder {
    ring: rtrb::Producer<f32>,
    shared: Arc<MicShared>,
    channels: usize,
}

impl InputFeeder {
    /// Takes one interleaved device buffer.
    pub fn feed<T>(&mut self, data: &[T])
    where
        T: Sample,
        f32: FromSample<T>,
    {
        let ch = self.channels.max(1);
        let frames = data.len() / ch;
        let scale = 1.0 / ch as f32;
        let mono = |f: &[T]| f.iter().map(|&s| f32::from_sample(s)).sum::<f32>() * scale;
        let (mut peak, mut sq) = (0.0f32, 0.0f64);
        for f in data.chunks_exact(ch) {
            let m = mono(f);
            peak = peak.max(m.abs());
            sq += f64::from(m * m);
        }
        if frames > 0 {
            self.shared
                .peak_bits
                .store(dbfs(peak).to_bits(), Ordering::Relaxed);
            let rms = (sq / frames as f64).sqrt() as f32;
            self.shared
                .rms_bits
                .store(dbfs(rms).to_bits(), Ordering::Relaxed);
        }
        let n = self.ring.slots().min(frames);
        if let Ok(mut chunk) = self.ring.write_chunk(n) {
            let (a, b) = chunk.as_mut_slices();
            for (o, f) in a.iter_mut().chain(b.iter_mut()).zip(data.chunks_exact(ch)) {
                *o = mono(f);
            }
            chunk.commit_all();
        }
        if n < frames {
            self.shared
                .dropped
                .fetch_add((frames - n) as u64, Ordering::Relaxed);
        }
        // An atomic swap and at most a futex wake: no lock, no allocation.
        if let Some(t) = self.shared.reader.get() {
            t.unpark();
        }
    }
}

/// Device rate -> the encoder's rate (8 kHz unless told another), one frame (20 ms unless told
/// 10) at a time, buffers allocated once.
pub struct Downsampler {
    resampler: Option<Fft<f32>>,
    input: Vec<f32>,
    output: Vec<f32>,
    /// Samples of one output frame.
    frame: usize,
    rate: u32,
}

impl std::fmt::Debug for Downsampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Downsampler").finish_non_exhaustive()
    }
}

impl Downsampler {
    pub fn new(rate: u32) -> Result<Self, AudioError> {
        Self::to_rate(rate, SAMPLE_RATE)
    }

    /// From the device's `rate` to 20 ms frames at `out` (8 kHz to 48 kHz).
    pub fn to_rate(rate: u32, out: u32) -> Result<Self, AudioError> {
        Self::framed(rate, out, 20)
    }

    /// From the device's `rate` to frames of `frame_ms` (10 or 20) at `out` (8 kHz to 48 kHz).
    pub fn framed(rate: u32, out: u32, frame_ms: u8) -> Result<Self, AudioError> {
        if !crate::vocab::audio::valid_rate(out) || !FRAME_MS.contains(&frame_ms) {
            return Err(AudioError::Resampler(format!(
                "no {frame_ms} ms frames at {out} Hz"
            )));
        }
        let frame = out as usize * usize::from(frame_ms) / 1000;
        let resampler = fft_resampler(rate, out, frame, FixedSync::Output)?;
        let (imax, omax) = resampler.as_ref().map_or((frame, frame), |r| {
            (r.input_frames_max(), r.output_frames_max())
        });
        Ok(Self {
            resampler,
            input: vec![0.0; imax],
            output: vec![0.0; omax],
            frame,
            rate: out,
        })
    }

    /// The rate of the frames it gives.
    pub fn rate(&self) -> u32 {
        self.rate
    }

    /// The length of the frames it gives, ms.
    pub fn frame_ms(&self) -> u8 {
        (self.frame * 1000 / self.rate as usize) as u8
    }

    /// Device samples the next frame needs.
    pub fn needed(&self) -> usize {
        self.resampler
            .as_ref()
            .map_or(self.frame, |r| r.input_frames_next())
    }

    /// Output (8 kHz) samples of delay.
    pub fn delay(&self) -> usize {
        self.resampler.as_ref().map_or(0, |r| r.output_delay())
    }

    /// Resamples exactly [`Self::needed`] samples from the ring into `out`; `false` (nothing
    /// consumed) when the ring holds fewer.
    fn process_from(
        &mut self,
        ring: &mut rtrb::Consumer<f32>,
        out: &mut [f32],
    ) -> Result<bool, AudioError> {
        let need = self.needed();
        let Ok(chunk) = ring.read_chunk(need) else {
            return Ok(false);
        };
        let (a, b) = chunk.as_slices();
        self.input[..a.len()].copy_from_slice(a);
        self.input[a.len()..need].copy_from_slice(b);
        chunk.commit_all();
        self.process(need, out)?;
        Ok(true)
    }

    /// Resamples the first `n` samples of the internal input buffer (tests and benches fill it
    /// through [`Self::process_slice`]).
    fn process(&mut self, n: usize, out: &mut [f32]) -> Result<(), AudioError> {
        let err = |e: &dyn std::fmt::Display| AudioError::Resampler(e.to_string());
        if out.len() != self.frame {
            return Err(AudioError::Resampler(format!(
                "a frame of {} samples where {} ms at {} Hz is {}",
                out.len(),
                self.frame_ms(),
                self.rate,
                self.frame
            )));
        }
        let Some(r) = self.resampler.as_mut() else {
            out.copy_from_slice(&self.input[..self.frame]);
            return Ok(());
        };
        let olen = self.output.len();
        let inp = InterleavedSlice::new(&self.input[..], 1, n).map_err(|e| err(&e))?;
        let mut outp =
            InterleavedSlice::new_mut(&mut self.output[..], 1, olen).map_err(|e| err(&e))?;
        let (_, got) = r
            .process_into_buffer(&inp, &mut outp, None)
            .map_err(|e| err(&e))?;
        out.fill(0.0);
        let got = got.min(self.frame);
        out[..got].copy_from_slice(&self.output[..got]);
        Ok(())
    }

    /// Resamples `input` (exactly [`Self::needed`] samples) into one frame.
    pub fn process_slice(&mut self, input: &[f32], out: &mut [f32]) -> Result<(), AudioError> {
        let need = self.needed();
        if input.len() != need {
            return Err(AudioError::Resampler(format!(
                "expected {need} input samples, got {}",
                input.len()
            )));
        }
        self.input[..need].copy_from_slice(input);
        self.process(need, out)
    }
}

/// Whether a frame goes out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gate {
    /// Voice: encode and send.
    Open,
    /// Muted, or push-to-talk with the key up: the frame is silence; send nothing (or DTX).
    Closed,
}

/// The encoder thread's end: frames out of the ring, 20 ms at 8 kHz until told the encoder's
/// rate and frame length ([`FrameReader::set_format`]).
#[derive(Debug)]
pub struct FrameReader {
    ring: rtrb::Consumer<f32>,
    down: Downsampler,
    device_rate: u32,
    controls: MicControls,
    frame: Vec<f32>,
}

impl FrameReader {
    /// Frames at `rate` from now on (Opus's 48 kHz, G.722's 16 kHz, ...), of the length they
    /// had. On an error the rate stays as it was.
    pub fn set_rate(&mut self, rate: u32) -> Result<(), AudioError> {
        self.set_format(rate, self.frame_ms())
    }

    /// Frames of `frame_ms` (10 or 20) at `rate` from now on: what the encoder takes. On an
    /// error the format stays as it was. What the ring holds is kept (the new frames start
    /// where the old ones stopped), but a resampler's history is not.
    pub fn set_format(&mut self, rate: u32, frame_ms: u8) -> Result<(), AudioError> {
        if rate != self.down.rate() || frame_ms != self.down.frame_ms() {
            self.down = Downsampler::framed(self.device_rate, rate, frame_ms)?;
            self.frame = vec![0.0; rate as usize * usize::from(frame_ms) / 1000];
        }
        Ok(())
    }

    /// The rate of the frames it gives.
    pub fn rate(&self) -> u32 {
        self.down.rate()
    }

    /// The length of the frames it gives, ms.
    pub fn frame_ms(&self) -> u8 {
        self.down.frame_ms()
    }

    /// Has the device's callback wake the calling thread after every buffer it delivers, so
    /// that a reader parked between looks ([`std::thread::park_timeout`]) takes each frame as
    /// it completes. The first thread to ask is the one woken.
    pub fn wake_me(&self) {
        self.controls.0.reader.get_or_init(std::thread::current);
    }

    /// Samples in one of its frames.
    pub fn frame_samples(&self) -> usize {
        self.frame.len()
    }

    /// The next frame into `out` ([`FrameReader::frame_samples`] long), `None` until the
    /// device has delivered enough. Never blocks: poll it every few milliseconds, or when woken
    /// ([`FrameReader::wake_me`]), and take frames while it yields.
    pub fn read_frame(&mut self, out: &mut [i16]) -> Result<Option<Gate>, AudioError> {
        if out.len() != self.frame.len() {
            return Err(AudioError::Resampler(format!(
                "a frame of {} samples where {} ms is {}",
                out.len(),
                self.frame_ms(),
                self.frame.len()
            )));
        }
        if !self.down.process_from(&mut self.ring, &mut self.frame)? {
            return Ok(None);
        }
        if !self.controls.transmitting() {
            out.fill(0);
            return Ok(Some(Gate::Closed));
        }
        for (o, &s) in out.iter_mut().zip(&self.frame) {
            *o = (s * 32768.0).round().clamp(-32768.0, 32767.0) as i16;
        }
        Ok(Some(Gate::Open))
    }

    pub fn controls(&self) -> &MicControls {
        &self.controls
    }
}

/// A capture pipeline without a device: the feeder for a callback and the reader for the
/// encoder. `ring` is the ring's length at `rate`.
pub fn capture_pipeline(
    rate: u32,
    channels: u16,
    ring: Duration,
) -> Result<(InputFeeder, FrameReader), AudioError> {
    let controls = MicControls::default();
    let down = Downsampler::new(rate)?;
    let cap = ((ring.as_secs_f64() * f64::from(rate)) as usize).max(2 * down.needed());
    let (tx, rx) = rtrb::RingBuffer::new(cap);
    Ok((
        InputFeeder {
            ring: tx,
            shared: controls.0.clone(),
            channels: usize::from(channels),
        },
        FrameReader {
            ring: rx,
            down,
            device_rate: rate,
            controls,
            frame: vec![0.0; FRAME_SIZE],
        },
    ))
}

/// A running microphone.
pub struct Capture {
    _stream: cpal::Stream,
    reader: FrameReader,
    device: String,
    rate: u32,
    channels: u16,
}

impl std::fmt::Debug for Capture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Capture")
            .field("device", &self.device)
            .field("rate", &self.rate)
            .field("channels", &self.channels)
            .finish()
    }
}

fn build_input<T>(
    device: &cpal::Device,
    config: cpal::StreamConfig,
    mut feeder: InputFeeder,
    shared: Arc<MicShared>,
) -> Result<cpal::Stream, cpal::Error>
where
    T: SizedSample,
    f32: FromSample<T>,
{
    device.build_input_stream::<T, _, _>(
        config,
        move |data: &[T], _: &cpal::InputCallbackInfo| feeder.feed(data),
        move |e: cpal::Error| {
            shared.errors.fetch_add(1, Ordering::Relaxed);
            if matches!(
                e.kind(),
                cpal::ErrorKind::DeviceNotAvailable | cpal::ErrorKind::StreamInvalidated
            ) {
                shared.lost.store(true, Ordering::Relaxed);
            }
        },
        None,
    )
}

impl Capture {
    /// Opens the microphone at its native format. An error means no capture: the app goes on
    /// receive-only and shows the error's line.
    pub fn start(choice: &DeviceChoice) -> Result<Self, AudioError> {
        let opened = devices::open(choice, Direction::Input)?;
        let rate = opened.config.sample_rate();
        let channels = opened.config.channels();
        let format = opened.config.sample_format();
        let mut config: cpal::StreamConfig = opened.config.config();
        if let Some(period) =
            devices::period(opened.config.buffer_size(), rate, Duration::from_millis(10))
        {
            config.buffer_size = cpal::BufferSize::Fixed(period);
        }
        let (feeder, reader) = capture_pipeline(rate, channels, Duration::from_millis(500))?;
        let shared = reader.controls.0.clone();
        let d = &opened.device;
        use cpal::SampleFormat as F;
        let stream = match format {
            F::F32 => build_input::<f32>(d, config, feeder, shared),
            F::F64 => build_input::<f64>(d, config, feeder, shared),
            F::I16 => build_input::<i16>(d, config, feeder, shared),
            F::U16 => build_input::<u16>(d, config, feeder, shared),
            F::I32 => build_input::<i32>(d, config, feeder, shared),
            F::U32 => build_input::<u32>(d, config, feeder, shared),
            F::I8 => build_input::<i8>(d, config, feeder, shared),
            F::U8 => build_input::<u8>(d, config, feeder, shared),
            other => return Err(AudioError::UnsupportedFormat(other.to_string())),
        }
        .map_err(|e| devices::no_device(Direction::Input, e.to_string()))?;
        stream
            .play()
            .map_err(|e| devices::no_device(Direction::Input, e.to_string()))?;
        Ok(Self {
            _stream: stream,
            reader,
            device: opened.name,
            rate,
            channels,
        })
    }

    /// See [`FrameReader::read_frame`].
    pub fn read_frame(&mut self, out: &mut [i16]) -> Result<Option<Gate>, AudioError> {
        self.reader.read_frame(out)
    }

    /// See [`FrameReader::set_rate`].
    pub fn set_rate(&mut self, rate: u32) -> Result<(), AudioError> {
        self.reader.set_rate(rate)
    }

    /// See [`FrameReader::set_format`].
    pub fn set_format(&mut self, rate: u32, frame_ms: u8) -> Result<(), AudioError> {
        self.reader.set_format(rate, frame_ms)
    }

    /// See [`FrameReader::wake_me`].
    pub fn wake_me(&self) {
        self.reader.wake_me();
    }

    /// Samples in one of its frames.
    pub fn frame_samples(&self) -> usize {
        self.reader.frame_samples()
    }

    /// The length of one of its frames, ms.
    pub fn frame_ms(&self) -> u8 {
        self.reader.frame_ms()
    }

    pub fn controls(&self) -> MicControls {
        self.reader.controls.clone()
    }

    pub fn device_name(&self) -> &str {
        &self.device
    }

    /// The device's native rate and channel count.
    pub fn format(&self) -> (u32, u16) {
        (self.rate, self.channels)
    }

    /// True once the device has gone: drop this and go on receive-only.
    pub fn lost(&self) -> bool {
        self.reader.controls.lost()
    }
}

#[cfg(test)]
mod tests {
    use super::super::mixer::{CHUNK, Upsampler};
    use super::*;

    fn tone(rate: u32, freq: f32, amp: f32, n: usize, offset: usize) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let t = (i + offset) as f32 / rate as f32;
                amp * (2.0 * std::f32::consts::PI * freq * t).sin()
            })
            .collect()
    }

    #[test]
    fn frames_come_at_the_encoders_rate_in_one_resampling_step() {
        // A 44.1 kHz microphone read for Opus (48 kHz) and for G.722 (16 kHz): a 9 kHz tone,
        // above any narrowband, comes through at its level where the rate can carry it.
        for (out_rate, carries) in [(48_000, true), (16_000, false), (8000, false)] {
            let (mut feeder, mut reader) =
                capture_pipeline(44_100, 1, Duration::from_secs(2)).unwrap();
            reader.set_rate(out_rate).unwrap();
            assert_eq!(reader.rate(), out_rate);
            let n = out_rate as usize / 50;
            assert_eq!(reader.frame_samples(), n);
            let mut wrong = vec![0i16; n + 1];
            assert!(reader.read_frame(&mut wrong).is_err());
            for block in tone(44_100, 9000.0, 0.5, 44_100, 0).chunks(441) {
                feeder.feed(block);
            }
            let mut frame = vec![0i16; n];
            let mut got = Vec::new();
            while let Some(gate) = reader.read_frame(&mut frame).unwrap() {
                assert_eq!(gate, Gate::Open);
                got.extend_from_slice(&frame);
            }
            assert!(got.len() >= 40 * n, "{out_rate}: {} samples", got.len());
            let tail = &got[got.len() / 2..];
            let rms = (tail.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / tail.len() as f64)
                .sqrt()
                / 32768.0;
            if carries {
                assert!(
                    (rms / (0.5 / 2f64.sqrt()) - 1.0).abs() < 0.05,
                    "{out_rate}: {rms}"
                );
            } else {
                assert!(rms < 0.01, "{out_rate}: 9 kHz leaked at {rms}");
            }
        }
        let (_, mut reader) = capture_pipeline(44_100, 1, Duration::from_secs(1)).unwrap();
        assert!(reader.set_rate(44_123).is_err());
        assert_eq!(reader.rate(), 8000);
    }

    #[test]
    fn stereo_i16_becomes_gated_8k_frames_with_a_meter() {
        let (mut feeder, mut reader) = capture_pipeline(48_000, 2, Duration::from_secs(1)).unwrap();
        let controls = reader.controls().clone();
        let mut out = [0i16; FRAME_SIZE];
        assert_eq!(reader.read_frame(&mut out).unwrap(), None);
        // Left carries a 440 Hz tone at -6 dBFS, right is silent: mono is -12 dBFS.
        let mono = tone(48_000, 440.0, 0.5, 48_000, 0);
        let stereo: Vec<i16> = mono
            .iter()
            .flat_map(|&s| [(s * 32767.0) as i16, 0])
            .collect();
        for block in stereo.chunks(960) {
            feeder.feed(block);
        }
        let level = controls.level();
        assert!((level.peak_dbfs + 12.04).abs() < 0.2, "{level:?}");
        assert!((level.rms_dbfs + 15.05).abs() < 0.2, "{level:?}");
        let mut frames = 0;
        let mut last_peak = 0;
        while let Some(g) = reader.read_frame(&mut out).unwrap() {
            assert_eq!(g, Gate::Open);
            frames += 1;
            last_peak = out.iter().map(|s| s.unsigned_abs()).max().unwrap_or(0);
        }
        assert_eq!(frames, 50);
        assert!((8000..8500).contains(&last_peak), "{last_peak}");
        // Mute, then push-to-talk: frames still flow (time goes on) but closed and silent.
        controls.set_muted(true);
        for block in stereo.chunks(1920).take(2) {
            feeder.feed(block);
        }
        assert_eq!(reader.read_frame(&mut out).unwrap(), Some(Gate::Closed));
        assert!(out.iter().all(|&s| s == 0));
        controls.set_muted(false);
        controls.set_push_to_talk(true);
        assert_eq!(reader.read_frame(&mut out).unwrap(), Some(Gate::Closed));
        controls.set_talk_pressed(true);
        feeder.feed(&stereo[..1920]);
        assert_eq!(reader.read_frame(&mut out).unwrap(), Some(Gate::Open));
        // Silence reads as the floor.
        feeder.feed(&[0i16; 64]);
        assert_eq!(controls.level().peak_dbfs, LEVEL_FLOOR_DBFS);
    }

    #[test]
    fn ten_ms_frames_come_as_each_10_ms_is_delivered() {
        // Opus's 10 ms frames from a 48 kHz microphone delivering 10 ms a callback: each
        // callback completes one frame; at 20 ms, every second one does.
        let (mut feeder, mut reader) = capture_pipeline(48_000, 1, Duration::from_secs(1)).unwrap();
        reader.set_format(48_000, 10).unwrap();
        assert_eq!((reader.frame_samples(), reader.frame_ms()), (480, 10));
        let mut frame = vec![0i16; 480];
        for k in 0..10 {
            feeder.feed(&tone(48_000, 440.0, 0.5, 480, 480 * k));
            assert_eq!(reader.read_frame(&mut frame).unwrap(), Some(Gate::Open));
            assert_eq!(reader.read_frame(&mut frame).unwrap(), None, "callback {k}");
        }
        // Back to 20 ms (a 20 ms encoder): a frame every second callback; a 16 kHz 10 ms frame
        // through a resampler comes too. Frame lengths other than 10 and 20 ms are refused.
        reader.set_format(48_000, 20).unwrap();
        let mut frame = vec![0i16; 960];
        let mut got = 0;
        for k in 0..10 {
            feeder.feed(&tone(48_000, 440.0, 0.5, 480, 480 * k));
            while reader.read_frame(&mut frame).unwrap().is_some() {
                got += 1;
            }
        }
        assert_eq!(got, 5);
        reader.set_format(16_000, 10).unwrap();
        assert_eq!(reader.frame_samples(), 160);
        assert!(reader.set_format(16_000, 15).is_err());
        assert_eq!((reader.rate(), reader.frame_ms()), (16_000, 10));
    }

    #[test]
    fn each_delivery_wakes_the_reader() {
        // The encoder's thread parks between looks; a callback's delivery unparks it.
        let (mut feeder, reader) = capture_pipeline(48_000, 1, Duration::from_secs(1)).unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let parked = std::thread::spawn(move || {
            reader.wake_me();
            tx.send(()).unwrap();
            let began = std::time::Instant::now();
            std::thread::park_timeout(Duration::from_secs(60));
            began.elapsed()
        });
        rx.recv().unwrap();
        std::thread::sleep(Duration::from_millis(50));
        feeder.feed(&[0.1f32; 480]);
        let waited = parked.join().unwrap();
        assert!(waited < Duration::from_secs(30), "woke after {waited:?}");
    }

    #[test]
    fn a_full_ring_drops_and_counts() {
        let (mut feeder, _reader) = capture_pipeline(8000, 1, Duration::from_millis(40)).unwrap();
        // Ring holds 2 frames (320 samples); 1000 pushed: 680 dropped.
        feeder.feed(&[0.1f32; 1000]);
        assert_eq!(feeder.shared.dropped.load(Ordering::Relaxed), 680);
    }

    #[test]
    fn chain_8k_48k_8k_keeps_a_tone() {
        let mut up = Upsampler::new(48_000).unwrap();
        let mut down = Downsampler::new(48_000).unwrap();
        let input = tone(8000, 700.0, 0.5, 8000, 0);
        let mut wide = Vec::new();
        for c in input.chunks_exact(CHUNK) {
            let mut chunk = [0.0; CHUNK];
            chunk.copy_from_slice(c);
            wide.extend_from_slice(up.process(&chunk).unwrap());
        }
        let mut back = Vec::new();
        let mut frame = [0.0; FRAME_SIZE];
        let mut at = 0;
        while at + down.needed() <= wide.len() {
            let n = down.needed();
            down.process_slice(&wide[at..at + n], &mut frame).unwrap();
            back.extend_from_slice(&frame);
            at += n;
        }
        let delay = up.delay() / 6 + down.delay();
        // Past the delays, the round trip matches the input sample for sample.
        let err = back[delay + 800..back.len() - 800]
            .iter()
            .zip(&input[800..])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(err < 0.02, "delay {delay}: max error {err}");
    }
}

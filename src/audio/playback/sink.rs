//! Where the mix goes: a device's output stream, whose callback copies from the ring and
//! publishes the clock, or a virtual sink that consumes the ring at the same pace and plays
//! nothing.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cpal::traits::{DeviceTrait, StreamTrait};
use cpal::{FromSample, Sample, SizedSample};

use crate::audio::clock::OutputClock;
use crate::audio::devices::{self, DeviceChoice, Direction};
use crate::audio::error::AudioError;

/// What the user hears.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OutputStatus {
    Playing {
        device: String,
        rate: u32,
        channels: u16,
    },
    /// No device: the engine runs on a virtual clock and plays nothing; `reason` is the line
    /// to show.
    Silent { reason: String },
}

/// Raised by the device's error callback (atomics only).
#[derive(Debug, Default)]
pub(super) struct Fault {
    pub(super) lost: AtomicBool,
    pub(super) errors: AtomicU64,
}

pub(super) enum Sink {
    Device {
        _stream: cpal::Stream,
        clock: Arc<OutputClock>,
        fault: Arc<Fault>,
    },
    Virtual {
        thread: Option<JoinHandle<()>>,
        stop: Arc<AtomicBool>,
        clock: Arc<OutputClock>,
    },
}

impl Sink {
    pub(super) fn clock(&self) -> &Arc<OutputClock> {
        match self {
            Sink::Device { clock, .. } | Sink::Virtual { clock, .. } => clock,
        }
    }
}

impl Drop for Sink {
    fn drop(&mut self) {
        if let Sink::Virtual { thread, stop, .. } = self {
            stop.store(true, Ordering::Relaxed);
            if let Some(t) = thread.take() {
                let _ = t.join();
            }
        }
    }
}

/// The output callback's state: a ring to copy from and a clock to publish to.
struct OutputState {
    ring: rtrb::Consumer<f32>,
    clock: Arc<OutputClock>,
    channels: usize,
    consumed: u64,
}

impl OutputState {
    /// Fills an interleaved buffer from the mono ring; silence where the ring runs short.
    /// No lock, no allocation, no system call beyond what the caller did to learn `heard_at`.
    fn fill<T: Sample + FromSample<f32>>(
        &mut self,
        data: &mut [T],
        heard_at: Instant,
        latency: Duration,
    ) {
        let ch = self.channels.max(1);
        let frames = data.len() / ch;
        let before = self.consumed;
        let n = self.ring.slots().min(frames);
        if let Ok(chunk) = self.ring.read_chunk(n) {
            let (a, b) = chunk.as_slices();
            for (frame, &s) in data.chunks_exact_mut(ch).zip(a.iter().chain(b)) {
                frame.fill(T::from_sample(s));
            }
            chunk.commit_all();
        }
        for frame in data.chunks_exact_mut(ch).skip(n) {
            frame.fill(T::EQUILIBRIUM);
        }
        self.consumed += n as u64;
        self.clock
            .publish(before, self.consumed, frames as u64, heard_at, latency);
    }
}

/// The period asked of an output device, and the virtual sink's.
pub(super) const PERIOD: Duration = Duration::from_millis(10);
/// The period assumed of a device that does not say what it supports.
const UNKNOWN_PERIOD: Duration = Duration::from_millis(20);

/// The ring's target fill and capacity, in device frames: one device period (what a callback
/// takes at once) plus `margin`. The mixer, woken by each callback, tops it up at once, so a
/// callback finds it short only when the mixer could not run for a whole period.
fn ring_capacity(
    rate: u32,
    period: usize,
    margin: Duration,
    chunk_out: usize,
) -> (RingTarget, usize) {
    let fill = period + (margin.as_secs_f64() * f64::from(rate)).ceil() as usize;
    let fill = fill.max(1);
    (RingTarget { fill, period }, 2 * fill + 2 * chunk_out)
}

/// How full the mixer keeps a sink's ring, in device frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct RingTarget {
    /// Topped up to this.
    pub(super) fill: usize,
    /// What one callback takes: a ring holding more may wait for a peer's frame.
    pub(super) period: usize,
}

fn frames_in(d: Duration, rate: u32) -> usize {
    (d.as_secs_f64() * f64::from(rate)).round() as usize
}

/// Device frames one 20 ms chunk of the mix can come to, whatever the mixer's rate.
fn chunk_out_len(rate: u32) -> usize {
    (rate as usize).div_ceil(50) + 1
}

fn build_output<T>(
    device: &cpal::Device,
    config: cpal::StreamConfig,
    mut state: OutputState,
    fault: Arc<Fault>,
) -> Result<cpal::Stream, cpal::Error>
where
    T: SizedSample + FromSample<f32>,
{
    device.build_output_stream::<T, _, _>(
        config,
        move |data: &mut [T], info: &cpal::OutputCallbackInfo| {
            let ts = info.timestamp();
            let latency = ts
                .playback
                .checked_duration_since(ts.callback)
                .unwrap_or_default();
            state.fill(data, Instant::now() + latency, latency);
        },
        move |e: cpal::Error| {
            fault.errors.fetch_add(1, Ordering::Relaxed);
            if matches!(
                e.kind(),
                cpal::ErrorKind::DeviceNotAvailable | cpal::ErrorKind::StreamInvalidated
            ) {
                fault.lost.store(true, Ordering::Relaxed);
            }
        },
        None,
    )
}

/// Opens the device, builds and starts its stream. Returns the sink, its ring's producer, the
/// target fill (a device period plus `margin`), and the status line.
pub(super) fn device_sink(
    choice: &DeviceChoice,
    margin: Duration,
) -> Result<(Sink, rtrb::Producer<f32>, RingTarget, OutputStatus), AudioError> {
    let opened = devices::open(choice, Direction::Output)?;
    let rate = opened.config.sample_rate();
    let channels = opened.config.channels();
    let format = opened.config.sample_format();
    let mut config: cpal::StreamConfig = opened.config.config();
    let period = match devices::period(opened.config.buffer_size(), rate, PERIOD) {
        Some(period) => {
            config.buffer_size = cpal::BufferSize::Fixed(period);
            period as usize
        }
        None => frames_in(UNKNOWN_PERIOD, rate),
    };
    let (target, cap) = ring_capacity(rate, period, margin, chunk_out_len(rate));
    let (tx, rx) = rtrb::RingBuffer::new(cap);
    let clock = Arc::new(OutputClock::new(rate));
    let fault = Arc::new(Fault::default());
    let state = OutputState {
        ring: rx,
        clock: clock.clone(),
        channels: usize::from(channels),
        consumed: 0,
    };
    let d = &opened.device;
    let f = fault.clone();
    use cpal::SampleFormat as F;
    let stream = match format {
        F::F32 => build_output::<f32>(d, config, state, f),
        F::F64 => build_output::<f64>(d, config, state, f),
        F::I16 => build_output::<i16>(d, config, state, f),
        F::U16 => build_output::<u16>(d, config, state, f),
        F::I32 => build_output::<i32>(d, config, state, f),
        F::U32 => build_output::<u32>(d, config, state, f),
        F::I8 => build_output::<i8>(d, config, state, f),
        F::U8 => build_output::<u8>(d, config, state, f),
        other => return Err(AudioError::UnsupportedFormat(other.to_string())),
    }
    .map_err(|e| devices::no_device(Direction::Output, e.to_string()))?;
    stream
        .play()
        .map_err(|e| devices::no_device(Direction::Output, e.to_string()))?;
    let status = OutputStatus::Playing {
        device: opened.name,
        rate,
        channels,
    };
    Ok((
        Sink::Device {
            _stream: stream,
            clock,
            fault,
        },
        tx,
        target,
        status,
    ))
}

/// A sink that plays nothing at real-time pace: at `rate` (the mixer's), 10 ms periods, timed by
/// the system clock; its ring's target a period plus `margin`.
pub(super) fn virtual_sink(rate: u32, margin: Duration) -> (Sink, rtrb::Producer<f32>, RingTarget) {
    const MAX_PERIOD: usize = crate::vocab::MAX_AUDIO_RATE as usize / 100;
    let rate = rate.clamp(100, crate::vocab::MAX_AUDIO_RATE);
    let period = frames_in(PERIOD, rate);
    let (target, cap) = ring_capacity(rate, period, margin, chunk_out_len(rate));
    let (tx, rx) = rtrb::RingBuffer::new(cap);
    let clock = Arc::new(OutputClock::new(rate));
    let stop = Arc::new(AtomicBool::new(false));
    let mut state = OutputState {
        ring: rx,
        clock: clock.clone(),
        channels: 1,
        consumed: 0,
    };
    let stop2 = stop.clone();
    let thread = std::thread::Builder::new()
        .name("lipcall-silent-sink".into())
        .spawn(move || {
            let mut scratch = [0.0f32; MAX_PERIOD];
            let scratch = &mut scratch[..period];
            let start = Instant::now();
            let mut played: u64 = 0;
            while !stop2.load(Ordering::Relaxed) {
                let due = (start.elapsed().as_secs_f64() * f64::from(rate)) as u64;
                // The period [played, played + PERIOD) is heard from its nominal start on.
                while played <= due {
                    let at = start + Duration::from_secs_f64(played as f64 / f64::from(rate));
                    state.fill(scratch, at, Duration::ZERO);
                    played += period as u64;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        });
    let thread = thread.ok();
    (
        Sink::Virtual {
            thread,
            stop,
            clock,
        },
        tx,
        target,
    )
}

/// An output callback over a fresh ring, for tests that drive it by hand.
#[cfg(test)]
pub(crate) fn test_output_state(
    rate: u32,
    channels: usize,
    capacity: usize,
) -> (rtrb::Producer<f32>, impl FnMut(&mut [f32], Instant)) {
    let (tx, rx) = rtrb::RingBuffer::new(capacity);
    let mut st = OutputState {
        ring: rx,
        clock: Arc::new(OutputClock::new(rate)),
        channels,
        consumed: 0,
    };
    (tx, move |data: &mut [f32], at: Instant| {
        st.fill(data, at, Duration::from_millis(10))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_callback_copies_counts_underruns_and_publishes() {
        let (mut tx, rx) = rtrb::RingBuffer::new(16);
        let clock = Arc::new(OutputClock::new(8000));
        let mut st = OutputState {
            ring: rx,
            clock: clock.clone(),
            channels: 2,
            consumed: 0,
        };
        let _ = tx.push_partial_slice(&[0.5, -0.5, 0.25]);
        let mut data = [7i16; 8]; // 4 stereo frames, 3 in the ring
        let t = Instant::now();
        st.fill(&mut data, t, Duration::from_millis(3));
        assert_eq!(data, [16384, 16384, -16384, -16384, 8192, 8192, 0, 0]);
        assert_eq!(clock.underruns(), 1);
        assert_eq!(clock.underrun_frames(), 1);
        assert_eq!(clock.frames_played(), 4);
        let a = clock.anchor().unwrap();
        assert_eq!((a.ring_frame, a.ring_end), (0, 3));
        let mut data = [0.0f32; 8];
        st.fill(&mut data, t, Duration::ZERO);
        assert_eq!(clock.underrun_frames(), 5);
        assert_eq!(clock.anchor().unwrap().ring_frame, 3);
    }
}

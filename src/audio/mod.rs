//! Audio in and out: WAV files (any rate, resampled to 8 kHz mono), and the real-time device
//! layer of the app: capture, per-peer mixing at the output device's rate, playback and the
//! playback clock for lip-sync.
//!
//! Threads: the device callbacks (capture, output) only touch rtrb rings and atomics; the
//! mixer thread sums peers and resamples; decoder threads push PCM into per-peer queues; the
//! app thread reads meters, sets volumes and asks the clock what is heard now.
//!
//! What the app does with it:
//! ```no_run
//! use std::time::Instant;
//! use lipcall::audio::{Capture, DeviceChoice, OutputStatus, Playback, PlaybackConfig, Schedule};
//! # fn main() -> Result<(), lipcall::audio::AudioError> {
//! // Never fails for want of a device: without one it runs silent on a virtual clock.
//! let mut playback = Playback::start(PlaybackConfig::default())?;
//! if let OutputStatus::Silent { reason } = playback.status() {
//!     println!("{reason}");
//! }
//! // Per remote peer: the feed goes to its decoder thread, with the weights' sender. The
//! // mixer runs at the device's rate; positions count samples at it, 20 ms a row.
//! let mut feed = playback.add_peer()?;
//! let (mut rows, mut weights) = Schedule::<[f32; 6]>::channel_with_rows(256, feed.frame_len());
//! // A decoded 20 ms frame at its codec's rate (here 48 kHz Opus), resampled once to the mix.
//! let audio = lipcall::vocab::FrameAudio::silence(48_000);
//! if let Some(pos) = feed.push_frame(&audio, 2, true) {
//!     rows.send(pos, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]); // its viseme weights
//! }
//! // Each UI frame: notice a lost device, then the weights of what is heard now.
//! playback.poll();
//! let _shown = playback.weights_now(&mut weights, feed.id(), Instant::now());
//! // The microphone: an error means receive-only (show its line).
//! match Capture::start(&DeviceChoice::Default) {
//!     Ok(mut mic) => {
//!         let mut frame = [0i16; 160];
//!         while let Some(_gate) = mic.read_frame(&mut frame)? { /* encode and send */ }
//!     }
//!     Err(e) => println!("{e}"),
//! }
//! # Ok(())
//! # }
//! ```

pub mod capture;
pub mod clock;
pub mod devices;
pub mod error;
pub mod mixer;
pub mod pacer;
pub mod playback;
mod resample;
pub mod ringtone;
pub mod wav;

pub use capture::{Capture, FrameReader, Gate, InputFeeder, Level, MicControls};
pub use clock::{OutputClock, PeerClock, Schedule, ScheduleSender};
pub use devices::{DeviceChoice, DeviceInfo, input_devices, output_devices};
pub use error::AudioError;
pub use mixer::{MixProgress, PeerControls, PeerFeed, PeerId};
pub use pacer::{FramePacer, Pulls};
pub use playback::{
    DEFAULT_OUTPUT_MARGIN, OpenedOutput, OutputStatus, Playback, PlaybackConfig, PlaybackStats,
    RetiredOutput,
};
pub use resample::FrameResampler;

/// The real-time paths allocate nothing once running: checked with a counting allocator.
// A counting global allocator proves the real-time paths allocate nothing; it needs unsafe.
#[cfg(test)]
#[allow(unsafe_code)]
mod realtime_tests {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::time::{Duration, Instant};

    struct Counting;

    static ALLOCS: AtomicU64 = AtomicU64::new(0);
    thread_local! {
        static ARMED: Cell<bool> = const { Cell::new(false) };
    }

    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            if ARMED.with(Cell::get) {
                ALLOCS.fetch_add(1, Ordering::Relaxed);
            }
            // SAFETY: forwarded unchanged to the system allocator.
            unsafe { System.alloc(l) }
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            // SAFETY: forwarded unchanged to the system allocator.
            unsafe { System.dealloc(p, l) }
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
            if ARMED.with(Cell::get) {
                ALLOCS.fetch_add(1, Ordering::Relaxed);
            }
            // SAFETY: forwarded unchanged to the system allocator.
            unsafe { System.realloc(p, l, n) }
        }
    }

    #[test]
    fn engine_parts_move_between_threads() {
        fn send<T: Send>() {}
        send::<super::Playback>();
        send::<super::Capture>();
        send::<super::FrameReader>();
        send::<super::PeerFeed>();
        send::<super::ScheduleSender<[f32; 6]>>();
        send::<super::MicControls>();
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    fn allocations(f: impl FnOnce()) -> u64 {
        let before = ALLOCS.load(Ordering::Relaxed);
        ARMED.with(|a| a.set(true));
        f();
        ARMED.with(|a| a.set(false));
        ALLOCS.load(Ordering::Relaxed) - before
    }

    #[test]
    fn callbacks_mixer_and_frame_reader_do_not_allocate() {
        use super::capture::capture_pipeline;
        use super::mixer::{
            CHUNK, Mixer, PeerControls, PeerId, Upsampler, peer_channel, peer_channel_at,
        };
        use super::playback::test_output_state;

        // The counter sees allocations at all.
        assert!(allocations(|| drop(std::hint::black_box(vec![1u8; 10]))) > 0);

        // Capture callback and the encoder's reader, full ring and empty ring included.
        let (mut feeder, mut reader) =
            capture_pipeline(44_100, 2, Duration::from_millis(100)).unwrap();
        let block = vec![1000i16; 2 * 441];
        let mut frame = [0i16; crate::codec::speex::FRAME_SIZE];
        let n = allocations(|| {
            for _ in 0..40 {
                feeder.feed(&block);
                while reader.read_frame(&mut frame).unwrap().is_some() {}
            }
            for _ in 0..40 {
                feeder.feed(&block);
            }
        });
        assert_eq!(n, 0, "capture path allocated");

        // Mixer thread's step and the output callback, with underruns.
        let mut mixer = Mixer::new();
        let mut feeds = Vec::new();
        for i in 0..4 {
            let (f, m, _) = peer_channel(PeerId(i), 8000, Arc::new(PeerControls::default()));
            mixer.add(m).unwrap();
            feeds.push(f);
        }
        let mut up = Upsampler::new(48_000).unwrap();
        let (mut ring, mut out) = test_output_state(48_000, 2, 48_000);
        let mut chunk = [0.0f32; CHUNK];
        let mut data = vec![0.0f32; 2 * 512];
        let pcm = [500i16; CHUNK];
        let n = allocations(|| {
            for _ in 0..100 {
                for f in &mut feeds {
                    f.push(&pcm);
                }
                mixer.mix(&mut chunk);
                let o = up.process(&chunk).unwrap();
                let _ = ring.push_partial_slice(o);
                out(&mut data, Instant::now());
            }
            for _ in 0..200 {
                out(&mut data, Instant::now());
            }
        });
        assert_eq!(n, 0, "mixer or output path allocated");

        // At 48 kHz, peers at their codecs' rates resampled into their queues once each (the
        // resampler is made on a peer's first frame, before counting), and the mix.
        let mut mixer = Mixer::at_rate(48_000);
        let mut feeds = Vec::new();
        let audio = [8000u32, 16_000, 48_000].map(|rate| {
            let pcm: Vec<i16> = (0..rate / 50).map(|i| (i % 200) as i16 * 50).collect();
            crate::vocab::FrameAudio::from_slice(rate, &pcm)
        });
        for (i, a) in audio.iter().enumerate() {
            let c = Arc::new(PeerControls::default());
            let (mut f, m, _) = peer_channel_at(PeerId(i as u32), 48_000, 48_000, c);
            mixer.add(m).unwrap();
            f.push_frame(a, 2, true);
            feeds.push(f);
        }
        let mut chunk = [0.0f32; 960];
        let n = allocations(|| {
            for _ in 0..100 {
                for (f, a) in feeds.iter_mut().zip(&audio) {
                    f.push_frame(a, 2, false);
                }
                mixer.mix(&mut chunk);
            }
        });
        assert_eq!(n, 0, "a 48 kHz mixer's peers allocated");
    }

    /// The app runs the receiver pipeline per peer and frame on its engine thread, beside the
    /// audio; it allocates only when a peer's settings change.
    #[test]
    fn the_receiver_pipeline_does_not_allocate_per_frame() {
        use crate::lipsync::{LipSync, LipSyncOptions, default_model};
        use crate::vocab::FeatureFamily;
        use crate::vocab::FrameFeatures;
        use crate::vocab::VisemeSet;

        let model = default_model();
        let frames: Vec<FrameFeatures> = (0..50)
            .map(|n| FrameFeatures {
                family: FeatureFamily::Bitstream,
                mode: Some(5),
                lsp: std::array::from_fn(|i| 0.28 * (i + 1) as f32 + 0.05 * (n as f32).sin()),
                energy_db: if n % 10 == 0 { -100.0 } else { -30.0 },
            })
            .collect();
        for visemes in [None, Some(VisemeSet::full()), VisemeSet::reduced(3).ok()] {
            let options = LipSyncOptions {
                visemes,
                ..LipSyncOptions::default()
            };
            let mut lipsync = LipSync::new(&model, &options).unwrap();
            let n = allocations(|| {
                for (tag, features) in frames.iter().enumerate() {
                    std::hint::black_box(lipsync.push_full(tag as u64, features));
                    if tag % 7 == 0 {
                        std::hint::black_box(lipsync.flush_full());
                    }
                }
            });
            assert_eq!(n, 0, "{:?}: the receiver allocated", options.visemes);
        }
    }

    /// A head driven by controls fits its visemes to them per frame on the same thread.
    #[test]
    fn fitting_visemes_to_controls_does_not_allocate() {
        use crate::lipsync::controls::Controls;
        use crate::lipsync::viseme_controls::ControlDecomposer;
        use crate::vocab::VisemeSet;

        for set in [VisemeSet::full(), VisemeSet::reduced(3).unwrap()] {
            let decomposer = ControlDecomposer::new(&set).unwrap();
            let mut weights = vec![1.0 / set.len() as f32; set.len()];
            let n = allocations(|| {
                for k in 0..50 {
                    let x = k as f32 / 50.0;
                    let controls = Controls {
                        aperture: 0.2 * x,
                        width: 0.1 - 0.2 * x,
                        jaw: x,
                        rounding: 1.0 - x,
                        closure: if k % 9 == 0 { 1.0 } else { 0.0 },
                        lower_lip_tuck: 0.0,
                    };
                    decomposer.fit(&controls, &mut weights);
                }
            });
            assert_eq!(n, 0, "{} visemes: fitting allocated", set.len());
            assert!((weights.iter().sum::<f32>() - 1.0).abs() < 1e-4);
        }
    }
}

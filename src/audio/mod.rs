//! Audio in and out: WAV files (any rate, resampled to 8 kHz mono), and the real-time device
//! layer of the app: capture, per-peer mixing, playback and the playback clock for lip-sync.
//!
//! Threads: the device callbacks (capture, output) only touch rtrb rings and atomics; the
//! mixer thread sums peers and resamples; decoder threads push PCM into per-peer queues; the
//! app thread reads meters, sets volumes and asks the clock what is heard now.

pub mod capture;
pub mod clock;
pub mod devices;
pub mod error;
pub mod mixer;
pub mod playback;
pub mod wav;

pub use capture::{Capture, FrameReader, Gate, InputFeeder, Level, MicControls};
pub use clock::{OutputClock, PeerClock, Schedule, ScheduleSender};
pub use devices::{DeviceChoice, DeviceInfo, input_devices, output_devices};
pub use error::AudioError;
pub use mixer::{PeerControls, PeerFeed, PeerId};
pub use playback::{OutputStatus, Playback, PlaybackConfig, PlaybackStats};

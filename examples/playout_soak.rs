//! Soak test of the app's playout: the engine plays a caller through a real output device for
//! minutes and prints, every 10 s, where the caller's audio waits (docs/audio.md):
//!
//!     bash .ci/pulse-null-sink.sh      # without a sound card: PulseAudio's null sink
//!     cargo run --release --example playout_soak -- [MINUTES] [SENDER_DRIFT_PERCENT]
//!
//! The caller sends the bundled speech sample, looped, in Speex over loopback, paced by the
//! system clock, or by one SENDER_DRIFT_PERCENT faster (1: its clock is 1 % fast; -1: slow).
//! Each line: the jitter buffer's delay, the peer's queue before the mixer, the output (mixed
//! but not heard yet: ring, resampler, device), their sum (`total`), the buffer's measured
//! drift and its corrections (inserted, dropped, of those forced in speech), the device's
//! underruns, the silence the mixer had to play for the caller (`starved`), the near-silent
//! frames left out to bring its queue back to the pacer's lead after that (`shed`), and the device's
//! rate against the system clock. At the end: the range of `total` after the first minute and
//! its trend. Not part of `cargo test`: it takes the minutes it is given.
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use lipcall::app::engine::{Engine, EngineConfig, lock};
use lipcall::audio::{DeviceChoice, OutputStatus, wav};
use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use lipcall::net::session::{Session, SessionConfig};
use lipcall::vocab::FRAME_SIZE;

const REPORT: Duration = Duration::from_secs(10);

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let minutes: f64 = match args.first() {
        Some(a) => a.parse().context("MINUTES: a number")?,
        None => 10.0,
    };
    let drift: f64 = match args.get(1) {
        Some(a) => a.parse().context("SENDER_DRIFT_PERCENT: a number")?,
        None => 0.0,
    };
    let engine = Engine::start(EngineConfig {
        listen: Some(SocketAddr::from(([127, 0, 0, 1], 0))),
        demo: false,
        name: "soak".into(),
        input: DeviceChoice::Default,
        output: DeviceChoice::Default,
        no_audio: false,
        output_margin: lipcall::audio::DEFAULT_OUTPUT_MARGIN,
    })?;
    let (to, device_rate) = {
        let s = lock(&engine.shared);
        let rate = match s.playback.status() {
            OutputStatus::Playing { rate, .. } => Some(*rate),
            OutputStatus::Silent { reason } => {
                eprintln!("no output device ({reason}): the virtual sink plays");
                None
            }
        };
        (
            s.call.local_addr.context("the engine is not listening")?,
            rate,
        )
    };
    println!(
        "playout soak: {minutes} min, sender {drift:+}% into {to}, output {}",
        device_rate.map_or("silent".into(), |r| format!("{r} Hz"))
    );
    report_device_period(&engine);
    let stop = Arc::new(AtomicBool::new(false));
    let sender = {
        let stop = stop.clone();
        let period = Duration::from_secs_f64(0.02 / (1.0 + drift / 100.0));
        std::thread::spawn(move || send(to, period, &stop))
    };

    println!(
        "{:>6} {:>8} {:>8} {:>8} {:>8} {:>9} {:>5} {:>5} {:>6} {:>9} {:>8} {:>8} {:>9}",
        "t_s",
        "jb_ms",
        "queue_ms",
        "out_ms",
        "total_ms",
        "drift_ppm",
        "ins",
        "drop",
        "forced",
        "underruns",
        "starved",
        "shed",
        "dev_ppm"
    );
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(minutes * 60.0);
    let mut totals: Vec<(f64, f64)> = Vec::new();
    let mut next = start + REPORT;
    let mut played = (0u64, 0.0f64);
    while next <= end {
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        next += REPORT;
        let now = Instant::now();
        let t = now.duration_since(start).as_secs_f64();
        let mut s = lock(&engine.shared);
        s.playback.poll();
        let stats = s.playback.stats();
        let mix_rate = u64::from(s.playback.mix_rate());
        let mixed = s.playback.mixed().samples();
        let out_ms = s
            .playback
            .heard_mix_position(now)
            .map_or(f64::NAN, |heard| {
                (mixed as f64 - heard as f64) * 1000.0 / mix_rate as f64
            });
        // Over the last interval (a device may take a while to start).
        let dev_ppm = device_rate.map_or(f64::NAN, |rate| {
            let frames = (stats.frames_played - played.0) as f64;
            (frames / ((t - played.1) * f64::from(rate)) - 1.0) * 1e6
        });
        played = (stats.frames_played, t);
        let Some(peer) = s.peers.views().into_iter().next() else {
            println!("{t:>6.0} (no peer yet)");
            continue;
        };
        let (starved, shed) = s
            .playback
            .peer_controls(peer.feed)
            .map_or((0, 0), |c| (c.starved(), c.shed()));
        drop(s);
        let b = peer.buffer;
        let total = b.current_delay_ms + peer.queued_ms + out_ms;
        if t > 60.0 {
            totals.push((t, total));
        }
        println!(
            "{t:>6.0} {:>8.1} {:>8.1} {out_ms:>8.1} {total:>8.1} {:>9.0} {:>5} {:>5} {:>6} {:>9} {:>8} {shed:>8} {dev_ppm:>9.0}",
            b.current_delay_ms,
            peer.queued_ms,
            b.drift_ppm,
            b.stretched,
            b.dropped,
            b.forced,
            stats.underruns,
            starved,
        );
    }
    stop.store(true, Ordering::Relaxed);
    sender
        .join()
        .map_err(|_| anyhow::anyhow!("the sender panicked"))??;
    if totals.len() >= 2 {
        let (lo, hi) = totals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, v)| {
                (lo.min(v), hi.max(v))
            });
        let n = totals.len() as f64;
        let (mt, mv) = totals
            .iter()
            .fold((0.0, 0.0), |(a, b), &(t, v)| (a + t / n, b + v / n));
        let (num, den) = totals.iter().fold((0.0, 0.0), |(num, den), &(t, v)| {
            (num + (t - mt) * (v - mv), den + (t - mt) * (t - mt))
        });
        println!(
            "total after the first minute: {lo:.1} to {hi:.1} ms, trend {:+.2} ms per minute",
            num / den * 60.0
        );
    }
    Ok(())
}

/// How the output takes the mix: the mixer's count watched every millisecond for 2 s (after
/// the device started), as the chunks it mixes at a time and the time between.
fn report_device_period(engine: &Engine) {
    let mixed = lock(&engine.shared).playback.mixed();
    let start = Instant::now();
    while mixed.chunks() < 10 && start.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut steps: Vec<(u64, f64)> = Vec::new();
    let (mut last, mut since) = (mixed.chunks(), Instant::now());
    let watch = Instant::now();
    while watch.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(1));
        let now = mixed.chunks();
        if now != last {
            steps.push((now - last, since.elapsed().as_secs_f64() * 1000.0));
            (last, since) = (now, Instant::now());
        }
    }
    let most = steps.iter().map(|s| s.0).max().unwrap_or(0);
    let mean_ms = steps.iter().map(|s| s.1).sum::<f64>() / steps.len().max(1) as f64;
    let pairs = steps.iter().filter(|s| s.0 >= 2).count();
    println!(
        "output: the mixer mixed {} times in 2 s, every {mean_ms:.1} ms on average, up to {most} \
         chunks at once ({pairs} times 2 or more)",
        steps.len()
    );
}

/// Sends the speech sample, looped, one Speex frame every `period`, until `stop`.
fn send(to: SocketAddr, period: Duration, stop: &AtomicBool) -> anyhow::Result<()> {
    let speech = wav::read_narrowband(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/assets/speech/demo.wav"
    )))?;
    anyhow::ensure!(speech.len() >= FRAME_SIZE, "the speech sample is empty");
    let mut config = SessionConfig::new(SocketAddr::from(([127, 0, 0, 1], 0)));
    config.destinations = vec![to];
    config.name = Some("Soak".into());
    let session = Session::start(config)?;
    let mut encoder = FrameEncoder::new(Codec::Speex, &EncoderSettings::default())?;
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let start = Instant::now();
    let mut at = 0;
    for k in 0u32.. {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        if let Some(wait) = (start + period * k).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let frame: [i16; FRAME_SIZE] = std::array::from_fn(|i| speech[(at + i) % speech.len()]);
        at = (at + FRAME_SIZE) % speech.len();
        if let Some((n, ticks)) = encoder.encode(&frame, &mut payload)? {
            session.send_packet(&payload[..n], ticks)?;
        }
    }
    session.leave();
    Ok(())
}

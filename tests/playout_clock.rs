//! The app's receive path against an output device whose clock is not the system's, in
//! simulated time: a Speex sender paced by the system clock, the peer's receiver (jitter buffer
//! and decoder), pulls paced by the mixer's demand ([`FramePacer`]), the peer's queue and the
//! mixer, and a device that takes 20 ms at a time, 1 % faster or slower than the system clock.
//! The queue holds the same few frames however long the call, every loud frame is heard, and
//! the drift is corrected inside the sender's pauses. Pulled on the system clock instead (the
//! app's loop before), the same queue runs dry or overflows within two minutes.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use lipcall::audio::mixer::{CHUNK, Mixer, PeerControls, PeerId, peer_channel};
use lipcall::audio::pacer::DEFAULT_LEAD;
use lipcall::audio::{FramePacer, PeerFeed};
use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use lipcall::net::jitter::JitterConfig;
use lipcall::net::peer::{FrameKind, PeerReceiver};
use lipcall::net::rtp::{self, RtpStream};
use lipcall::vocab::FRAME_SIZE;

const FRAME_MS: u64 = 20;
/// Two minutes.
const FRAMES: usize = 6000;
/// The peer's queue, as the app makes it: one second.
const QUEUE: usize = 8000;

/// Frame `k` of a talker: 1.6 s of a voiced sound, then 0.4 s of faint noise.
fn talker(k: usize) -> ([i16; FRAME_SIZE], bool) {
    common::talker::talker(k, 80, 100)
}

/// What a run saw, from its second second on.
#[derive(Debug, Default)]
struct Run {
    /// Fewest and most samples queued for the mixer.
    queued: (usize, usize),
    /// Samples the mixer found missing (the device played silence for this peer), and those
    /// that did not fit in the queue.
    starved: u64,
    overflow: u64,
    /// Loud frames sent and heard.
    loud_sent: usize,
    loud_heard: usize,
    /// The jitter buffer's delay, fewest and most ms, after 20 s, and over the last 30 s.
    delay_ms: (f64, f64),
    late_delay_ms: (f64, f64),
    dropped: u64,
    stretched: u64,
    forced: u64,
    drift_ppm: f64,
}

/// Two minutes of the talker into a receiver whose output device runs at `rate` times the
/// system clock; `paced` pulls on the mixer's demand, otherwise every 20 ms of system time.
fn call(rate: f64, paced: bool) -> Run {
    call_with_stall(rate, paced, None, None)
}

/// As [`call`], the device taking nothing for `stall` (ms from, ms long), and the puller (the
/// app's engine thread) held up for `held` (ms from, ms long).
fn call_with_stall(
    rate: f64,
    paced: bool,
    stall: Option<(u64, u64)>,
    held: Option<(u64, u64)>,
) -> Run {
    let mut encoder = FrameEncoder::new(Codec::Speex, &EncoderSettings::default()).unwrap();
    let payloads: Vec<(Vec<u8>, u32)> = (0..100)
        .map(|k| {
            let mut out = [0u8; MAX_FRAME_PAYLOAD];
            let (n, ticks) = encoder.encode(&talker(k).0, &mut out).unwrap().unwrap();
            (out[..n].to_vec(), ticks)
        })
        .collect();
    let mut stream = RtpStream::new(0x5eed, 1, 1000);
    stream.set_payload(110, 160);
    let t0 = Instant::now();
    let mut rx = PeerReceiver::new(JitterConfig::default(), t0, true);
    let controls = Arc::new(PeerControls::default());
    let (mut feed, mixer_peer, _clock) = peer_channel(PeerId(1), QUEUE, controls.clone());
    let mut mixer = Mixer::new();
    mixer.add(mixer_peer).unwrap();
    let progress = mixer.progress();
    let mut pacer = FramePacer::new(DEFAULT_LEAD);
    let mut chunk = [0.0f32; CHUNK];
    let mut datagram = Vec::new();
    let mut run = Run {
        queued: (usize::MAX, 0),
        delay_ms: (f64::INFINITY, 0.0),
        late_delay_ms: (f64::INFINITY, 0.0),
        ..Run::default()
    };
    let mut sent = 0;
    let mut next_tick = 0;
    let mut playing = false;
    let mut pull = |rx: &mut PeerReceiver,
                    at: Instant,
                    ahead: Option<usize>,
                    feed: &mut PeerFeed,
                    run: &mut Run| {
        let frame = rx.pull(at);
        let resuming = !std::mem::replace(&mut playing, frame.is_some());
        if let Some(frame) = frame {
            match (paced, ahead) {
                (true, Some(ahead)) => {
                    feed.push_paced(&frame.pcm, ahead, resuming);
                }
                (true, None) => {}
                (false, _) => {
                    feed.push(&frame.pcm);
                }
            }
            if frame.kind == FrameKind::Decoded && frame.features.energy_db > -35.0 {
                run.loud_heard += 1;
            }
        }
        let d = rx.stats().jitter.current_delay_ms;
        if at > t0 + Duration::from_secs(20) {
            run.delay_ms = (run.delay_ms.0.min(d), run.delay_ms.1.max(d));
        }
        if at > t0 + Duration::from_secs(90) {
            run.late_delay_ms = (run.late_delay_ms.0.min(d), run.late_delay_ms.1.max(d));
        }
    };
    let end = FRAMES as u64 * FRAME_MS + 1000;
    for ms in 0..end {
        let now = t0 + Duration::from_millis(ms);
        // The sender, on the system clock; 3 ms to arrive.
        while sent < FRAMES && (sent as u64 * FRAME_MS + 3) <= ms {
            let (payload, ticks) = &payloads[sent % 100];
            stream
                .packetize_ticks(payload, *ticks, &mut datagram)
                .unwrap();
            rx.insert(&rtp::parse(&datagram, None).unwrap(), now);
            run.loud_sent += usize::from(talker(sent).1);
            sent += 1;
        }
        // The device takes 20 ms at a time, at its own rate (as PulseAudio's null sink does;
        // the pacer's own tests have a device that takes 40 ms).
        let device_ms = match stall {
            Some((from, _)) if ms < from => ms,
            Some((from, long)) => from.max(ms.saturating_sub(long)),
            None => ms,
        };
        let wanted = (device_ms as f64 * rate / 20.0).floor() as u64;
        while mixer.position() / (CHUNK as u64) < wanted {
            mixer.mix(&mut chunk);
        }
        let held_up = held.is_some_and(|(from, long)| (from..from + long).contains(&ms));
        if ms % 5 == 0 && !held_up {
            if paced {
                let pulls = pacer.poll(progress.chunks(), now);
                for i in 0..pulls.total() {
                    pull(&mut rx, now, pulls.ahead(i), &mut feed, &mut run);
                }
            } else if ms >= next_tick {
                next_tick += FRAME_MS;
                pull(&mut rx, now, None, &mut feed, &mut run);
            }
        }
        // Counted while the talker talks (after it, the mixer rightly finds nothing).
        if ms == 1000 || ms == end - 1000 {
            run.starved = controls.starved() - run.starved;
            run.overflow = controls.overflow() - run.overflow;
        }
        if ms > 1000 && ms < end - 1000 {
            let q = feed.queued();
            run.queued = (run.queued.0.min(q), run.queued.1.max(q));
        }
    }
    let j = rx.stats().jitter;
    (run.dropped, run.stretched, run.forced, run.drift_ppm) =
        (j.dropped, j.stretched, j.forced, j.drift_ppm);
    run
}

#[test]
fn pulled_on_the_mixers_demand_the_queue_stays_flat_whatever_the_device_clock() {
    // (A loud frame's last 5 ms come out of the decoder with the next: each pause's first
    // frame is loud too. A device in step is the reference.)
    let steady = call(1.0, true);
    assert!(steady.loud_heard >= steady.loud_sent, "{steady:?}");
    assert_eq!(steady.dropped + steady.stretched, 0, "{steady:?}");
    for rate in [1.01, 0.99] {
        let run = call(rate, true);
        eprintln!("device x{rate}, paced by the mixer: {run:?}");
        // The queue holds the pacer's lead (a frame less just after the mixer took one), never
        // runs dry while the talker talks, and never overflows.
        let lead = DEFAULT_LEAD as usize * CHUNK;
        assert_eq!(run.queued, (lead - CHUNK, lead), "{run:?}");
        assert_eq!((run.starved, run.overflow), (0, 0), "{run:?}");
        // The drift now shows between the sender and the device: measured, and corrected in
        // the pauses, so every loud frame is heard and the delay stays within a few frames.
        assert!((run.drift_ppm.abs() - 10_000.0).abs() < 1000.0, "{run:?}");
        assert_eq!(run.forced, 0, "{run:?}");
        assert!(run.dropped + run.stretched >= 50, "{run:?}");
        assert_eq!(run.loud_heard, steady.loud_heard, "{run:?}");
        assert!(run.delay_ms.1 - run.delay_ms.0 < 60.0, "{run:?}");
    }
}

#[test]
fn a_device_that_stalls_for_a_second_comes_back_where_it_was() {
    // The device takes nothing for a second a minute into the call (a busy sound server). The
    // pulls go on by the system clock meanwhile, what they decode is not queued, and
    // afterwards the queue holds its lead again and the delay is what it was: the stall cost
    // its second of audio, not a second of latency for the rest of the call.
    let steady = call(1.0, true);
    let run = call_with_stall(1.0, true, Some((60_000, 1000)), None);
    eprintln!("a second's stall: {run:?}");
    let lead = DEFAULT_LEAD as usize * CHUNK;
    assert!(
        run.queued.0 >= lead - CHUNK && run.queued.1 <= lead,
        "{run:?}"
    );
    assert_eq!((run.starved, run.overflow), (0, 0), "{run:?}");
    assert_eq!(run.late_delay_ms, steady.late_delay_ms, "{run:?}");
    assert_eq!(run.dropped + run.stretched, 0, "{run:?}");
}

#[test]
fn a_puller_held_up_drops_what_was_mixed_meanwhile() {
    // The engine thread gets no CPU for 150 ms a minute into the call: the mixer plays
    // silence for the peer meanwhile (what a late puller cannot help), then the frames it
    // played silence for are pulled and dropped, and the queue is back at its lead at once
    // (rather than late audio queued on top of it, for the rest of the call).
    let steady = call(1.0, true);
    let run = call_with_stall(1.0, true, None, Some((60_000, 150)));
    eprintln!("the puller held up for 150 ms: {run:?}");
    let lead = DEFAULT_LEAD as usize * CHUNK;
    assert!(run.queued.1 <= lead, "{run:?}");
    assert!(run.starved <= 8 * CHUNK as u64, "{run:?}");
    assert_eq!(run.late_delay_ms, steady.late_delay_ms, "{run:?}");
    assert_eq!(run.dropped + run.stretched, 0, "{run:?}");
}

#[test]
fn pulled_on_the_system_clock_the_queue_drifts_away() {
    // What the app did before: a device 1 % fast drains the queue (the mixer plays silence
    // for the peer, about 1.2 s of it in two minutes), a slow one fills it until it
    // overflows (a second of latency, then lost audio).
    let fast = call(1.01, false);
    eprintln!("device x1.01, paced by the system clock: {fast:?}");
    assert!(fast.starved > 8000, "{fast:?}");
    let slow = call(0.99, false);
    eprintln!("device x0.99, paced by the system clock: {slow:?}");
    assert!(slow.queued.1 >= QUEUE - CHUNK, "{slow:?}");
    assert!(slow.overflow > 0, "{slow:?}");
}

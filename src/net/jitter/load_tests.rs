//! A clean start and a busy machine, in simulated time: a burst of a stream's first packets
//! (a subscription that came up after the publisher began, a re-join), and the receiving and
//! pulling threads starved (arrivals bunched behind a stall, pulls made late for the ticks
//! they were asked for). What arrived is played, once, in order; nothing of it is concealed,
//! no frame inserted in speech; drift stays what the clocks do.

use std::time::{Duration, Instant};

use super::*;

/// One-frame Opus-clocked packets sent every 20 ms from t = 0 (`sent(i)`, seconds).
const CLOCK: u32 = 48_000;
const STEP: u32 = CLOCK / 50;

/// A run: packet `i` is filed (by a thread that may lag) at `filed(i)` seconds, stamped with
/// that time; pull `k` is asked for tick `0.02 k` and made at `pulled(k)` (its thread may lag
/// behind its ticks too). Frames 40 to 49 of every 50 are quiet (pauses to correct in).
struct Run {
    played: Vec<u32>,
    dropped: Vec<u32>,
    /// Pops that concealed (`Lost`) or inserted (`Stretch`) while speech went on, and where.
    concealed: Vec<(u32, char)>,
    stats: JitterStats,
    /// The target delay (ms) after each second.
    targets: Vec<f64>,
    /// The delay played at (ms) after each second.
    delays: Vec<f64>,
}

fn run(packets: u32, filed: impl Fn(u32) -> f64, pulled: impl Fn(u32) -> f64) -> Run {
    run_stamped(packets, &filed, &filed, pulled)
}

/// As [`run`], packet `i` filed at `filed(i)` but stamped `stamped(i)`: the kernel's arrival
/// time, where the filing thread read it later.
fn run_stamped(
    packets: u32,
    filed: impl Fn(u32) -> f64,
    stamped: impl Fn(u32) -> f64,
    pulled: impl Fn(u32) -> f64,
) -> Run {
    let t0 = Instant::now();
    let at = |s: f64| t0 + Duration::from_secs_f64(s.max(0.0));
    let mut jb = JitterBuffer::with_clock(JitterConfig::default(), t0, CLOCK);
    let mut arrivals: Vec<(f64, u32)> = (0..packets).map(|i| (filed(i), i)).collect();
    arrivals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let pulls = packets + 100;
    let mut out = Run {
        played: Vec::new(),
        dropped: Vec::new(),
        concealed: Vec::new(),
        stats: JitterStats::default(),
        targets: Vec::new(),
        delays: Vec::new(),
    };
    let mut next = 0;
    let mut last_played = None;
    for k in 0..pulls {
        let made = pulled(k).max(0.02 * f64::from(k));
        while let Some(&(time, i)) = arrivals.get(next) {
            if time > made {
                break;
            }
            jb.file(Arrival {
                sequence: 5000u16.wrapping_add(i as u16),
                timestamp: 7_000_000u32.wrapping_add(i * STEP),
                marker: i == 0,
                payload_type: 96,
                payload: &i.to_le_bytes(),
                duration: STEP,
                on_grid: true,
                at: at(stamped(i)),
            });
            next += 1;
        }
        let tick = at(0.02 * f64::from(k));
        let mut playout = jb.pop(tick);
        loop {
            let loud = |i: u32| i % 50 < 40;
            let loudness = match &playout {
                Playout::Packet(p) => {
                    let i = u32::from_le_bytes(p[..4].try_into().unwrap());
                    last_played = Some(i);
                    loud(i)
                }
                Playout::Lost | Playout::Stretch => {
                    let kind = if playout == Playout::Lost { 'L' } else { 'S' };
                    let speaking = last_played.is_some_and(|i| loud(i) && i + 1 < packets);
                    if speaking {
                        out.concealed.push((k, kind));
                    }
                    speaking
                }
                _ => break,
            };
            let loudness = if loudness {
                Loudness::Audible
            } else {
                Loudness::Quiet
            };
            if jb.played(loudness) != Correction::Drop {
                break;
            }
            if let Some(i) = last_played.take() {
                out.dropped.push(i);
            }
            playout = jb.pop(tick);
        }
        if let Some(i) = last_played
            && out.played.last() != Some(&i)
            && !out.dropped.contains(&i)
        {
            out.played.push(i);
        }
        if k % 50 == 49 {
            out.targets.push(jb.stats().target_delay_ms);
            out.delays.push(jb.stats().current_delay_ms);
        }
    }
    out.stats = jb.stats();
    out
}

fn sent(i: u32) -> f64 {
    0.02 * f64::from(i)
}

/// Everything sent was played once, in order, but for quiet frames shed in pauses.
fn all_played(run: &Run, packets: u32, what: &str) {
    let mut expected: Vec<u32> = (0..packets).filter(|i| !run.dropped.contains(i)).collect();
    expected.dedup();
    if run.played != expected {
        let missing: Vec<&u32> = expected
            .iter()
            .filter(|i| !run.played.contains(i))
            .collect();
        panic!("{what}: not played {missing:?}");
    }
    assert!(
        run.dropped.iter().all(|&i| i % 50 >= 40),
        "a loud frame dropped: {what}: {:?}",
        run.dropped
    );
}

#[test]
fn a_burst_of_the_first_packets_is_played_not_taken_for_late_packets() {
    // A subscription that came up after the publisher began: its first 200 ms come together
    // (the first alone a moment before the rest, or all at once), then the stream on time.
    for (alone, what) in [(0.0, "all at once"), (0.015, "first alone")] {
        let packets = 500;
        let out = run(
            packets,
            |i| match i {
                0 => 0.2 - alone,
                1..=10 => 0.2 + 0.0002 * f64::from(i),
                _ => sent(i) + 0.002,
            },
            |k| 0.02 * f64::from(k),
        );
        all_played(&out, packets, what);
        assert_eq!(out.concealed, vec![], "{what}: {:?}", out.stats);
        assert_eq!(
            (out.stats.late, out.stats.forced, out.stats.stretched),
            (0, 0, 0),
            "{what}: {:?}",
            out.stats
        );
    }
}

#[test]
fn a_first_packet_ahead_of_a_held_up_burst_does_not_set_the_timeline() {
    // The first packet comes on time, the next 300 ms are held up and come together (a
    // subscription's first packet through, then its keys or its path set up): playing from the
    // first packet's timing would conceal 300 ms and then drop the burst as late.
    let packets = 500;
    let out = run(
        packets,
        |i| match i {
            0 => 0.002,
            1..=15 => 0.3 + 0.0002 * f64::from(i),
            _ => sent(i) + 0.002,
        },
        |k| 0.02 * f64::from(k),
    );
    all_played(&out, packets, "first ahead");
    assert_eq!(out.stats.late, 0, "{:?}", out.stats);
    assert_eq!(out.stats.forced, 0, "{:?}", out.stats);
}

/// Stalls of the whole receiving process: (start, seconds) pseudo-random, 30 to 130 ms long,
/// one every 0.3 to 0.9 s, for `seconds`.
fn stalls(seconds: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let mut t = 0.5;
    let mut k = 0u32;
    while t < seconds {
        let long = 0.03 + f64::from((k * 37) % 11) * 0.01;
        out.push((t, long));
        t += long + 0.3 + f64::from((k * 13) % 7) * 0.1;
        k += 1;
    }
    out
}

/// When a thread that wanted to run at `t` runs: after the stall it fell in.
fn after_stalls(stalls: &[(f64, f64)], t: f64) -> f64 {
    stalls
        .iter()
        .find(|&&(s, d)| (s..s + d).contains(&t))
        .map_or(t, |&(s, d)| s + d)
}

#[test]
fn a_starved_receiver_conceals_nothing_that_arrived_and_measures_no_drift() {
    // 30 s on a busy machine: the receiving and the pulling thread stall together (30 to
    // 130 ms, every half second or so) for 20 s, then run freely. Packets come on time to the
    // socket; the thread reads them after the stall, bunched; the pulls of the ticks in the
    // stall are made after it, asked for their ticks.
    let packets = 1500;
    let busy = stalls(20.0);
    let out = run(
        packets,
        |i| after_stalls(&busy, sent(i) + 0.001) + 0.00005 * f64::from(i % 3),
        |k| after_stalls(&busy, 0.02 * f64::from(k)) + 0.0001,
    );
    let what = format!("{:?} targets {:?}", out.stats, out.targets);
    all_played(&out, packets, &what);
    assert_eq!(out.concealed, vec![], "{what}");
    assert_eq!((out.stats.late, out.stats.forced), (0, 0), "{what}");
    assert!(out.stats.drift_ppm.abs() < 300.0, "{what}");
    // Within seconds of the load's end the target is back where a quiet link puts it.
    let after = out.targets[25];
    assert!(after < 45.0, "{what}");
}

#[test]
fn a_starved_receive_thread_alone_is_jitter_and_the_target_comes_back_down() {
    // Only the receiving thread stalls (the puller runs on time): its packets do come late,
    // and the buffer grows for them while the load lasts; drift stays what the clocks do, and
    // once the load ends the target is back down within seconds.
    let packets = 1500;
    let busy = stalls(15.0);
    let out = run(
        packets,
        |i| after_stalls(&busy, sent(i) + 0.001),
        |k| 0.02 * f64::from(k),
    );
    let what = format!("{:?} targets {:?}", out.stats, out.targets);
    assert!(out.stats.drift_ppm.abs() < 300.0, "{what}");
    let loaded = out.targets[3..15].iter().copied().fold(0.0, f64::max);
    assert!(loaded > 60.0, "{what}");
    assert!(out.targets[22] < 45.0, "{what}");
    assert!(out.stats.forced <= 5, "{what}");
}

#[test]
fn a_stream_that_resumes_after_a_stall_plays_on_not_dropped_as_late() {
    // The sender (or its path) stalls for 220 ms twice, in speech: the packets of the stall
    // come together after it. The buffer has played what it had, concealed a frame or two,
    // then paused; the packets that follow play on from there, none dropped as late.
    let packets = 800;
    let held = |i: u32, from: u32| (from..from + 11).contains(&i);
    let out = run(
        packets,
        |i| {
            if held(i, 105) {
                sent(105) + 0.22
            } else if held(i, 407) {
                sent(407) + 0.22
            } else {
                sent(i) + 0.002
            }
        },
        |k| 0.02 * f64::from(k),
    );
    let what = format!("{:?}", out.stats);
    all_played(&out, packets, &what);
    // The first stall resumes the stream; the delay it left (no delay is shed for seconds
    // after a stall) may absorb the second.
    assert_eq!(out.stats.late, 0, "{what}");
    assert!((1..=2).contains(&out.stats.resumed), "{what}");
    // What was concealed was before the stall's packets came, a frame or two at most.
    assert!(out.concealed.len() <= 4, "{what}: {:?}", out.concealed);
}

/// A clean run's outcome: the stream of `packets` filed and stamped on time, pulled on time.
fn clean(packets: u32) -> Run {
    run(packets, |i| sent(i) + 0.001, |k| 0.02 * f64::from(k))
}

/// A stall of 150 ms every 2 s, from 1 s on: when a thread that wanted to run at `t` runs.
fn stalled(t: f64) -> f64 {
    let phase = t % 2.0;
    if (1.0..1.15).contains(&phase) {
        t - phase + 1.15
    } else {
        t
    }
}

#[test]
fn a_burst_read_after_a_stall_is_no_jitter_when_stamped_by_the_kernel() {
    // The receiving process stalls for 150 ms every 2 s: its socket thread reads what came
    // meanwhile in a burst and its puller makes the pulls of the stall late (asked for their
    // ticks); or the socket thread alone stalls, and the puller reads what is waiting on the
    // socket before it pulls. The kernel stamped each packet as it came, 20 ms apart: target,
    // drift and concealment are as on a clean stream.
    let packets = 1000;
    let quiet = clean(packets);
    let arrived = |i: u32| sent(i) + 0.001;
    // The first pull at or after the packet's arrival reads it, if the reader has not.
    let drained = |i: u32| stalled(arrived(i)).min((arrived(i) / 0.02).ceil() * 0.02);
    let whole = run_stamped(
        packets,
        |i| stalled(arrived(i)) + 0.0001,
        arrived,
        |k| stalled(0.02 * f64::from(k)) + 0.0002,
    );
    let reader = run_stamped(packets, drained, arrived, |k| 0.02 * f64::from(k));
    for (out, what) in [(whole, "the process"), (reader, "the reader")] {
        let what = format!(
            "{what} stalled: {:?} targets {:?}\nclean {:?}",
            out.stats, out.targets, quiet.stats
        );
        all_played(&out, packets, &what);
        assert_eq!(out.concealed, vec![], "{what}");
        let counts = |r: &Run| {
            let s = r.stats;
            (
                s.late,
                s.forced,
                s.stretched,
                s.missing,
                s.dropped,
                s.held_upstream,
            )
        };
        assert_eq!(counts(&out), counts(&quiet), "{what}");
        assert_eq!(out.targets, quiet.targets, "{what}");
        assert!(out.stats.drift_ppm.abs() < 100.0, "{what}");
    }
    // Stamped when read instead, the same bursts are jitter: the target rises for them.
    let unstamped = run(
        packets,
        |i| stalled(arrived(i)) + 0.0001,
        |k| stalled(0.02 * f64::from(k)) + 0.0002,
    );
    let highest = |r: &Run| r.targets.iter().copied().fold(0.0, f64::max);
    assert!(
        highest(&unstamped) > highest(&quiet) + 40.0,
        "{:?}",
        unstamped.targets
    );
}

/// A stream held up upstream (its sender or a relay starved) from packet `from` on for
/// `stall` seconds: what was sent meanwhile comes in a burst after it, stamped as it came.
fn held_upstream(i: u32, from: u32, stall: f64) -> f64 {
    let burst = sent(from) + stall + 0.0002 * f64::from(i.saturating_sub(from));
    let on_time = sent(i) + 0.001;
    if i >= from {
        on_time.max(burst)
    } else {
        on_time
    }
}

#[test]
fn a_lone_upstream_stall_is_played_late_once_and_the_delay_comes_back_down() {
    // One stall of 300 to 400 ms in speech at 5.1 s: its packets are played late once (the
    // gap concealed, then the stream resumes), the target does not rise for a lone spike, and
    // the delay the stall added is shed in the next pauses: within 4 s the stream plays at the
    // delay a clean stream plays at, for the rest of the call.
    let packets = 1500;
    let quiet = clean(packets);
    for stall in [0.3, 0.35, 0.4] {
        let out = run(
            packets,
            |i| held_upstream(i, 255, stall),
            |k| 0.02 * f64::from(k),
        );
        let what = format!(
            "stall {stall}: {:?}\ntargets {:?}\ndelays {:?}\nclean delays {:?}",
            out.stats, out.targets, out.delays, quiet.delays
        );
        all_played(&out, packets, &what);
        assert!(out.concealed.len() <= 2, "{what}: {:?}", out.concealed);
        assert_eq!((out.stats.late, out.stats.forced), (0, 0), "{what}");
        assert_eq!(
            (out.stats.resumed, out.stats.held_upstream),
            (1, 1),
            "{what}"
        );
        let highest = out.targets.iter().copied().fold(0.0, f64::max);
        let clean_highest = quiet.targets.iter().copied().fold(0.0, f64::max);
        assert!(highest <= clean_highest + 1e-6, "{what}");
        for second in 9..out.delays.len() {
            assert!(
                out.delays[second] <= quiet.delays[second] + 1.0,
                "second {second}: {what}"
            );
        }
        assert!(out.stats.drift_ppm.abs() < 100.0, "{what}");
    }
}

#[test]
fn stalls_that_repeat_raise_the_target_and_keep_it_up() {
    // A truly jittery path: 300 ms stalls every 2 s from 1.1 s to 21.1 s. The first stalls
    // are played late (and shed); once they repeat the target covers them, and the later ones
    // cost nothing: no concealment after the first seconds, nothing late.
    let packets = 1500;
    let starts: Vec<u32> = (0..10).map(|n| 55 + 100 * n).collect();
    let out = run(
        packets,
        |i| {
            let from = starts.iter().copied().filter(|&s| s <= i).max();
            from.map_or(sent(i) + 0.001, |from| held_upstream(i, from, 0.3))
        },
        |k| 0.02 * f64::from(k),
    );
    let what = format!(
        "{:?}\ntargets {:?}\ndelays {:?}\nconcealed {:?}",
        out.stats, out.targets, out.delays, out.concealed
    );
    all_played(&out, packets, &what);
    assert_eq!(out.stats.late, 0, "{what}");
    assert!(out.targets[6..21].iter().all(|&t| t >= 250.0), "{what}");
    assert!(out.concealed.iter().all(|&(k, _)| k < 300), "{what}");
    assert!(out.stats.drift_ppm.abs() < 100.0, "{what}");
}

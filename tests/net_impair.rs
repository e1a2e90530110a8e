//! `lipcall send` -> impairment proxy -> `lipcall receive`: loss, jitter, reordering and
//! duplicates with seeded randomness, for Speex and for Opus. The played audio must stay
//! continuous, of the right duration, with concealment (and Opus's FEC recovery) counted and a
//! feature row for every frame.

mod common;

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::net::{SocketAddr, UdpSocket};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::net::{Announce, fields, num, spawn_listening};
use common::{lipcall, read_wav_i16, run};

/// splitmix64: small, seeded, good enough to pick losses and delays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[derive(Debug, Clone, Copy)]
struct Impairment {
    loss: f64,
    /// Delay is uniform in base +- jitter, so packets overtake each other (reordering).
    base: Duration,
    jitter: Duration,
    duplicate: f64,
    seed: u64,
}

/// A datagram waiting in the proxy: release time, arrival order, destination, bytes.
type Scheduled = (Instant, u64, SocketAddr, Vec<u8>);

#[derive(Debug, Default, Clone, Copy)]
struct ProxyCounts {
    media: u64,
    dropped: u64,
    duplicated: u64,
    reordered: u64,
}

/// Forwards sender -> receiver with impairments on RTP; RTCP is delayed alike but not lost
/// (a lost BYE only makes the receiver conceal a little longer; the test is about media).
/// Receiver -> sender traffic (reports) passes untouched. Runs until `stop`, bounded anyway.
fn proxy(
    socket: UdpSocket,
    receiver: SocketAddr,
    imp: Impairment,
    stop: Arc<AtomicBool>,
) -> ProxyCounts {
    socket
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let mut rng = Rng(imp.seed);
    let mut counts = ProxyCounts::default();
    let mut queue: BinaryHeap<Reverse<Scheduled>> = BinaryHeap::new();
    let mut sender: Option<SocketAddr> = None;
    let mut order = 0u64;
    let mut last_release_seq: Option<u16> = None;
    let mut buf = [0u8; 2048];
    let deadline = Instant::now() + Duration::from_secs(60);
    while !stop.load(Ordering::Relaxed) && Instant::now() < deadline {
        if let Ok((n, from)) = socket.recv_from(&mut buf) {
            let data = buf[..n].to_vec();
            if from == receiver {
                if let Some(s) = sender {
                    let _ = socket.send_to(&data, s);
                }
            } else {
                sender = Some(from);
                let rtp = n >= 12 && !(200..=204).contains(&data[1]);
                if rtp {
                    counts.media += 1;
                    if rng.unit() < imp.loss {
                        counts.dropped += 1;
                        continue;
                    }
                }
                let copies = if rtp && rng.unit() < imp.duplicate {
                    2
                } else {
                    1
                };
                counts.duplicated += copies - 1;
                for _ in 0..copies {
                    let spread = (rng.unit() * 2.0 - 1.0) * imp.jitter.as_secs_f64();
                    let delay = imp.base.as_secs_f64() + spread;
                    let due = Instant::now() + Duration::from_secs_f64(delay.max(0.0));
                    order += 1;
                    queue.push(Reverse((due, order, receiver, data.clone())));
                }
            }
        }
        let now = Instant::now();
        while queue.peek().is_some_and(|Reverse((due, ..))| *due <= now) {
            let Reverse((_, _, to, data)) = queue.pop().unwrap();
            if data.len() >= 12 && !(200..=204).contains(&data[1]) {
                let seq = u16::from_be_bytes([data[2], data[3]]);
                if last_release_seq.is_some_and(|l| seq.wrapping_sub(l) > 0x8000) {
                    counts.reordered += 1;
                }
                last_release_seq = Some(seq);
            }
            let _ = socket.send_to(&data, to);
        }
    }
    counts
}

fn impaired_call(imp: Impairment, codec: &str) {
    let dir = tempfile::tempdir().unwrap();
    let demo = common::demo_8k(dir.path());
    let clip = dir.path().join("clip.wav");
    run(Command::new("sox")
        .arg(&demo)
        .arg(&clip)
        .args(["trim", "0", "4"]));
    let out = dir.path().join("played.wav");
    let features = dir.path().join("features.csv");
    let weights = dir.path().join("weights.csv");

    // The receiver binds a port of its own and says which once it listens.
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0"])
            .arg("--wav")
            .arg(&out)
            .arg("--features")
            .arg(&features)
            .arg("--weights")
            .arg(&weights)
            .args(["--seconds", "15"])
            .env("LIPCALL_KEY", "impaired")
            // Compared with the 8 kHz source whatever the codec's own rate.
            .args(["--rate", "8000"]),
        Announce::Lipcall,
    );
    let receiver_addr: SocketAddr = receiver.addr().parse().unwrap();
    let proxy_socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let proxy_addr = proxy_socket.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let proxy_thread = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || proxy(proxy_socket, receiver_addr, imp, stop))
    };

    run(lipcall()
        .arg("send")
        .arg(&clip)
        .args([
            "--to",
            &proxy_addr.to_string(),
            "--name",
            "Imp",
            "--codec",
            codec,
        ])
        .env("LIPCALL_KEY", "impaired"));
    // The receiver stops by itself once the sender's BYE has been played out.
    let (_, stderr) = receiver.finish(Duration::from_secs(40), "lipcall receive");
    stop.store(true, Ordering::Relaxed);
    let counts = proxy_thread.join().unwrap();
    eprintln!("{imp:?}\n{counts:?}\n{stderr}");

    let sent_frames = 200; // 4 s of 20 ms frames
    assert_eq!(counts.media, sent_frames);
    assert!(
        counts.reordered > 0,
        "the proxy reordered nothing: {counts:?}"
    );
    assert!(counts.duplicated > 0, "{counts:?}");

    let peer = fields(&stderr, "peer ");
    assert_eq!(peer["name"], "Imp");
    assert_eq!(peer["codec"], codec);
    let (received, played, lost, late) = (
        num(&peer, "received"),
        num(&peer, "played"),
        num(&peer, "lost"),
        num(&peer, "late"),
    );
    let (stretched, dropped) = (num(&peer, "stretched"), num(&peer, "dropped"));
    let concealed = num(&peer, "concealed");
    let recovered = num(&peer, "recovered");
    assert_eq!(received as u64, counts.media - counts.dropped);
    // With SRTP the replay window catches duplicates before the jitter buffer sees them.
    let session = fields(&stderr, "lipcall: played");
    assert_eq!(
        num(&peer, "duplicates") + num(&session, "replayed"),
        counts.duplicated as f64
    );
    assert_eq!(num(&session, "auth_failed"), 0.0);
    if codec == "opus" {
        // The losses whose next packet came in time and carried FEC (speech, not silence).
        assert!(recovered >= 0.3 * counts.dropped as f64, "{peer:?}");
    } else {
        assert_eq!(recovered, 0.0);
    }
    // Loss is what the sequence numbers show missing: every packet the proxy dropped, but for
    // any after the last one that came (no later sequence number reveals those).
    assert!(lost <= counts.dropped as f64, "{peer:?}");
    assert!(lost + 3.0 >= counts.dropped as f64, "{peer:?}");
    assert!(late <= 20.0, "{peer:?}");

    // Duration: every frame of the stream was played, concealed or (Opus) rebuilt from the
    // next packet's FEC exactly once; frames the buffer inserted or skipped to follow the
    // jitter are accounted for explicitly.
    let (_, pcm) = read_wav_i16(&out);
    assert_eq!(pcm.len() % 160, 0);
    let frames = (pcm.len() / 160) as f64;
    assert_eq!(frames, played + concealed + recovered, "{peer:?}");
    assert!(concealed + recovered >= lost + stretched, "{peer:?}");
    let net = frames - stretched + dropped;
    assert!(
        (net - sent_frames as f64).abs() <= 1.0,
        "{frames} frames played (+{stretched} inserted, -{dropped} skipped) for {sent_frames} sent"
    );
    assert!(stretched + dropped <= 6.0, "{peer:?}");

    // Continuous: one feature row per played frame, no gap in the timeline; concealed rows
    // carry no mode (recovered ones do: they are decoded audio).
    let csv = std::fs::read_to_string(&features).unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(rows.len() as f64, frames);
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row[0], i.to_string());
        assert_eq!(row.len(), 14);
    }
    let concealed_rows = rows.iter().filter(|r| r[2].is_empty()).count() as f64;
    assert_eq!(concealed_rows, concealed);
    // Weights keep coming through the loss: one convex row per played frame.
    let weights_csv = std::fs::read_to_string(&weights).unwrap();
    let weight_rows: Vec<Vec<f32>> = weights_csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').skip(2).map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(weight_rows.len() as f64, frames);
    for row in &weight_rows {
        let sum: f32 = row.iter().sum();
        assert!(
            (sum - 1.0).abs() < 2e-3 && row.iter().all(|&w| w >= 0.0),
            "{row:?}"
        );
    }
    // Audio never drops to digital silence for a whole frame inside the spurt unless the
    // source was silent there: check the played audio has no run of 3+ all-zero frames.
    let zero_run = pcm
        .chunks(160)
        .map(|c| c.iter().all(|&s| s == 0))
        .fold((0, 0), |(run, max), z| {
            if z {
                (run + 1, max.max(run + 1))
            } else {
                (0, max)
            }
        })
        .1;
    assert!(zero_run < 3, "{zero_run} silent frames in a row");
}

const FIVE_PERCENT: Impairment = Impairment {
    loss: 0.05,
    base: Duration::from_millis(30),
    jitter: Duration::from_millis(30),
    duplicate: 0.03,
    seed: 5,
};

const FIFTEEN_PERCENT: Impairment = Impairment {
    loss: 0.15,
    base: Duration::from_millis(30),
    jitter: Duration::from_millis(30),
    duplicate: 0.03,
    seed: 15,
};

#[test]
fn five_percent_loss_with_jitter_reordering_and_duplicates() {
    impaired_call(FIVE_PERCENT, "speex");
}

#[test]
fn fifteen_percent_loss_with_jitter_reordering_and_duplicates() {
    impaired_call(FIFTEEN_PERCENT, "speex");
}

#[test]
fn opus_five_percent_loss_with_jitter_reordering_and_duplicates() {
    impaired_call(FIVE_PERCENT, "opus");
}

#[test]
fn opus_fifteen_percent_loss_with_jitter_reordering_and_duplicates() {
    impaired_call(FIFTEEN_PERCENT, "opus");
}

//! Calls through a real Mumble server (Debian's murmurd, started here with its own ini on a
//! free loopback port): two lipcalls hear each other over UDP and through the TLS tunnel, and
//! a restarted server is said and rejoined.

mod common;

use std::time::Duration;

use common::mumble::{Murmur, lipcall_as, runs_here};
use common::net::{Announce, finish, spawn, spawn_listening};
use common::segmental_snr;
use common::{demo_8k, lipcall, read_wav_i16, repo_file};

/// `receive --mumble` as Rx, started before the sender; it ends when the sender has left.
fn receiver(dir: &std::path::Path, murmur: &Murmur, extra: &[&str]) -> std::process::Child {
    let child = spawn(
        lipcall_as(dir, "rx")
            .args(["receive", "--mumble", &murmur.address(), "--name", "Rx"])
            // Compared with the 8 kHz source.
            .args(["--rate", "8000"])
            .arg("--wav")
            .arg(dir.join("rx.wav"))
            .arg("--weights")
            .arg(dir.join("rx.csv"))
            .args(extra),
    );
    // Joined before the sender speaks.
    std::thread::sleep(Duration::from_millis(1500));
    child
}

/// `send --mumble` of the demo speech as Ann.
fn sender(dir: &std::path::Path, murmur: &Murmur, extra: &[&str]) -> std::process::Child {
    spawn(
        lipcall_as(dir, "ann")
            .arg("send")
            .arg(repo_file("assets/speech/demo.wav"))
            .args(["--mumble", &murmur.address(), "--name", "Ann"])
            .args(extra),
    )
}

/// lipcall's own Opus round trip at the same bitrate, direct over RTP: the reference SNR.
fn direct_opus_snr(dir: &std::path::Path, source: &[i16]) -> f64 {
    let wav = dir.join("direct.wav");
    let rx = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0", "--seconds", "11"])
            .args(["--rate", "8000"])
            .arg("--wav")
            .arg(&wav),
        Announce::Lipcall,
    );
    let tx = spawn(
        lipcall()
            .arg("send")
            .arg(repo_file("assets/speech/demo.wav"))
            .args(["--to", &rx.addr(), "--codec", "opus"]),
    );
    finish(tx, Duration::from_secs(30), "lipcall send --codec opus");
    rx.finish(Duration::from_secs(30), "lipcall receive");
    segmental_snr(source, &read_wav_i16(&wav).1, 2000).0
}

fn field(stderr: &str, key: &str) -> u64 {
    stderr
        .split_whitespace()
        .find_map(|w| w.strip_prefix(&format!("{key}=")))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {key}= in {stderr}"))
}

#[test]
fn two_lipcalls_on_murmur_hear_each_other_and_the_receiver_animates() {
    if !runs_here("two_lipcalls_on_murmur_hear_each_other_and_the_receiver_animates") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let source = read_wav_i16(&demo_8k(dir.path())).1;
    let rx = receiver(dir.path(), &murmur, &[]);
    let (_, sent) = finish(
        sender(dir.path(), &murmur, &[]),
        Duration::from_secs(40),
        "lipcall send --mumble",
    );
    let (_, received) = finish(rx, Duration::from_secs(40), "lipcall receive --mumble");
    assert!(sent.contains("is now trusted"), "first visit: {sent}");
    assert!(sent.contains("voice goes by UDP"), "{sent}");
    assert!(
        received.contains("\"Ann\"") && received.contains("left"),
        "{received}"
    );
    assert!(field(&received, "udp") >= 400, "{received}");
    assert!(received.contains("name=\"Ann\""), "{received}");

    let got = read_wav_i16(&dir.path().join("rx.wav")).1;
    let snr = segmental_snr(&source, &got, 2000).0;
    let direct = direct_opus_snr(dir.path(), &source);
    eprintln!(
        "SNR through murmur {snr:.2} dB, direct Opus round trip {direct:.2} dB; received {:.2} s \
         of {:.2} s",
        got.len() as f64 / 8000.0,
        source.len() as f64 / 8000.0
    );
    assert!(
        (snr - direct).abs() <= 1.0,
        "murmur {snr:.2} dB vs direct {direct:.2} dB\n{received}"
    );
    assert!(
        direct > 5.0,
        "the reference itself is sound: {direct:.2} dB"
    );
    assert!(
        got.len() as f64 >= source.len() as f64 * 0.97,
        "{} samples",
        got.len()
    );

    let csv = std::fs::read_to_string(dir.path().join("rx.csv")).unwrap();
    let mut lines = csv.lines();
    assert!(lines.next().unwrap().starts_with("frame,time_s,"));
    let first: Vec<f64> = lines
        .map(|r| r.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    assert!(
        first.len() * 160 >= got.len() * 95 / 100,
        "{} rows",
        first.len()
    );
    let (lo, hi) = first
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi - lo > 0.2, "the mouth barely moves: {lo}..{hi}");

    // The second visit knows the server's certificate.
    let (_, again) = finish(
        spawn(
            lipcall_as(dir.path(), "ann")
                .arg("send")
                .arg(dir.path().join("demo8k.wav"))
                .args(["--mumble", &murmur.address(), "--name", "Ann"]),
        ),
        Duration::from_secs(40),
        "second send",
    );
    assert!(again.contains("trusted before"), "{again}");
}

/// `send --mumble --frame-ms 10`: twice the voice packets (Mumble clients send 10 ms frames
/// natively; the sequence counts 10 ms), the whole speech played, a weights row per 20 ms.
#[test]
fn ten_ms_frames_through_murmur_play_whole_and_animate() {
    if !runs_here("ten_ms_frames_through_murmur_play_whole_and_animate") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let source = read_wav_i16(&demo_8k(dir.path())).1;
    let rx = receiver(dir.path(), &murmur, &[]);
    finish(
        sender(dir.path(), &murmur, &["--frame-ms", "10"]),
        Duration::from_secs(40),
        "lipcall send --mumble --frame-ms 10",
    );
    let (_, received) = finish(rx, Duration::from_secs(40), "lipcall receive --mumble");
    // 8.8 s: 440 packets of 20 ms, 880 of 10.
    assert!(field(&received, "udp") >= 800, "{received}");
    assert_eq!(field(&received, "decode_errors"), 0, "{received}");
    let got = read_wav_i16(&dir.path().join("rx.wav")).1;
    assert!(
        got.len() as f64 >= source.len() as f64 * 0.97,
        "{} samples",
        got.len()
    );
    let rows = std::fs::read_to_string(dir.path().join("rx.csv"))
        .unwrap()
        .lines()
        .count()
        - 1;
    assert_eq!(rows * 160, got.len(), "a row per 20 ms played");
}

#[test]
fn with_udp_blocked_the_tls_tunnel_carries_the_call() {
    if !runs_here("with_udp_blocked_the_tls_tunnel_carries_the_call") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let source = read_wav_i16(&demo_8k(dir.path())).1;
    let rx = receiver(dir.path(), &murmur, &["--tcp-only"]);
    let (_, sent) = finish(
        sender(dir.path(), &murmur, &["--tcp-only"]),
        Duration::from_secs(40),
        "lipcall send --mumble --tcp-only",
    );
    let (_, received) = finish(rx, Duration::from_secs(40), "lipcall receive --tcp-only");
    assert_eq!(field(&sent, "udp_sent"), 0, "{sent}");
    assert!(field(&sent, "tunnel_sent") >= 400, "{sent}");
    assert_eq!(field(&received, "udp"), 0, "{received}");
    assert!(field(&received, "tunnel") >= 400, "{received}");
    let got = read_wav_i16(&dir.path().join("rx.wav")).1;
    let snr = segmental_snr(&source, &got, 2000).0;
    eprintln!("SNR through the tunnel {snr:.2} dB");
    assert!(snr > 5.0, "{snr:.2} dB\n{received}");
    assert!(
        got.len() as f64 >= source.len() as f64 * 0.97,
        "{} samples",
        got.len()
    );
}

#[test]
fn a_restarted_murmur_is_said_and_rejoined_and_the_call_goes_on() {
    if !runs_here("a_restarted_murmur_is_said_and_rejoined_and_the_call_goes_on") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut murmur = Murmur::start(dir.path(), "");
    let rx = receiver(dir.path(), &murmur, &["--seconds", "16"]);
    let tx = sender(dir.path(), &murmur, &[]);
    std::thread::sleep(Duration::from_secs(3));
    murmur.restart(Duration::from_millis(500));
    let (_, sent) = finish(tx, Duration::from_secs(40), "lipcall send across a restart");
    let (_, received) = finish(
        rx,
        Duration::from_secs(40),
        "lipcall receive across a restart",
    );
    for (who, stderr) in [("sender", &sent), ("receiver", &received)] {
        assert!(stderr.contains("lost the Mumble server"), "{who}: {stderr}");
        assert!(
            stderr.contains("back on the Mumble server"),
            "{who}: {stderr}"
        );
    }
    // Ann is heard again after the restart: her new session (listed after the one the restart
    // cut) played seconds of speech.
    let ann = received
        .lines()
        .rev()
        .find(|l| l.starts_with("peer ") && l.contains("name=\"Ann\""))
        .unwrap_or_else(|| panic!("{received}"));
    assert!(field(ann, "played") > 100, "{received}");
}

/// A TCP relay on loopback to `to` that holds each connection `hold` before passing it on (a
/// server slow to answer the handshake).
fn slow_tcp_relay(to: std::net::SocketAddr, hold: Duration) -> std::net::SocketAddr {
    use std::net::{Shutdown, TcpListener, TcpStream};
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let at = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        for client in listener.incoming().take(4).flatten() {
            std::thread::spawn(move || {
                std::thread::sleep(hold);
                let Ok(server) = TcpStream::connect(to) else {
                    return;
                };
                let pump = |mut from: TcpStream, mut to: TcpStream| {
                    std::thread::spawn(move || {
                        let _ = std::io::copy(&mut from, &mut to);
                        let _ = to.shutdown(Shutdown::Write);
                    })
                };
                pump(client.try_clone().unwrap(), server.try_clone().unwrap());
                pump(server, client);
            });
        }
    });
    at
}

/// `--seconds` counts from the command's start, the join included: a server that takes 2 s
/// and more to let us in leaves an 8 s receive 6 s in the channel at most (it was the join,
/// then 8 s more).
#[test]
fn seconds_count_the_join_too() {
    if !runs_here("seconds_count_the_join_too") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let slow = slow_tcp_relay(murmur.address().parse().unwrap(), Duration::from_secs(2));
    let started = std::time::Instant::now();
    let rx = spawn(
        lipcall_as(dir.path(), "rx")
            .args(["receive", "--mumble", &slow.to_string(), "--name", "Rx"])
            .args(["--tcp-only", "--seconds", "8"]),
    );
    let (_, received) = finish(rx, Duration::from_secs(30), "lipcall receive --seconds 8");
    let took = started.elapsed();
    eprintln!("--seconds 8 with a join held 2 s took {took:?}: {received}");
    assert!(
        received.contains("lipcall: joined as session"),
        "{received}"
    );
    assert!(
        took >= Duration::from_secs(8) && took < Duration::from_millis(9500),
        "took {took:?}: {received}"
    );
}

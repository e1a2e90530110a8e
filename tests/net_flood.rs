//! A flood of new SSRCs on a real socket: one UDP socket on 127.0.0.1 sends 2,000 valid
//! packets a second, each from a new SSRC, while a real `lipcall send` calls `receive`. The
//! caller must still be heard.

mod common;

use std::net::UdpSocket;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::net::{finish, new_ssrc_flood, spawn, start_receiver};
use common::{lipcall, repo_file};
use lipcall::net::rtp::RtpStream;

#[test]
fn a_caller_is_heard_through_a_flood_of_new_ssrcs() {
    let receiver = start_receiver(&["--seconds", "11"]);
    let stop = Arc::new(AtomicBool::new(false));
    let flood = {
        let stop = Arc::clone(&stop);
        let to = receiver.socket_addr();
        std::thread::spawn(move || new_ssrc_flood(to, &stop))
    };
    std::thread::sleep(Duration::from_millis(500));
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(repo_file("assets/speech/demo.wav"))
            .args(["--to", &receiver.addr()]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send");
    stop.store(true, Ordering::Relaxed);
    let flooded = flood.join().unwrap();
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive");
    let played = received
        .lines()
        .filter(|l| l.starts_with("peer "))
        .filter_map(|l| {
            l.split_whitespace()
                .find_map(|kv| kv.strip_prefix("played="))
                .and_then(|v| v.parse::<u32>().ok())
        })
        .max()
        .unwrap_or(0);
    // demo.wav is 8.8 s: 441 frames of 20 ms.
    eprintln!("flood of {flooded} packets; the caller played {played} frames\n{sent}");
    assert!(flooded > 10_000, "{flooded}");
    assert!(
        played >= 397,
        "the caller played {played} of 441 frames:\n{received}"
    );
}

/// Open file descriptors of a process.
fn open_files(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/fd")).map_or(0, |d| d.count())
}

#[test]
fn short_lived_ssrcs_leave_no_files_open_behind_them() {
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("w.csv");
    let receiver = start_receiver(&["--seconds", "11", "--weights", weights.to_str().unwrap()]);
    let pid = receiver.pid();
    let to = receiver.socket_addr();
    let stop = Arc::new(AtomicBool::new(false));
    // 40 new SSRCs a second, 3 packets each: every one plays a little, then is gone.
    let flood = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
            let mut ssrcs = 0u32;
            let start = Instant::now();
            while !stop.load(Ordering::Relaxed) {
                let mut stream = RtpStream::new(0, 0, 0);
                stream.ssrc = 0x5000_0000 + ssrcs;
                stream.set_payload(0, 160);
                for _ in 0..3 {
                    let mut buf = Vec::new();
                    stream.packetize(&[0x55; 160], 1, &mut buf).unwrap();
                    let _ = socket.send_to(&buf, to);
                }
                ssrcs += 1;
                let due = start + Duration::from_millis(25 * u64::from(ssrcs));
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
            }
            ssrcs
        })
    };
    std::thread::sleep(Duration::from_secs(5));
    let early = open_files(pid);
    std::thread::sleep(Duration::from_secs(4));
    let late = open_files(pid);
    stop.store(true, Ordering::Relaxed);
    let ssrcs = flood.join().unwrap();
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive");
    let files = std::fs::read_dir(dir.path()).unwrap().count();
    eprintln!("{ssrcs} SSRCs, {files} CSV files; open files {early} at 5 s, {late} at 9 s");
    assert!(files > 100, "each caller got its file: {files}\n{received}");
    assert!(
        late <= early + 30 && late < 250,
        "open files grow with the callers gone: {early} at 5 s, {late} at 9 s"
    );
}

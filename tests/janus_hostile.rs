//! `receive --janus` against a scripted Janus that misbehaves (tests/data/scripted_janus.py on
//! 127.0.0.1): publishers churning faster than they can be subscribed to, answers that never
//! come, floods of events, a publisher without Opus, a server that is not Janus. The call must
//! end on time, stop at one SIGINT, keep its memory and stay in the room.

mod common;

use std::process::Command;
use std::time::{Duration, Instant};

use common::janus::{IN_ROOM, scripted};
use common::lipcall;
use common::net::{spawn, spawn_listening};

fn receive(url: &str, seconds: &str) -> Command {
    let mut cmd = lipcall();
    cmd.args([
        "receive",
        "--janus",
        url,
        "--room",
        "r",
        "--seconds",
        seconds,
    ]);
    cmd
}

#[test]
fn publishers_churning_faster_than_subscriptions_answer_neither_hold_the_call_nor_a_stop() {
    let Some(janus) = scripted("churn") else {
        return;
    };
    let started = Instant::now();
    let rx = spawn_listening(&mut receive(&janus.url, "4"), IN_ROOM);
    let (_, stderr) = rx.finish(Duration::from_secs(30), "receive --janus --seconds 4");
    let took = started.elapsed();
    assert!(took < Duration::from_secs(9), "took {took:?}: {stderr}");

    let rx = spawn_listening(&mut receive(&janus.url, "60"), IN_ROOM);
    std::thread::sleep(Duration::from_secs(2));
    let asked = Instant::now();
    rx.interrupt();
    let (_, stderr) = rx.finish(Duration::from_secs(30), "receive --janus after SIGINT");
    let took = asked.elapsed();
    assert!(
        took < Duration::from_millis(1500),
        "one SIGINT took {took:?}: {stderr}"
    );
}

#[test]
fn a_flood_of_unsolicited_events_keeps_memory_flat_and_the_join_times_out() {
    let Some(janus) = scripted("flood") else {
        return;
    };
    let mut cmd = receive(&janus.url, "5");
    let child = spawn(&mut cmd);
    let pid = child.id();
    let mut peak: f64 = 0.0;
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(25) {
        match common::rss_mb(pid) {
            Some(mb) => peak = peak.max(mb),
            None => break,
        }
        if std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| s.contains(") Z ")) {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut child = child;
    let _ = child.kill();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("peak RSS {peak:.1} MB; {stderr}");
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(peak < 150.0, "peak RSS {peak:.1} MB");
    assert!(stderr.contains("no answer from Janus"), "{stderr}");
}

#[test]
fn a_publisher_without_opus_is_skipped_and_the_room_kept() {
    let Some(janus) = scripted("noopus") else {
        return;
    };
    let out = receive(&janus.url, "3").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("\"PCMU phone\" (55) cannot be heard, skipped")
            && stderr.contains("no Opus"),
        "{stderr}"
    );
    assert!(!stderr.contains("lost the Janus room"), "{stderr}");
}

#[test]
fn a_janus_that_falls_silent_lets_the_call_end_on_time() {
    let Some(janus) = scripted("mute") else {
        return;
    };
    let started = Instant::now();
    let rx = spawn_listening(&mut receive(&janus.url, "3"), IN_ROOM);
    let (_, stderr) = rx.finish(Duration::from_secs(60), "receive --janus (mute)");
    let took = started.elapsed();
    assert!(took < Duration::from_secs(8), "took {took:?}: {stderr}");
}

#[test]
fn a_server_that_is_not_janus_is_told_from_an_unreachable_one() {
    let Some(janus) = scripted("garbage") else {
        return;
    };
    let out = receive(&janus.url, "2").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("not as Janus does"), "{stderr}");
    assert!(!stderr.contains("cannot reach"), "{stderr}");
}

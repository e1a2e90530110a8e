//! lipcall against a Janus as Debian ships it: the VideoRoom's own configuration, which numbers
//! rooms and publishers (`string_ids` unset) and has a demo room 1234. Each test runs in a
//! network namespace of its own (tests/common/netns.rs).

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::janus::{
    IN_ROOM, STOCK_VIDEOROOM, envelope, envelope_correlation, receive_in_room, start_janus_with,
};
use common::net::{finish, spawn, spawn_listening};
use common::{lipcall, repo_file};

fn stock_janus_here(test: &str) -> bool {
    if !common::janus::runs_here(test) {
        return false;
    }
    if !Path::new(STOCK_VIDEOROOM).exists() {
        common::unavailable("no stock VideoRoom configuration (Debian package janus)");
        return false;
    }
    true
}

#[test]
fn a_stock_janus_numbering_its_rooms_carries_a_call() {
    if !stock_janus_here("a_stock_janus_numbering_its_rooms_carries_a_call") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus_with(dir.path(), &[Path::new(STOCK_VIDEOROOM)]);
    let speech = repo_file("assets/speech/demo.wav");
    let wav = dir.path().join("stock.wav");
    let weights = dir.path().join("stock-weights.csv");
    // Room 4321 does not exist: the receiver creates it (by number) and the sender joins it.
    let receiver = receive_in_room(&janus, "4321", "pin 4321", "13", &wav, &weights);
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(&speech)
            .args(["--janus", &janus.url, "--room", "4321"])
            .env("LIPCALL_KEY", "pin 4321")
            .args(["--name", "Ann"]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    assert!(
        received.contains("\"Ann\"") && received.contains("is publishing"),
        "sender: {sent}\nreceiver: {received}"
    );
    let heard = envelope(&wav);
    let spoken = envelope(&speech);
    let r = envelope_correlation(&spoken, &heard);
    eprintln!(
        "level contour r {r:.3}; {} of {} frames heard",
        heard.len(),
        spoken.len()
    );
    assert!(r > 0.9, "the speech is heard: r {r:.3}\n{received}");
    assert!(heard.len() * 100 >= spoken.len() * 95, "{received}");
    let rows = std::fs::read_to_string(&weights).unwrap().lines().count() - 1;
    assert!(rows * 100 >= spoken.len() * 95, "{rows} weight rows");
}

#[test]
fn a_stock_janus_s_own_demo_room_is_joined_and_a_room_name_is_refused_clearly() {
    if !stock_janus_here(
        "a_stock_janus_s_own_demo_room_is_joined_and_a_room_name_is_refused_clearly",
    ) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus_with(dir.path(), &[Path::new(STOCK_VIDEOROOM)]);
    let member = spawn_listening(
        lipcall()
            .args(["receive", "--janus", &janus.url, "--room", "1234"])
            .args(["--seconds", "2"]),
        IN_ROOM,
    );
    member.finish(Duration::from_secs(20), "receive in the demo room 1234");

    let started = Instant::now();
    let out = lipcall()
        .args(["receive", "--janus", &janus.url, "--room", "lipcall-test"])
        .args(["--seconds", "2"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("numbers its rooms") && stderr.contains("--room 1234"),
        "{stderr}"
    );
    assert!(started.elapsed() < Duration::from_secs(5), "{stderr}");

    // A number on a Janus that names rooms by strings (the repository's config) is a name there.
    let own_dir = tempfile::tempdir().unwrap();
    let own = start_janus_with(own_dir.path(), &[]);
    let member = spawn_listening(
        lipcall()
            .args(["receive", "--janus", &own.url, "--room", "1234"])
            .args(["--seconds", "2"]),
        IN_ROOM,
    );
    member.finish(Duration::from_secs(20), "receive in room \"1234\" by name");
}

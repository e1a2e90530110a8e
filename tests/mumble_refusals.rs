//! A Mumble server that turns us down, and one that is not the server we trusted: a clear
//! one-line message, exit status 1, and nothing hangs (a real murmurd, its own ini, a free
//! loopback port).

mod common;

use std::process::Output;
use std::time::{Duration, Instant};

use common::mumble::{Murmur, lipcall_as, runs_here};
use common::repo_file;

/// Runs `send --mumble` as `name` with `extra` flags; it must fail within 20 s.
fn refused(
    dir: &std::path::Path,
    who: &str,
    murmur: &Murmur,
    name: &str,
    extra: &[&str],
) -> String {
    let start = Instant::now();
    let out: Output = lipcall_as(dir, who)
        .arg("send")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["--mumble", &murmur.address(), "--name", name])
        .args(extra)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        start.elapsed() < Duration::from_secs(20),
        "took {:?}",
        start.elapsed()
    );
    let last = stderr.lines().last().unwrap_or_default().to_string();
    assert!(last.starts_with("lipcall: "), "{stderr}");
    last
}

/// A `receive --mumble` as `name` that stays in for 30 s; returns once it has joined.
fn holder(dir: &std::path::Path, who: &str, murmur: &Murmur, name: &str) -> std::process::Child {
    let log = dir.join(format!("{who}.log"));
    let child = lipcall_as(dir, who)
        .args([
            "receive",
            "--mumble",
            &murmur.address(),
            "--name",
            name,
            "--seconds",
            "30",
        ])
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while !std::fs::read_to_string(&log)
        .unwrap_or_default()
        .contains("joined as")
    {
        assert!(
            Instant::now() < deadline,
            "{name} did not join: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    child
}

#[test]
fn a_wrong_server_password_is_refused_clearly() {
    if !runs_here("a_wrong_server_password_is_refused_clearly") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "serverpassword=open sesame");
    let without = refused(dir.path(), "a", &murmur, "Ann", &[]);
    assert!(without.contains("wrong server password"), "{without}");
    let guess = dir.path().join("guess");
    std::fs::write(&guess, "guess\n").unwrap();
    let guess = guess.to_str().unwrap();
    let wrong = refused(dir.path(), "a", &murmur, "Ann", &["--password-file", guess]);
    assert!(wrong.contains("wrong server password"), "{wrong}");
}

#[test]
fn a_full_server_a_name_taken_over_and_a_refused_name_are_said_clearly() {
    if !runs_here("a_full_server_and_a_name_in_use_are_refused_clearly") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "users=1");
    let mut first = lipcall_as(dir.path(), "first")
        .args([
            "receive",
            "--mumble",
            &murmur.address(),
            "--name",
            "Ann",
            "--seconds",
            "30",
        ])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    let full = refused(dir.path(), "second", &murmur, "Bob", &[]);
    assert!(full.contains("the server is full"), "{full}");
    let taken = refused(dir.path(), "third", &murmur, "Ann", &[]);
    assert!(
        taken.contains("name is in use") || taken.contains("the server is full"),
        "{taken}"
    );
    let _ = first.kill();
    let _ = first.wait();

    // On a server with room, a name in use from the same address counts as a reconnect of
    // a ghost: murmur removes the older session. That one says so and ends, status 1.
    let roomy = Murmur::start(&dir.path().join("roomy"), "username=[A-Za-z]+");
    let ghost = holder(dir.path(), "first-roomy", &roomy, "Ann");
    let mut newer = lipcall_as(dir.path(), "third")
        .args([
            "receive",
            "--mumble",
            &roomy.address(),
            "--name",
            "Ann",
            "--seconds",
            "30",
        ])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let out = ghost.wait_with_output().unwrap();
    let _ = newer.kill();
    let _ = newer.wait();
    let log = std::fs::read_to_string(dir.path().join("first-roomy.log")).unwrap();
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(start.elapsed() < Duration::from_secs(20), "{log}");
    assert!(log.contains("the Mumble server removed us"), "{log}");
    assert!(
        !log.contains("reconnecting"),
        "a removed client does not fight back: {log}"
    );
    // A name the server's rule refuses.
    let bad = refused(dir.path(), "third", &roomy, "Ann 2", &[]);
    assert!(bad.contains("does not accept this name"), "{bad}");
}

#[test]
fn a_missing_channel_and_a_changed_certificate_are_refused_clearly() {
    if !runs_here("a_missing_channel_and_a_changed_certificate_are_refused_clearly") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "");
    let missing = refused(dir.path(), "a", &murmur, "Ann", &["--channel", "Nowhere"]);
    assert!(
        missing.contains("no channel named \"Nowhere\""),
        "{missing}"
    );
    // The first visit kept the server's fingerprint; another one under that address is refused.
    let known = dir.path().join("config-a/lipcall/mumble/known_servers");
    let text = std::fs::read_to_string(&known).unwrap();
    assert!(text.contains(&murmur.address()), "{text}");
    let forged = format!("{} AA:BB:CC\n", murmur.address());
    std::fs::write(&known, forged).unwrap();
    let changed = refused(dir.path(), "a", &murmur, "Ann", &[]);
    assert!(
        changed.contains("certificate of")
            && changed.contains("changed")
            && changed.contains("AA:BB:CC"),
        "{changed}"
    );
}

#[test]
fn a_server_back_with_another_certificate_ends_the_receive() {
    if !runs_here("a_server_back_with_another_certificate_ends_the_receive") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut murmur = Murmur::start(dir.path(), "");
    let mut rx = holder(dir.path(), "rx", &murmur, "Rx");
    let known = dir.path().join("config-rx/lipcall/mumble/known_servers");
    std::fs::write(&known, format!("{} AA:BB:CC\n", murmur.address())).unwrap();
    murmur.restart(Duration::from_millis(300));
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = rx.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            let _ = rx.kill();
            panic!("the receive went on after the certificate changed");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let log = std::fs::read_to_string(dir.path().join("rx.log")).unwrap();
    assert_eq!(status.code(), Some(1), "{log}");
    let last = log.lines().last().unwrap_or_default();
    assert!(
        last.contains("certificate of") && last.contains("not reconnecting"),
        "{log}"
    );
}

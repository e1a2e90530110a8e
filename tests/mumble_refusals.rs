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

#[test]
fn a_wrong_server_password_is_refused_clearly() {
    if !runs_here("a_wrong_server_password_is_refused_clearly") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur = Murmur::start(dir.path(), "serverpassword=open sesame");
    let without = refused(dir.path(), "a", &murmur, "Ann", &[]);
    assert!(without.contains("wrong server password"), "{without}");
    let wrong = refused(dir.path(), "a", &murmur, "Ann", &["--password", "guess"]);
    assert!(wrong.contains("wrong server password"), "{wrong}");
}

#[test]
fn a_full_server_and_a_name_in_use_are_refused_clearly() {
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

    // On a server with room, the name itself is what is refused.
    let roomy = Murmur::start(&dir.path().join("roomy"), "");
    let mut holder = lipcall_as(dir.path(), "first")
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
    std::thread::sleep(Duration::from_secs(2));
    let taken = refused(dir.path(), "third", &roomy, "Ann", &[]);
    assert!(taken.contains("name is in use"), "{taken}");
    let bad = refused(dir.path(), "third", &roomy, "", &[]);
    assert!(bad.contains("does not accept this name"), "{bad}");
    let _ = holder.kill();
    let _ = holder.wait();
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

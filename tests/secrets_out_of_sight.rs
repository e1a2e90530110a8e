//! Every secret lipcall takes (a room passphrase, a raw SRTP key, a Mumble server's password, a
//! Janus's api_secret and token, a TURN password) comes from the environment or a file: each
//! command is run with its secrets while a watcher reads the child's /proc/PID/cmdline and
//! core limit, with `RUST_LOG=trace`: no secret is in the arguments or the log, and core dumps
//! are off. The old flags that took a secret are usage errors, so no test can pass one.

mod common;

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::janus::scripted;
use common::repo_file;

const ROOM_KEY: &str = "room-passphrase-7f3a9c21e4";
const MUMBLE_PASSWORD: &str = "mumble-password-5b8d0e6f12";
const JANUS_SECRET: &str = "janus-api-secret-c4e1a7b930";
const JANUS_TOKEN: &str = "janus-token-91d2f08b7a6c";
const TURN_PASSWORD: &str = "turn-password-3e6a1f9d04";
/// 30 bytes of SRTP master key + salt.
const HEX_KEY: &str = "6c69706361 6c6c2d7365637265742d6865786b65792d3132333435363738";

fn hex_key() -> String {
    HEX_KEY.replace(' ', "")
}

/// What the watcher saw of one command.
struct Watched {
    cmdline: String,
    core_limit: String,
    stderr: String,
    code: Option<i32>,
}

/// Runs lipcall with `args` and `env` (core dumps allowed where it starts, as a user's shell
/// may), `RUST_LOG=trace`; reads its arguments and core limit every 20 ms from `look_after` in
/// while it runs (the last look kept), and waits up to `limit` for it to end.
fn watch(
    config: &Path,
    args: &[&str],
    env: &[(&str, &str)],
    look_after: Duration,
    limit: Duration,
) -> Watched {
    let mut cmd = Command::new("sh");
    cmd.args(["-c", "ulimit -c unlimited && exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_lipcall"))
        .args(args)
        .env("RUST_LOG", "trace")
        .env("XDG_CONFIG_HOME", config)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    for var in [
        "LIPCALL_KEY",
        "LIPCALL_KEY_HEX",
        "LIPCALL_MUMBLE_PASSWORD",
        "LIPCALL_JANUS_SECRET",
        "LIPCALL_JANUS_TOKEN",
        "LIPCALL_TURN_PASSWORD",
    ] {
        cmd.env_remove(var);
    }
    cmd.envs(env.iter().copied());
    let started = Instant::now();
    let mut child = cmd.spawn().unwrap();
    // stderr is read as it comes: a trace log fills a pipe long before the end.
    let mut pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = Vec::new();
        std::io::Read::read_to_end(&mut pipe, &mut text).unwrap();
        String::from_utf8_lossy(&text).into_owned()
    });
    let proc = PathBuf::from(format!("/proc/{}", child.id()));
    let mut cmdlines = Vec::new();
    let mut core_limit = String::new();
    let status = loop {
        if started.elapsed() >= look_after {
            // Read before the exit check: a process that has exited leaves these empty.
            let cmdline = std::fs::read(proc.join("cmdline")).unwrap_or_default();
            let limits = std::fs::read_to_string(proc.join("limits")).unwrap_or_default();
            if let Some(line) = limits.lines().find(|l| l.starts_with("Max core file size")) {
                core_limit = line.to_owned();
            }
            if !cmdline.is_empty() {
                cmdlines.push(String::from_utf8_lossy(&cmdline).replace('\0', " "));
            }
        }
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    cmdlines.dedup();
    Watched {
        cmdline: cmdlines.join("\n"),
        core_limit,
        stderr: reader.join().unwrap(),
        code: status.and_then(|s| s.code()),
    }
}

impl Watched {
    /// The command ran (its arguments were seen), and none of `secrets` is in its arguments
    /// or its log; core dumps were off.
    fn holds_out_of_sight(&self, what: &str, secrets: &[&str]) {
        assert!(
            self.cmdline.contains("lipcall") || self.cmdline.contains("--"),
            "{what}: the watcher saw no arguments (it ended too soon): {}",
            self.tail()
        );
        for secret in secrets {
            assert!(
                !self.cmdline.contains(secret),
                "{what}: {secret} is in the arguments: {}",
                self.cmdline
            );
            let shown = self.stderr.lines().find(|l| l.contains(secret));
            assert!(shown.is_none(), "{what}: {secret} is in the log: {shown:?}");
        }
        let fields: Vec<_> = self.core_limit.split_whitespace().collect();
        assert_eq!(
            fields.get(4..6),
            Some(&["0", "0"][..]),
            "{what}: core dumps on while a secret is held: {}",
            self.core_limit
        );
    }

    fn tail(&self) -> String {
        let lines: Vec<_> = self.stderr.lines().rev().take(6).collect();
        lines.into_iter().rev().collect::<Vec<_>>().join("\n")
    }
}

fn secret_file(dir: &Path, name: &str, secret: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, format!("{secret}\n")).unwrap();
    path.to_str().unwrap().to_owned()
}

/// A port nothing answers on (bound, so that no ICMP says it is gone).
fn silent_udp() -> (UdpSocket, String) {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = socket.local_addr().unwrap().to_string();
    (socket, addr)
}

#[test]
fn a_keyed_direct_call_keeps_its_passphrase_and_hex_key_out_of_sight() {
    let dir = tempfile::tempdir().unwrap();
    let speech = repo_file("assets/speech/demo.wav");
    let speech = speech.to_str().unwrap();
    let key_file = secret_file(dir.path(), "room-key", ROOM_KEY);
    let port = UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .unwrap()
        .port();
    let listen = format!("127.0.0.1:{port}");
    // A receiver keyed from the environment, a sender from a file: they must agree.
    let receiver = std::thread::spawn({
        let config = dir.path().to_owned();
        let listen = listen.clone();
        move || {
            watch(
                &config,
                // It ends once the sender has said BYE.
                &["receive", "--listen", &listen, "--seconds", "25"],
                &[("LIPCALL_KEY", ROOM_KEY)],
                Duration::from_millis(800),
                Duration::from_secs(40),
            )
        }
    });
    std::thread::sleep(Duration::from_millis(500));
    let sender = watch(
        dir.path(),
        &[
            "send",
            speech,
            "--to",
            &listen,
            "--key-file",
            &key_file,
            "--seconds",
            "1.5",
        ],
        &[],
        Duration::from_millis(500),
        Duration::from_secs(30),
    );
    let receiver = receiver.join().unwrap();
    assert_eq!(sender.code, Some(0), "{}", sender.tail());
    assert_eq!(receiver.code, Some(0), "{}", receiver.tail());
    assert!(
        receiver.stderr.contains("auth_failed=0") && receiver.stderr.contains("peer ssrc="),
        "the keys agreed: {}",
        receiver.tail()
    );
    sender.holds_out_of_sight("send --key-file", &[ROOM_KEY]);
    receiver.holds_out_of_sight("receive with LIPCALL_KEY", &[ROOM_KEY]);

    let (_tap, tap) = silent_udp();
    let hex = hex_key();
    let raw = watch(
        dir.path(),
        &["send", speech, "--to", &tap, "--seconds", "1.5"],
        &[("LIPCALL_KEY_HEX", &hex)],
        Duration::from_millis(500),
        Duration::from_secs(30),
    );
    assert_eq!(raw.code, Some(0), "{}", raw.tail());
    assert!(raw.stderr.contains("media encrypted"), "{}", raw.tail());
    raw.holds_out_of_sight("send with LIPCALL_KEY_HEX", &[&hex]);
}

#[test]
fn a_janus_room_keeps_its_secret_token_pin_and_turn_password_out_of_sight() {
    let Some(janus) = scripted("noopus") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (_turn, turn) = silent_udp();
    let token_file = secret_file(dir.path(), "token", JANUS_TOKEN);
    let watched = watch(
        dir.path(),
        &[
            "receive",
            "--janus",
            &janus.url,
            "--room",
            "1234",
            "--seconds",
            "10",
            "--janus-token-file",
            &token_file,
            "--turn",
            &turn,
            "--turn-user",
            "ann",
        ],
        &[
            ("LIPCALL_KEY", ROOM_KEY),
            ("LIPCALL_JANUS_SECRET", JANUS_SECRET),
            ("LIPCALL_TURN_PASSWORD", TURN_PASSWORD),
        ],
        Duration::from_millis(800),
        Duration::from_secs(30),
    );
    assert!(
        watched.stderr.contains("lipcall: in room"),
        "it joined: {}",
        watched.tail()
    );
    // ureq logs each long poll's URL, its credentials in the query: they pass the redaction.
    assert!(
        watched
            .stderr
            .contains("apisecret=(redacted)&token=(redacted)"),
        "{}",
        watched.tail()
    );
    watched.holds_out_of_sight(
        "receive --janus",
        &[ROOM_KEY, JANUS_SECRET, JANUS_TOKEN, TURN_PASSWORD],
    );

    // Without its password a TURN server is a clear error, not a relay asked with none.
    let out = common::lipcall()
        .args(["receive", "--janus", &janus.url, "--room", "1234"])
        .args(["--seconds", "1", "--turn", &turn, "--turn-user", "ann"])
        .env_remove("LIPCALL_TURN_PASSWORD")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("needs its password: set LIPCALL_TURN_PASSWORD"),
        "{stderr}"
    );
}

#[test]
fn a_mumble_servers_password_stays_out_of_sight() {
    if !common::mumble::runs_here("a_mumble_servers_password_stays_out_of_sight") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let murmur =
        common::mumble::Murmur::start(dir.path(), &format!("serverpassword={MUMBLE_PASSWORD}"));
    let speech = repo_file("assets/speech/demo.wav");
    let address = murmur.address();
    let args = [
        "send",
        speech.to_str().unwrap(),
        "--mumble",
        &address,
        "--name",
        "Ann",
        "--seconds",
        "2",
    ];
    let watched = watch(
        &dir.path().join("config-ann"),
        &args,
        &[("LIPCALL_MUMBLE_PASSWORD", MUMBLE_PASSWORD)],
        Duration::from_millis(800),
        Duration::from_secs(30),
    );
    assert_eq!(watched.code, Some(0), "{}", watched.tail());
    assert!(
        watched.stderr.contains("joined as session"),
        "the password was taken: {}",
        watched.tail()
    );
    watched.holds_out_of_sight("send --mumble", &[MUMBLE_PASSWORD]);
}

#[test]
fn the_flags_that_took_a_secret_are_gone() {
    let speech = repo_file("assets/speech/demo.wav");
    let speech = speech.to_str().unwrap();
    for args in [
        vec!["send", speech, "--to", "127.0.0.1:9", "--key", "x"],
        vec!["send", speech, "--to", "127.0.0.1:9", "--key-hex", "x"],
        vec!["receive", "--listen", "127.0.0.1:0", "--key", "x"],
        vec![
            "send",
            speech,
            "--mumble",
            "127.0.0.1:9",
            "--name",
            "a",
            "--password",
            "x",
        ],
        vec![
            "receive",
            "--janus",
            "http://127.0.0.1:9/janus",
            "--room",
            "1",
            "--janus-secret",
            "x",
        ],
        vec![
            "receive",
            "--janus",
            "http://127.0.0.1:9/janus",
            "--room",
            "1",
            "--janus-token",
            "x",
        ],
        vec![
            "receive",
            "--janus",
            "http://127.0.0.1:9/janus",
            "--room",
            "1",
            "--turn",
            "127.0.0.1:9",
            "--turn-user",
            "a",
            "--turn-password",
            "x",
        ],
        vec!["sip", "answer", "--password", "x"],
    ] {
        let out = common::lipcall().args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains("unexpected argument"), "{args:?}: {stderr}");
    }
}

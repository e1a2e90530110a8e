//! A real Janus for the tests (Debian's `janus`, started with the repository's config folder,
//! assets/janus, its HTTP API on a free loopback port), killed when dropped.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use super::net::{Announce, Listening, spawn_listening};
use super::repo_file;

/// `receive --janus` has joined its room (`lipcall: in room ...` on stderr).
pub const IN_ROOM: Announce = Announce::StderrLine("lipcall: in room ");

/// `lipcall receive --janus` as "Bob" in `room` with `pin`, for `seconds`, writing `wav` and
/// `weights`; returned once it is in the room.
pub fn receive_in_room(
    janus: &Janus,
    room: &str,
    pin: &str,
    seconds: &str,
    wav: &Path,
    weights: &Path,
) -> Listening {
    spawn_listening(
        super::lipcall()
            .args([
                "receive", "--janus", &janus.url, "--room", room, "--key", pin,
            ])
            .args(["--name", "Bob", "--seconds", seconds])
            // Compared with 8 kHz sources (the Opus stream itself is decoded at 48 kHz).
            .args(["--rate", "8000"])
            .arg("--wav")
            .arg(wav)
            .arg("--weights")
            .arg(weights),
        IN_ROOM,
    )
}

/// A Janus process with the repository's config, its HTTP API on a free loopback port.
pub struct Janus {
    child: Child,
    pub url: String,
    port: u16,
    config: PathBuf,
    log: PathBuf,
}

impl Drop for Janus {
    fn drop(&mut self) {
        self.stop();
    }
}

pub fn janus_installed() -> bool {
    Command::new("janus")
        .arg("--help")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Whether this process runs a Janus test's body: not when the test ran in a network namespace
/// of its own (that run reports the outcome), nor when Janus is missing (said, skipped).
pub fn runs_here(test: &str) -> bool {
    if super::netns::ran_in_own_namespace(test) {
        return false;
    }
    if !janus_installed() {
        super::unavailable("no `janus` binary (Debian package janus)");
        return false;
    }
    true
}

pub fn free_tcp_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

/// Starts Janus with a copy of assets/janus in `dir` and waits until its HTTP API listens.
pub fn start_janus(dir: &Path) -> Janus {
    let config = dir.join("janus-config");
    std::fs::create_dir_all(&config).unwrap();
    let port = free_tcp_port();
    for entry in std::fs::read_dir(repo_file("assets/janus")).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        // The one change to the repository's config: the port.
        let text = text.replace("port = 8088", &format!("port = {port}"));
        std::fs::write(config.join(path.file_name().unwrap()), text).unwrap();
    }
    let log = dir.join("janus.log");
    let mut janus = Janus {
        child: run_janus(&config, &log),
        url: format!("http://127.0.0.1:{port}/janus"),
        port,
        config,
        log,
    };
    janus.wait_ready();
    janus
}

fn run_janus(config: &Path, log: &Path) -> Child {
    Command::new("janus")
        .arg("-F")
        .arg(config)
        .arg("-L")
        .arg(log)
        .arg("-N")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("janus starts")
}

impl Janus {
    fn wait_ready(&mut self) {
        let deadline = Instant::now() + Duration::from_secs(15);
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "Janus did not open its HTTP port: {}",
                std::fs::read_to_string(&self.log).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// A fresh Janus on the same port and config, knowing nothing of the old sessions.
    pub fn restart(&mut self) {
        self.stop();
        self.child = run_janus(&self.config, &self.log);
        self.wait_ready();
    }
}

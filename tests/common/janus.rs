//! A real Janus for the tests (Debian's `janus`, started with the repository's config folder,
//! assets/janus, its HTTP API on a free loopback port), killed when dropped; and a scripted,
//! misbehaving one (tests/data/scripted_janus.py).

use std::io::{BufRead, BufReader};
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
            .args(["receive", "--janus", &janus.url, "--room", room])
            .env("LIPCALL_KEY", pin)
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
    start_janus_with(dir, &[])
}

/// Debian's own VideoRoom configuration, as every stock deployment has it: rooms numbered
/// (`string_ids` unset), a demo room 1234.
pub const STOCK_VIDEOROOM: &str = "/etc/janus/janus.plugin.videoroom.jcfg";

/// Starts Janus with assets/janus, each of `replaced` (a config file elsewhere, such as
/// [`STOCK_VIDEOROOM`]) taking the place of the repository's file of the same name.
pub fn start_janus_with(dir: &Path, replaced: &[&Path]) -> Janus {
    start_janus_edited(dir, "http", |name, text| {
        match replaced
            .iter()
            .find(|r| r.file_name() == Some(name.as_ref()))
        {
            Some(other) => std::fs::read_to_string(other).unwrap(),
            None => text,
        }
    })
}

/// Starts Janus with assets/janus, each file's text (by name) passed through `edit` after the
/// port (`PORT` in what `edit` returns is the port too); its API at `scheme://127.0.0.1:PORT/janus`.
pub fn start_janus_edited(
    dir: &Path,
    scheme: &str,
    edit: impl Fn(&str, String) -> String,
) -> Janus {
    let config = dir.join("janus-config");
    std::fs::create_dir_all(&config).unwrap();
    let port = free_tcp_port();
    for entry in std::fs::read_dir(repo_file("assets/janus")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let text = std::fs::read_to_string(&path).unwrap();
        // The one change every test makes to the repository's config: the port.
        let text = text.replace("port = 8088", &format!("port = {port}"));
        let text = edit(&name, text).replace("PORT", &port.to_string());
        std::fs::write(config.join(&name), text).unwrap();
    }
    let log = dir.join("janus.log");
    let mut janus = Janus {
        child: run_janus(&config, &log),
        url: format!("{scheme}://127.0.0.1:{port}/janus"),
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

    /// Freezes the server (SIGSTOP): its sockets stay open and nothing answers, as a server
    /// that hangs does.
    pub fn freeze(&self) {
        let status = Command::new("kill")
            .args(["-STOP", &self.child.id().to_string()])
            .status()
            .expect("kill runs");
        assert!(status.success(), "kill -STOP janus: {status}");
    }

    /// A fresh Janus on the same port and config, knowing nothing of the old sessions.
    pub fn restart(&mut self) {
        self.stop();
        self.child = run_janus(&self.config, &self.log);
        self.wait_ready();
    }
}

/// The level (dB) of each 20 ms of a WAV, whatever its rate.
pub fn envelope(path: &Path) -> Vec<f64> {
    let (rate, samples) = super::read_wav_i16(path);
    let frame = (rate / 50) as usize;
    samples
        .chunks_exact(frame)
        .map(|c| {
            let power = c.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>() / frame as f64;
            10.0 * (power + 1.0).log10()
        })
        .collect()
}

/// The best correlation of two level contours within +-1 s of lag.
pub fn envelope_correlation(a: &[f64], b: &[f64]) -> f64 {
    (-50isize..=50)
        .filter_map(|lag| {
            let pairs: Vec<(f64, f64)> = (0..a.len())
                .filter_map(|i| {
                    let j = i as isize + lag;
                    (j >= 0 && (j as usize) < b.len()).then(|| (a[i], b[j as usize]))
                })
                .collect();
            (pairs.len() > 100).then(|| pearson(&pairs))
        })
        .fold(f64::MIN, f64::max)
}

fn pearson(pairs: &[(f64, f64)]) -> f64 {
    let n = pairs.len() as f64;
    let (ma, mb) = pairs
        .iter()
        .fold((0.0, 0.0), |(x, y), (a, b)| (x + a / n, y + b / n));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (a, b) in pairs {
        sab += (a - ma) * (b - mb);
        saa += (a - ma).powi(2);
        sbb += (b - mb).powi(2);
    }
    sab / (saa * sbb).sqrt().max(1e-12)
}

/// The scripted Janus (tests/data/scripted_janus.py) in one of its modes, killed when dropped.
pub struct Scripted {
    child: Child,
    pub url: String,
}

impl Drop for Scripted {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The scripted Janus in `mode` on 127.0.0.1, once it listens; none (said) without python3.
pub fn scripted(mode: &str) -> Option<Scripted> {
    let child = Command::new("python3")
        .arg(repo_file("tests/data/scripted_janus.py"))
        .arg(mode)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn();
    let Ok(mut child) = child else {
        super::unavailable("no python3 for the scripted Janus");
        return None;
    };
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap()
        .to_string();
    Some(Scripted {
        child,
        url: format!("http://127.0.0.1:{port}/janus"),
    })
}

//! A browser in a lipcall room on Janus: headless Chromium (Debian's `chromium`, its fake
//! microphone playing the demo speech) opens the room page (assets/web, served by
//! tools/room_page.py with Debian's janus.js), creates the room with a pin and publishes;
//! `lipcall receive --janus` hears and animates it, and the page hears `lipcall send --janus`.
//!
//! ICE: Janus's libnice gathers no loopback candidates (not even with `ice_enforce_list =
//! "lo"`), so the test runs in a network namespace of its own (tests/common/netns.rs), where
//! Chromium, Janus and lipcall meet on the namespace's one interface address; signalling and
//! the page are on 127.0.0.1 there.

mod common;

use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::janus::{receive_in_room, start_janus};
use common::net::{finish, spawn};
use common::{lipcall, read_wav_i16, repo_file};

/// What the room page logs to the console (chromium's stderr): `lipcall-room: ...`.
const PAGE_LOG: &str = "lipcall-room: ";

/// A child process (and whatever it starts: it leads its own process group) whose stderr
/// lines are read as they come, killed when dropped.
struct Process {
    child: Child,
    what: &'static str,
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
}

impl Process {
    fn start(cmd: &mut Command, what: &'static str) -> Self {
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .process_group(0)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
        let stderr = child.stderr.take().expect("stderr");
        let (tx, lines) = mpsc::channel();
        // Read to the end, so that a chatty child never blocks on a full pipe.
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            child,
            what,
            lines,
            seen: Vec::new(),
        }
    }

    /// The first line from now on that `pick` accepts, mapped by it; fails after `limit`.
    fn wait_for<T>(&mut self, limit: Duration, pick: impl Fn(&str) -> Option<T>) -> T {
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    let picked = pick(&line);
                    self.seen.push(line);
                    if let Some(picked) = picked {
                        return picked;
                    }
                }
                Err(_) => panic!(
                    "{} did not say what was awaited within {limit:?}; it said:\n{}",
                    self.what,
                    self.said()
                ),
            }
        }
    }

    /// What it said so far, the room page's lines only when there are any.
    fn said(&self) -> String {
        let page: Vec<&str> = self.seen.iter().filter_map(|l| page_line(l)).collect();
        if page.is_empty() {
            self.seen.join("\n")
        } else {
            page.join("\n")
        }
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        // The whole group: Chromium's renderer, GPU and zygote processes too.
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.child.id())])
            .stderr(Stdio::null())
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The page's message in one of chromium's console lines
/// (`[...:INFO:CONSOLE:37] "lipcall-room: MESSAGE", source: http://... (37)`).
fn page_line(line: &str) -> Option<&str> {
    let start = line.find(PAGE_LOG)? + PAGE_LOG.len();
    let rest = &line[start..];
    Some(rest.rsplit_once("\", source: ").map_or(rest, |(m, _)| m))
}

fn chromium_installed() -> bool {
    Command::new("chromium")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// tools/room_page.py on a free loopback port: the page and Debian's JavaScript.
fn serve_room_page() -> (Process, u16) {
    let mut server = Process::start(
        Command::new("python3")
            .arg(repo_file("tools/room_page.py"))
            .args(["--bind", "127.0.0.1", "--port", "0"]),
        "tools/room_page.py",
    );
    let port = server.wait_for(Duration::from_secs(20), |line| {
        line.strip_prefix("lipcall: listening on 127.0.0.1:")
            .map(|p| p.trim().parse::<u16>().expect("a port"))
    });
    (server, port)
}

fn open_in_chromium(url: &str, microphone: &Path, profile: &Path) -> Process {
    Process::start(
        Command::new("chromium")
            .args([
                "--headless=new",
                "--no-sandbox",
                "--no-first-run",
                "--use-fake-ui-for-media-stream",
                "--use-fake-device-for-media-stream",
                "--autoplay-policy=no-user-gesture-required",
                "--enable-logging=stderr",
                "--v=0",
            ])
            .arg(format!(
                "--use-file-for-fake-audio-capture={}",
                microphone.display()
            ))
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(url),
        "chromium",
    )
}

/// `key=value` out of a line of `key=value` words.
fn field(line: &str, key: &str) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(key)?.strip_prefix('='))
        .and_then(|v| v.parse().ok())
}

/// Level of each 20 ms frame (8 kHz), dB relative to full scale.
fn frame_levels_db(samples: &[i16]) -> Vec<f64> {
    samples
        .chunks_exact(160)
        .map(|f| {
            let power = f.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / 160.0;
            10.0 * (power / 32768f64.powi(2)).max(1e-12).log10()
        })
        .collect()
}

#[test]
fn a_browser_and_lipcall_hear_each_other_in_a_janus_room() {
    if !common::janus::runs_here("a_browser_and_lipcall_hear_each_other_in_a_janus_room") {
        return;
    }
    if !chromium_installed() {
        common::unavailable("no `chromium` binary (Debian package chromium)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let janus = start_janus(dir.path());
    let (_server, page_port) = serve_room_page();
    let room = "browser-room";
    let pin = "open sesame";
    let speech = repo_file("assets/speech/demo.wav");

    // The browser comes first: the page creates the room, with the pin, as lipcall would.
    let page_url = |pin: &str| {
        format!(
            "http://127.0.0.1:{page_port}/room.html?room={room}&pin={}&name=Browser&janus={}",
            pin.replace(' ', "%20"),
            janus.url
        )
    };
    let mut browser = open_in_chromium(
        &page_url(pin),
        &speech,
        &dir.path().join("chromium-profile"),
    );
    let limit = Duration::from_secs(30);
    browser.wait_for(limit, |l| match page_line(l) {
        Some(m) if m.starts_with("error ") => panic!("the page failed: {m}"),
        Some("publishing") => Some(()),
        _ => None,
    });

    // lipcall hears the browser's microphone and animates it.
    let wav = dir.path().join("heard.wav");
    let weights = dir.path().join("weights.csv");
    let receiver = receive_in_room(&janus, room, pin, "6", &wav, &weights);
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    assert!(
        received.contains("\"Browser\" (") && received.contains("is publishing"),
        "{received}"
    );
    let peer = received
        .lines()
        .find(|l| l.starts_with("peer ") && l.contains("name=\"Browser\""))
        .unwrap_or_else(|| panic!("no peer line for the browser: {received}"));
    let packets = field(peer, "received").unwrap();
    assert!(packets >= 250.0, "{packets} packets in 6 s: {received}");

    let heard = read_wav_i16(&wav).1;
    let mut levels = frame_levels_db(&heard);
    let loud = levels.iter().filter(|&&db| db > -35.0).count() as f64 / levels.len() as f64;
    levels.sort_by(f64::total_cmp);
    let (quiet, high) = (levels[levels.len() / 10], levels[levels.len() * 9 / 10]);
    eprintln!(
        "lipcall heard the browser: {:.2} s, {:.0} % of frames above -35 dBFS, levels \
         {quiet:.1} .. {high:.1} dBFS (10th .. 90th percentile)",
        heard.len() as f64 / 8000.0,
        loud * 100.0
    );
    // Speech: loud for much of the time, and rising and falling (words and pauses).
    assert!(loud >= 0.3, "{:.0} % of frames loud", loud * 100.0);
    assert!(high - quiet >= 20.0, "levels {quiet:.1} .. {high:.1} dBFS");

    let csv = std::fs::read_to_string(&weights).unwrap();
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    let visemes = header.split(',').count() - 2;
    let rows: Vec<Vec<f64>> = lines
        .map(|r| r.split(',').skip(2).map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() >= 250, "{} rows of weights", rows.len());
    // The mouth moves: some viseme's weight varies over the speech.
    let widest = (0..visemes)
        .map(|v| {
            let (lo, hi) = rows
                .iter()
                .fold((f64::MAX, f64::MIN), |(l, h), r| (l.min(r[v]), h.max(r[v])));
            hi - lo
        })
        .fold(0.0, f64::max);
    assert!(widest > 0.2, "weights barely move ({widest:.2}): {header}");

    // The browser hears lipcall: Ann's speech reaches the page's player.
    let sender = spawn(
        lipcall()
            .arg("send")
            .arg(&speech)
            .args(["--janus", &janus.url, "--room", room])
            .env("LIPCALL_KEY", pin)
            .args(["--name", "Ann"]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let sent_packets = sent
        .lines()
        .find_map(|l| l.strip_prefix("lipcall: sent "))
        .and_then(|l| l.split_whitespace().next()?.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("no count of packets sent: {sent}"));
    // The page reports each speaker's counts once a second, and once more as it leaves.
    let mut last = None;
    while let Some(report) = browser.wait_for(limit, |l| match page_line(l) {
        Some(m) if m.contains("\"Ann\" packets=") => Some(Some(m.to_string())),
        Some(m) if m.contains("\"Ann\" left") => Some(None),
        _ => None,
    }) {
        last = Some(report);
    }
    let last = last.unwrap_or_else(|| panic!("the page never heard Ann:\n{}", browser.said()));
    let (packets, energy) = (
        field(&last, "packets").unwrap(),
        field(&last, "energy").unwrap(),
    );
    eprintln!("the browser heard lipcall: {last} ({sent_packets} sent)");
    // The page subscribes only once Janus says Ann publishes, and the subscription's offer,
    // answer, ICE and DTLS take up to 1.5 s on a loaded machine (0.9 s seen in CI): Ann's
    // first packets are sent before anyone listens. Every packet after that must arrive.
    let before_listening = 1.5 / 0.020;
    assert!(
        packets >= sent_packets - before_listening,
        "{packets} of {sent_packets} packets: {last}"
    );
    assert!(
        field(&last, "lost").unwrap() <= packets * 0.01,
        "{packets} packets: {last}"
    );
    // totalAudioEnergy: the sum of level^2 x seconds of what was played; speech, not silence.
    assert!(energy > 0.1, "{last}");
    drop(browser);

    // A wrong pin: the page says Janus's reason.
    let mut intruder = open_in_chromium(
        &page_url("wrong"),
        &speech,
        &dir.path().join("chromium-wrong-pin"),
    );
    let error = intruder.wait_for(limit, |l| {
        page_line(l)
            .and_then(|m| m.strip_prefix("error "))
            .map(str::to_string)
    });
    assert!(error.contains("433") && error.contains("pin"), "{error}");
}

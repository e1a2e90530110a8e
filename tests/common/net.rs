//! Helpers for the transport tests: ports, child processes, reference decodes, alignment.

use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use lipcall::codec::speex::codec::{Decoder, FrameOutcome};
use lipcall::codec::speex::ogg_file;
use lipcall::vocab::FRAME_SIZE;

/// A child process that binds its own port (port 0) and says which, read from its output
/// before anything is sent to it: no port is picked by the test and raced for, and no sleep
/// stands in for "it is listening now".
pub struct Listening {
    child: Child,
    /// The port it bound, on 127.0.0.1.
    pub port: u16,
    /// Every line of the announcing stream (before and after the announcement), until it
    /// closes.
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
    from_stdout: bool,
}

/// Where a child announces its port, and how the announcement reads.
pub enum Announce {
    /// `lipcall receive`: `lipcall: listening on IP:PORT` on stderr (see `receive --help`).
    Lipcall,
    /// `gst-launch-1.0 -v` with a `udpsrc port=0`: `/GstPipeline:...GstUDPSrc:NAME: port = N`
    /// on stdout, notified once the socket is bound (`-q` would hide it).
    GstUdpsrc,
    /// Ready, with no port: the first stderr line starting with this (e.g. `receive --janus`'s
    /// `lipcall: in room `). `Listening::port` is then 0.
    StderrLine(&'static str),
}

impl Announce {
    fn port(&self, line: &str) -> Option<u16> {
        match self {
            Announce::Lipcall => line
                .strip_prefix("lipcall: listening on ")
                .map(|a| a.parse::<SocketAddr>().expect("an address").port()),
            Announce::GstUdpsrc => line
                .contains("GstUDPSrc:")
                .then(|| line.rsplit_once(": port = "))
                .flatten()
                .map(|(_, p)| p.trim().parse().expect("a port")),
            Announce::StderrLine(prefix) => line.starts_with(prefix).then_some(0),
        }
    }
}

/// `lipcall receive` on a loopback port of its own choosing, with `args`; its address read back
/// from what it prints.
pub fn start_receiver(args: &[&str]) -> Listening {
    spawn_listening(
        super::lipcall()
            .args(["receive", "--listen", "127.0.0.1:0"])
            .args(args),
        Announce::Lipcall,
    )
}

/// Starts `cmd` and waits (up to 20 s) until it says which port it bound (or that it is
/// ready, for [`Announce::StderrLine`]).
pub fn spawn_listening(cmd: &mut Command, announce: Announce) -> Listening {
    let mut child = spawn(cmd);
    let from_stdout = matches!(announce, Announce::GstUdpsrc);
    let (tx, lines) = mpsc::channel();
    let stream: Box<dyn Read + Send> = if from_stdout {
        Box::new(child.stdout.take().expect("stdout"))
    } else {
        Box::new(child.stderr.take().expect("stderr"))
    };
    std::thread::spawn(move || {
        for line in BufReader::new(stream).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut seen = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match lines.recv_timeout(left) {
            Ok(line) => {
                let port = announce.port(&line);
                seen.push(line);
                if let Some(port) = port {
                    return Listening {
                        child,
                        port,
                        lines,
                        seen,
                        from_stdout,
                    };
                }
            }
            Err(_) => {
                let _ = child.kill();
                let out = child.wait_with_output().expect("output");
                panic!(
                    "{cmd:?} did not say which port it bound:\n{}\n{}{}",
                    seen.join("\n"),
                    String::from_utf8_lossy(&out.stdout),
                    String::from_utf8_lossy(&out.stderr)
                );
            }
        }
    }
}

impl Listening {
    /// `127.0.0.1:PORT`.
    pub fn addr(&self) -> String {
        format!("127.0.0.1:{}", self.port)
    }

    pub fn socket_addr(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Sends SIGINT (see [`interrupt`]).
    pub fn interrupt(&self) {
        interrupt(&self.child);
    }

    /// Sends the signal `name` (`INT`, `TERM`, ...) with kill(1).
    pub fn signal(&self, name: &str) {
        let status = Command::new("kill")
            .args([&format!("-{name}"), &self.child.id().to_string()])
            .status()
            .expect("kill");
        assert!(status.success());
    }

    /// [`finish`], with the announcing stream whole: (stdout, stderr).
    pub fn finish(mut self, limit: Duration, what: &str) -> (String, String) {
        let deadline = Instant::now() + limit;
        let overran = loop {
            match self.child.try_wait().expect("wait") {
                Some(_) => break false,
                None if Instant::now() > deadline => {
                    let _ = self.child.kill();
                    break true;
                }
                None => std::thread::sleep(Duration::from_millis(20)),
            }
        };
        let out = self.child.wait_with_output().expect("output");
        let mut lines = self.seen;
        // The reader ends when the stream closes, which the child's exit did.
        lines.extend(self.lines.iter());
        let mut announced = lines.join("\n");
        announced.push('\n');
        let (stdout, stderr) = if self.from_stdout {
            (announced, String::from_utf8_lossy(&out.stderr).into_owned())
        } else {
            (String::from_utf8_lossy(&out.stdout).into_owned(), announced)
        };
        assert!(
            !overran,
            "{what} did not finish within {limit:?}: {stdout}{stderr}"
        );
        assert!(out.status.success(), "{what} failed: {stdout}{stderr}");
        (stdout, stderr)
    }
}

pub fn spawn(cmd: &mut Command) -> Child {
    cmd.stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e} (install it: see README)"))
}

/// Waits for a child with a deadline; kills it (and fails) if it overruns.
pub fn finish(mut child: Child, limit: Duration, what: &str) -> (String, String) {
    let deadline = Instant::now() + limit;
    loop {
        match child.try_wait().expect("wait") {
            Some(_) => break,
            None if Instant::now() > deadline => {
                let _ = child.kill();
                let out = child.wait_with_output().expect("output");
                panic!(
                    "{what} did not finish within {limit:?}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
            }
            None => std::thread::sleep(Duration::from_millis(20)),
        }
    }
    let out = child.wait_with_output().expect("output");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{what} failed: {stderr}");
    (String::from_utf8_lossy(&out.stdout).into_owned(), stderr)
}

/// Sends SIGINT (gst-launch -e then finishes its files cleanly).
pub fn interrupt(child: &Child) {
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
}

/// Audio packets of an Ogg Speex file.
pub fn ogg_packets(path: &Path) -> Vec<Vec<u8>> {
    let bytes = std::fs::read(path).expect("read spx");
    let file = ogg_file::read(&bytes).expect("parse spx");
    file.pages.into_iter().flat_map(|p| p.packets).collect()
}

/// Every frame of every packet decoded in order, untrimmed, as real-time playback hears it.
pub fn decode_frames(packets: &[Vec<u8>]) -> Vec<i16> {
    let mut decoder = Decoder::new(true).expect("decoder");
    let mut out = Vec::new();
    let mut pcm = [0i16; FRAME_SIZE];
    for p in packets {
        decoder.load(p).expect("load");
        while let Ok(FrameOutcome::Decoded) = decoder.decode_next(&mut pcm) {
            out.extend_from_slice(&pcm);
        }
    }
    out
}

fn energy(x: &[i16]) -> f64 {
    x.iter().map(|&s| f64::from(s).powi(2)).sum()
}

fn snr(reference: &[i16], test: &[i16]) -> f64 {
    let noise: f64 = reference
        .iter()
        .zip(test)
        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
        .sum();
    10.0 * (energy(reference) / noise.max(1e-9)).log10()
}

/// How well `test` reproduces `reference` played out with an unknown start offset and a few
/// whole frames inserted or skipped by a jitter buffer.
#[derive(Debug, Clone)]
pub struct Alignment {
    /// `test[i]` lines up with `reference[i - offset]` at the start.
    pub offset: i64,
    /// SNR of each 200 ms chunk of `test` that carries speech, at its best frame shift.
    pub chunk_snr: Vec<f64>,
    /// Reference and error energy of those chunks, at their best shifts.
    pub energy: (f64, f64),
}

impl Alignment {
    pub fn median(&self) -> f64 {
        let mut v = self.chunk_snr.clone();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NEG_INFINITY)
    }

    /// The SNR of all the chunks together (each at its best frame shift).
    pub fn overall(&self) -> f64 {
        10.0 * (self.energy.0 / self.energy.1.max(1e-9)).log10()
    }

    pub fn share_above(&self, db: f64) -> f64 {
        self.chunk_snr.iter().filter(|&&s| s > db).count() as f64
            / self.chunk_snr.len().max(1) as f64
    }
}

pub fn align(reference: &[i16], test: &[i16], max_offset: usize) -> Alignment {
    align_frames(reference, test, max_offset, FRAME_SIZE)
}

/// [`align`] of streams whose 20 ms frames hold `frame` samples (960 at 48 kHz): chunks of
/// 200 ms, each at its best shift of up to 4 whole frames.
pub fn align_frames(reference: &[i16], test: &[i16], max_offset: usize, frame: usize) -> Alignment {
    let window = 4000
        .min(reference.len())
        .min(test.len().saturating_sub(max_offset));
    let start = reference
        .chunks(frame)
        .position(|c| energy(c) > 1e6 * c.len() as f64)
        .unwrap_or(0)
        * frame;
    let reference_part = &reference[start..(start + window).min(reference.len())];
    let mut best = (f64::NEG_INFINITY, 0i64);
    for lag in 0..=max_offset as i64 {
        let from = start as i64 + lag;
        let Some(t) = test.get(from as usize..from as usize + reference_part.len()) else {
            continue;
        };
        let s = snr(reference_part, t);
        if s > best.0 {
            best = (s, lag);
        }
    }
    let offset = best.1;
    let chunk = 10 * frame;
    let mut chunk_snr = Vec::new();
    let mut energies = (0.0, 0.0);
    for (i, t) in test.chunks_exact(chunk).enumerate() {
        // Only where the reference runs (not the concealed tail after the stream), and not
        // before it starts.
        let end = ((i + 1) * chunk) as i64 - offset;
        if energy(t) < 1e6 * chunk as f64
            || end + 4 * frame as i64 > reference.len() as i64
            || end < chunk as i64
        {
            continue;
        }
        let mut best_chunk = (f64::NEG_INFINITY, (0.0, 0.0));
        for shift in -4i64..=4 {
            let r0 = (i * chunk) as i64 - offset + shift * frame as i64;
            if r0 < 0 {
                continue;
            }
            let Some(r) = reference.get(r0 as usize..r0 as usize + chunk) else {
                continue;
            };
            let s = snr(r, t);
            if s > best_chunk.0 {
                let noise: f64 = r
                    .iter()
                    .zip(t)
                    .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                    .sum();
                best_chunk = (s, (energy(r), noise));
            }
        }
        chunk_snr.push(best_chunk.0);
        energies.0 += (best_chunk.1).0;
        energies.1 += (best_chunk.1).1;
    }
    Alignment {
        offset,
        chunk_snr,
        energy: energies,
    }
}

/// SNR of `test` against `reference` at the lag (`test` later by 0..=`max_lag` samples) that
/// fits the first second best, over all of `reference` that `test` covers; with that lag.
pub fn snr_at_best_lag(reference: &[i16], test: &[i16], max_lag: usize) -> (f64, usize) {
    let probe = &reference[..reference.len().min(8000)];
    let lag = (0..=max_lag)
        .filter(|&lag| test.len() >= lag + probe.len())
        .max_by(|&a, &b| {
            snr(probe, &test[a..a + probe.len()]).total_cmp(&snr(probe, &test[b..b + probe.len()]))
        })
        .unwrap_or(0);
    let covered = test.len().saturating_sub(lag).min(reference.len());
    (snr(&reference[..covered], &test[lag..lag + covered]), lag)
}

/// `key=value` fields of the first stderr line starting with `prefix`.
pub fn fields(stderr: &str, prefix: &str) -> std::collections::HashMap<String, String> {
    stderr
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no line starting {prefix:?} in:\n{stderr}"))
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.trim_matches('"').to_string()))
        .collect()
}

pub fn num(fields: &std::collections::HashMap<String, String>, key: &str) -> f64 {
    fields
        .get(key)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no numeric {key} in {fields:?}"))
}

/// Sends `frames` 20 ms Speex frames of a steady tone from `session`, each at its time.
pub fn talk(session: &lipcall::net::session::Session, frames: u32) {
    use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
    let mut encoder = FrameEncoder::new(Codec::Speex, &EncoderSettings::default()).unwrap();
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let start = Instant::now();
    for k in 0..frames {
        let due = start + Duration::from_millis(20) * k;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let frame: [i16; FRAME_SIZE] =
            std::array::from_fn(|i| ((i as f32 * 0.3).sin() * 8000.0) as i16);
        let (n, ticks) = encoder.encode(&frame, &mut payload).unwrap().unwrap();
        session.send_packet(&payload[..n], ticks).unwrap();
    }
}

/// Sends PCMU packets (payload type 0, any bytes decode) from new SSRCs to `to` at 2,000 a
/// second until `stop`.
pub fn new_ssrc_flood(to: std::net::SocketAddr, stop: &std::sync::atomic::AtomicBool) -> u64 {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut stream = lipcall::net::rtp::RtpStream::new(0, 0, 0);
    stream.set_payload(0, 160);
    let start = Instant::now();
    let mut sent = 0u64;
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        let due = start + Duration::from_micros(500 * sent);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        stream.ssrc = 0x4000_0000 + sent as u32;
        let mut buf = Vec::new();
        stream.packetize(&[0x55; 160], 1, &mut buf).unwrap();
        let _ = socket.send_to(&buf, to);
        sent += 1;
    }
    sent
}

//! SIP test peers (SIPp, kamailio, baresip) started on free loopback ports with configs in a
//! temp dir, killed when dropped; and how to tell that a recording holds the speech sent.

use std::io::Read;
use std::net::UdpSocket;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A free UDP port on 127.0.0.1 (and, with `pair`, the one two above it free too, as SIPp's
/// media needs).
pub fn free_port(pair: bool) -> u16 {
    loop {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        let port = s.local_addr().unwrap().port();
        if !pair {
            return port;
        }
        if port < 65000 && UdpSocket::bind(("127.0.0.1", port + 2)).is_ok() {
            return port;
        }
    }
}

pub fn installed(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A peer process, killed (and reaped) when dropped.
pub struct Peer {
    pub child: Option<Child>,
    pub name: &'static str,
}

impl Peer {
    pub fn spawn(name: &'static str, cmd: &mut Command) -> Self {
        let child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Self {
            child: Some(child),
            name,
        }
    }

    /// Starts a peer whose output is read as it comes ([`Logged::text`]).
    pub fn spawn_logged(name: &'static str, cmd: &mut Command) -> Logged {
        let mut peer = Self::spawn(name, cmd);
        let text = Arc::new(Mutex::new(String::new()));
        let child = peer.child.as_mut().expect("running");
        let streams: Vec<Box<dyn Read + Send>> = vec![
            Box::new(child.stdout.take().expect("piped")),
            Box::new(child.stderr.take().expect("piped")),
        ];
        for mut stream in streams {
            let text = Arc::clone(&text);
            std::thread::spawn(move || {
                let mut buf = [0u8; 4096];
                while let Ok(n) = stream.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    text.lock()
                        .unwrap()
                        .push_str(&String::from_utf8_lossy(&buf[..n]));
                }
            });
        }
        Logged { peer, text }
    }

    /// Waits up to `limit` for the peer to exit by itself; its output, or `None` if it did not
    /// (then it is killed).
    pub fn finish(mut self, limit: Duration) -> Option<Output> {
        let mut child = self.child.take()?;
        let deadline = Instant::now() + limit;
        loop {
            match child.try_wait() {
                Ok(Some(_)) => return child.wait_with_output().ok(),
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(50))
                }
                _ => {
                    let _ = child.kill();
                    let out = child.wait_with_output().ok();
                    if let Some(out) = &out {
                        eprintln!(
                            "{} did not exit; its output:\n{}\n{}",
                            self.name,
                            String::from_utf8_lossy(&out.stdout),
                            String::from_utf8_lossy(&out.stderr)
                        );
                    }
                    return None;
                }
            }
        }
    }

    /// Kills it and returns what it printed.
    pub fn stop(mut self) -> Output {
        let mut child = self.child.take().expect("running");
        let _ = child.kill();
        child.wait_with_output().expect("reaped")
    }
}

/// A peer whose output is collected while it runs.
pub struct Logged {
    pub peer: Peer,
    text: Arc<Mutex<String>>,
}

impl Logged {
    pub fn text(&self) -> String {
        self.text.lock().unwrap().clone()
    }

    /// Waits up to `limit` for `needle` in the output.
    pub fn wait_for(&self, needle: &str, limit: Duration) -> bool {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            if self.text().contains(needle) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        false
    }

    /// Ends it with SIGTERM (a server's own clean shutdown, its workers included).
    pub fn terminate(&mut self) {
        if let Some(child) = &mut self.peer.child {
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status();
            let deadline = Instant::now() + Duration::from_secs(5);
            while Instant::now() < deadline {
                if let Ok(Some(_)) = child.try_wait() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    }
}

impl Drop for Logged {
    fn drop(&mut self) {
        self.terminate();
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if let Some(child) = &mut self.child {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// SIPp as a UAS on `port` (media on `media_port`, echoed back) running `scenario` (an XML
/// file, or SIPp's built-in `uas`) for one call.
pub fn sipp_uas(dir: &Path, port: u16, media_port: u16, scenario: Option<&str>) -> Peer {
    let mut cmd = Command::new("sipp");
    match scenario {
        Some(xml) => {
            let path = dir.join(format!("scenario-{port}.xml"));
            std::fs::write(&path, xml).unwrap();
            cmd.arg("-sf").arg(path);
        }
        None => {
            cmd.args(["-sn", "uas"]);
        }
    }
    cmd.args(["-i", "127.0.0.1", "-p", &port.to_string()])
        .args([
            "-mp",
            &media_port.to_string(),
            "-rtp_echo",
            "-m",
            "1",
            "-nostdin",
        ])
        .args(["-timeout", "60s", "-timeout_error"])
        .current_dir(dir);
    let peer = Peer::spawn("sipp", &mut cmd);
    // SIPp binds its sockets within a few ms of starting.
    std::thread::sleep(Duration::from_millis(300));
    peer
}

/// The start of a 200 OK answering SIPp's last request (its headers copied), for scenarios.
pub const SIPP_OK_HEAD: &str = "SIP/2.0 200 OK\n[last_Via:]\n[last_From:]\n[last_To:];tag=[pid]SIPpTag01[call_number]\n[last_Call-ID:]\n[last_CSeq:]\nContact: <sip:[local_ip]:[local_port];transport=[transport]>\n";

/// A SIPp UAS that answers with `sdp_media` (the lines from `m=` on), then waits for BYE.
pub fn answering_scenario(sdp_media: &str) -> String {
    format!(
        r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="answer">
  <recv request="INVITE" crlf="true"/>
  <send><![CDATA[
{SIPP_OK_HEAD}Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 1 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
{sdp_media}
]]></send>
  <recv request="ACK" crlf="true"/>
  <recv request="BYE"/>
  <send><![CDATA[
SIP/2.0 200 OK
[last_Via:]
[last_From:]
[last_To:]
[last_Call-ID:]
[last_CSeq:]
Content-Length: 0

]]></send>
</scenario>
"#
    )
}

/// The lag (in samples, `test` behind `reference`, within +-`max_lag`) at which the two agree
/// best over `window` samples of `reference` from `from`, and their normalised correlation
/// there.
pub fn best_alignment(
    reference: &[i16],
    test: &[i16],
    from: usize,
    window: usize,
    max_lag: usize,
) -> (isize, f64) {
    let reference = &reference[from.min(reference.len())..];
    let n = window.min(reference.len());
    let mut best = (0isize, f64::MIN);
    for lag in -(max_lag as isize)..=(max_lag as isize) {
        let (mut dot, mut ea, mut eb) = (0f64, 0f64, 0f64);
        for (i, &a) in reference[..n].iter().enumerate() {
            let j = from as isize + i as isize + lag;
            let Some(&b) = usize::try_from(j).ok().and_then(|j| test.get(j)) else {
                continue;
            };
            let (a, b) = (f64::from(a), f64::from(b));
            dot += a * b;
            ea += a * a;
            eb += b * b;
        }
        let corr = dot / (ea.sqrt() * eb.sqrt()).max(1e-9);
        if corr > best.1 {
            best = (lag, corr);
        }
    }
    best
}

/// `samples` through G.711 mu-law and back: what the best possible G.711 call delivers.
pub fn mulaw_round_trip(samples: &[i16]) -> Vec<i16> {
    samples
        .iter()
        .map(|&s| {
            // The G.711 mu-law segment coder, as sox and every phone does it.
            let sign = s < 0;
            let magnitude = (i32::from(s).abs().min(32635) + 0x84) as u32;
            let exponent = 31 - magnitude.leading_zeros() - 7;
            let mantissa = (magnitude >> (exponent + 3)) & 0x0f;
            let decoded = (((mantissa << 3) + 0x84) << exponent) as i32 - 0x84;
            let decoded = decoded as i16;
            if sign { -decoded } else { decoded }
        })
        .collect()
}

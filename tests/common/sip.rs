//! SIP test peers (SIPp, kamailio, baresip) started on free loopback ports with configs in a
//! temp dir, killed when dropped; and how to tell that a recording holds the speech sent.

use std::collections::HashSet;
use std::io::{Read, Write};
use std::net::{SocketAddr, SocketAddrV4, TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
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

/// The median, over quarter seconds of speech from 1 s to 4 s, of the SNR of `heard` against
/// `sent` at the lag where each quarter agrees best (the jitter buffer may drop or stretch a
/// frame now and then, which moves the lag), beside the same for a perfect G.711 round trip.
pub fn median_snr(sent: &[i16], heard: &[i16]) -> (f64, f64) {
    const QUARTER: usize = 2000;
    let round_trip = mulaw_round_trip(sent);
    let mut ours = Vec::new();
    let mut g711 = Vec::new();
    for from in (8000..32000).step_by(QUARTER) {
        let piece = &sent[from..from + QUARTER];
        let power = piece.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / QUARTER as f64;
        if power < 1e4 {
            // Silence: nothing to compare.
            continue;
        }
        let (lag, _) = best_alignment(sent, heard, from, QUARTER, 1600);
        let start = usize::try_from(from as isize + lag).unwrap_or(0);
        ours.push(super::snr_db(piece, &heard[start.min(heard.len())..]));
        g711.push(super::snr_db(piece, &round_trip[from..]));
    }
    assert!(
        ours.len() >= 6,
        "too little speech to compare: {}",
        ours.len()
    );
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    (median(&mut ours), median(&mut g711))
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

pub const PASSWORD: &str = "lipcall-test-secret";

pub fn have(tools: &[&str]) -> bool {
    for tool in tools {
        if !installed(tool) {
            super::unavailable(&format!("{tool} is not installed"));
            return false;
        }
    }
    true
}

/// kamailio as registrar and proxy on `port`: REGISTER must answer a digest challenge for
/// [`PASSWORD`]; everything else is routed by the location table (kept in memory). `extra`:
/// more `modparam` lines; `route`: script run on a new request before it is routed.
pub fn kamailio_with(dir: &Path, port: u16, extra: &str, route: &str) -> Logged {
    let modules = [
        "tm",
        "sl",
        "pv",
        "maxfwd",
        "usrloc",
        "registrar",
        "textops",
        "siputils",
        "auth",
    ];
    let loads: String = modules
        .iter()
        .map(|m| format!("loadmodule \"{m}.so\"\n"))
        .collect();
    let modules = kamailio_modules();
    let config = format!(
        r#"#!KAMAILIO
debug=2
log_stderror=yes
children=2
disable_tcp=yes
auto_aliases=no
listen=udp:127.0.0.1:{port}
alias="127.0.0.1:{port}"
mpath="{modules}"
{loads}modparam("usrloc", "db_mode", 0)
{extra}

request_route {{
    if (!mf_process_maxfwd_header("10")) {{
        sl_send_reply("483", "Too Many Hops");
        exit;
    }}
    if (is_method("CANCEL")) {{
        if (t_check_trans()) {{
            t_relay();
        }}
        exit;
    }}
    if (has_totag()) {{
        if (is_method("ACK") && !t_check_trans()) {{
            exit;
        }}
        t_relay();
        exit;
    }}
    if (is_method("REGISTER")) {{
        if (!pv_www_authenticate("$td", "{PASSWORD}", "0")) {{
            www_challenge("$td", "0");
            exit;
        }}
        save("location");
        exit;
    }}
    {route}
    if (!lookup("location")) {{
        sl_send_reply("404", "Not Found");
        exit;
    }}
    t_relay();
}}
"#
    );
    let path = dir.join("kamailio.cfg");
    std::fs::write(&path, config).unwrap();
    let kamailio = Peer::spawn_logged(
        "kamailio",
        Command::new("kamailio")
            .arg("-f")
            .arg(&path)
            .args(["-DD", "-E", "-m", "32", "-M", "8", "-Y"])
            .arg(dir),
    );
    assert!(
        kamailio.wait_for("SO_RCVBUF is finally", Duration::from_secs(10)),
        "kamailio did not start: {}",
        kamailio.text()
    );
    kamailio
}

/// Debian installs kamailio's modules under the architecture's library folder.
pub fn kamailio_modules() -> String {
    let lib = Path::new("/usr/lib");
    std::fs::read_dir(lib)
        .into_iter()
        .flatten()
        .filter_map(Result::ok)
        .map(|e| e.path().join("kamailio/modules"))
        .chain([lib.join("kamailio/modules")])
        .find(|p| p.join("tm.so").exists())
        .map(|p| format!("{}/", p.display()))
        .expect("kamailio's modules (tm.so) under /usr/lib")
}

pub fn kamailio(dir: &Path, port: u16, extra: &str) -> Logged {
    kamailio_with(dir, port, extra, "")
}

/// baresip as bob at the kamailio on `kam_port` (digest for [`PASSWORD`]), answering by
/// `answermode` (`auto` or `manual`) in PCMU, its microphone `source`: returned once
/// registered.
pub fn bob_registered(dir: &Path, kam_port: u16, answermode: &str, source: &Path) -> Logged {
    let (port, control) = (free_port(false), free_port(false));
    let bob = baresip(
        dir,
        port,
        control,
        &format!(
            "<sip:bob@127.0.0.1:{kam_port}>;auth_pass={PASSWORD};answermode={answermode};regint=60;audio_codecs=PCMU"
        ),
        source,
    );
    assert!(
        bob.wait_for("200 OK", Duration::from_secs(10)),
        "baresip did not register: {}",
        bob.text()
    );
    bob
}

/// baresip with its own config folder: `account` its accounts line, its microphone `source`
/// (8 kHz mono), what it hears dumped into `dir`/heard by sndfile.
pub fn baresip(dir: &Path, port: u16, control: u16, account: &str, source: &Path) -> Logged {
    baresip_with(dir, port, control, account, source, "")
}

/// [`baresip`] with `extra` lines of config (more modules).
pub fn baresip_with(
    dir: &Path,
    port: u16,
    control: u16,
    account: &str,
    source: &Path,
    extra: &str,
) -> Logged {
    let home = dir.join("baresip");
    let heard = dir.join("heard");
    std::fs::create_dir_all(&home).unwrap();
    std::fs::create_dir_all(&heard).unwrap();
    let config = format!(
        "poll_method epoll\nsip_listen 127.0.0.1:{port}\nsip_trans_def udp\n\
         audio_player alsa,null\naudio_alert alsa,null\naudio_source aufile,{}\n\
         module_path /usr/lib/baresip/modules\nmodule g711.so\nmodule g722.so\nmodule aufile.so\n\
         module alsa.so\nmodule sndfile.so\nmodule srtp.so\nmodule_app account.so\nmodule_app menu.so\n\
         module_app ctrl_tcp.so\nctrl_tcp_listen 127.0.0.1:{control}\nsnd_path {}\n{extra}",
        source.display(),
        heard.display()
    );
    std::fs::write(home.join("config"), config).unwrap();
    std::fs::write(home.join("accounts"), format!("{account}\n")).unwrap();
    let baresip = Peer::spawn_logged("baresip", Command::new("baresip").arg("-f").arg(&home));
    assert!(
        baresip.wait_for("baresip is ready", Duration::from_secs(10)),
        "baresip did not start: {}",
        baresip.text()
    );
    baresip
}

/// A command to baresip's ctrl_tcp (a netstring of JSON).
pub fn tell_baresip(control: u16, command: &str, params: &str) {
    let json = format!(r#"{{"command":"{command}","params":"{params}","token":"t"}}"#);
    let mut stream = TcpStream::connect(("127.0.0.1", control)).unwrap();
    stream
        .write_all(format!("{}:{json},", json.len()).as_bytes())
        .unwrap();
}

/// The WAV sndfile wrote for the audio baresip decoded.
pub fn baresip_heard(dir: &Path) -> PathBuf {
    std::fs::read_dir(dir.join("heard"))
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.path())
        .find(|p| p.to_string_lossy().ends_with("-dec.wav"))
        .expect("baresip dumped what it heard")
}

/// The demo speech reversed, at 8 kHz: a second voice, told apart from the first.
pub fn reversed_8k(dir: &Path) -> PathBuf {
    let out = dir.join("reversed8k.wav");
    super::run(
        Command::new("sox")
            .arg(super::demo_8k(dir))
            .arg(&out)
            .arg("reverse"),
    );
    out
}

/// `lipcall sip answer` on 127.0.0.1:`port`, playing the demo speech for up to `seconds` and
/// writing what it hears to `wav`; returned once its SIP socket is open.
pub fn lipcall_answering(dir: &Path, port: u16, seconds: &str, wav: &Path) -> Logged {
    lipcall_answering_with(dir, port, seconds, wav, &[])
}

/// [`lipcall_answering`] with `extra` flags.
pub fn lipcall_answering_with(
    dir: &Path,
    port: u16,
    seconds: &str,
    wav: &Path,
    extra: &[&str],
) -> Logged {
    let answer = Peer::spawn_logged(
        "lipcall sip answer",
        super::lipcall()
            .args(["sip", "answer", "--listen", &format!("127.0.0.1:{port}")])
            .arg("--play")
            .arg(super::demo_8k(dir))
            .args(["--seconds", seconds])
            .arg("--wav")
            .arg(wav)
            .args(extra),
    );
    assert!(
        answer.wait_for("SIP on", Duration::from_secs(10)),
        "{}",
        answer.text()
    );
    answer
}

/// Waits up to `limit` for `lipcall` to exit; its status and log.
pub fn exit_of(mut lipcall: Logged, limit: Duration) -> (Option<i32>, String) {
    let mut child = lipcall.peer.child.take().unwrap();
    let deadline = Instant::now() + limit;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            std::thread::sleep(Duration::from_millis(200));
            return (status.code(), lipcall.text());
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("lipcall did not end: {}", lipcall.text());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A STUN Binding success answering `request` (its cookie and transaction id), giving
/// `mapped` as XOR-MAPPED-ADDRESS; `None` if `request` is no Binding request.
pub fn stun_binding_success(request: &[u8], mapped: SocketAddrV4) -> Option<Vec<u8>> {
    if request.len() < 20 || request[..2] != [0x00, 0x01] {
        return None;
    }
    let mut reply = vec![0x01, 0x01, 0, 12];
    reply.extend_from_slice(&request[4..20]);
    reply.extend([0x00, 0x20, 0, 8, 0, 1]);
    reply.extend((mapped.port() ^ 0x2112).to_be_bytes());
    reply.extend((u32::from(*mapped.ip()) ^ 0x2112_a442).to_be_bytes());
    Some(reply)
}

/// The value of the first header `name` of a SIP message.
pub fn header<'m>(message: &'m str, name: &str) -> Option<&'m str> {
    message.lines().find_map(|line| {
        let (n, value) = line.split_once(':')?;
        n.trim().eq_ignore_ascii_case(name).then(|| value.trim())
    })
}

/// The status code of a response (`None` for a request).
pub fn status(message: &str) -> Option<u16> {
    message.strip_prefix("SIP/2.0 ")?.get(..3)?.parse().ok()
}

pub fn receive(socket: &UdpSocket) -> Option<(String, SocketAddr)> {
    let mut buf = [0u8; 65536];
    let (n, from) = socket.recv_from(&mut buf).ok()?;
    Some((String::from_utf8_lossy(&buf[..n]).into_owned(), from))
}

/// Sends `count` requests made by `make` (by number), no more than `window` unanswered at a time
/// so that lipcall's socket buffer does not drop them, within `limit`; the numbers answered with
/// a final response, each counted once, by `number` (the request's number in a response).
pub fn flood(
    socket: &UdpSocket,
    to: SocketAddr,
    count: usize,
    window: usize,
    limit: Duration,
    make: impl Fn(usize) -> String,
    number: impl Fn(&str) -> Option<usize>,
) -> HashSet<usize> {
    socket
        .set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let mut answered = HashSet::new();
    let mut written_off = 0;
    let mut sent = 0;
    let outstanding = |sent: usize, answered: &HashSet<usize>, written_off: usize| {
        sent.saturating_sub(answered.len() + written_off)
    };
    let deadline = Instant::now() + limit;
    while (sent < count || outstanding(sent, &answered, written_off) > 0)
        && Instant::now() < deadline
    {
        while sent < count && outstanding(sent, &answered, written_off) < window {
            socket.send_to(make(sent).as_bytes(), to).unwrap();
            sent += 1;
        }
        match receive(socket) {
            Some((message, _)) => {
                if status(&message).is_some_and(|code| code >= 200)
                    && let Some(n) = number(&message)
                {
                    answered.insert(n);
                }
            }
            // Lost or never to be answered: the window moves on.
            None => written_off = sent.saturating_sub(answered.len()),
        }
    }
    answered
}

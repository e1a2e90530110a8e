//! `lipcall sip answer` against a caller written here on raw UDP sockets (127.0.0.1), and
//! strangers around it: RTP from a second address, before the caller's first packet and after
//! its silence, is neither played nor answered; offers whose media address is no host (the
//! unspecified address, broadcast, multicast, IPv6 on an IPv4 call) get 488 and the address
//! named; a STUN server that says our address is a multicast group is not believed.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use common::sip::{
    exit_of, free_port, lipcall_answering, lipcall_answering_with, stun_binding_success,
};

/// A caller speaking just enough SIP over one UDP socket for one call.
struct Caller {
    sip: UdpSocket,
    lipcall: SocketAddr,
    call_id: String,
    /// The INVITE's transaction, and the headers its ACK and BYE repeat.
    branch: String,
    from: String,
    /// lipcall's To (with its tag) and Contact, from its final answer.
    to: String,
    contact: String,
}

impl Caller {
    fn new(lipcall: SocketAddr) -> Self {
        let sip = UdpSocket::bind("127.0.0.1:0").unwrap();
        let here = sip.local_addr().unwrap();
        let tag = here.port();
        Self {
            sip,
            lipcall,
            call_id: format!("hostile-{tag}@127.0.0.1"),
            branch: format!("z9hG4bK-hostile-{tag}"),
            from: format!("<sip:caller@{here}>;tag=t{tag}"),
            to: format!("<sip:lipcall@{lipcall}>"),
            contact: format!("sip:lipcall@{lipcall}"),
        }
    }

    fn request(&self, method: &str, uri: &str, branch: &str, cseq: u32, sdp: &str) -> String {
        let here = self.sip.local_addr().unwrap();
        let body = if sdp.is_empty() {
            String::new()
        } else {
            "Content-Type: application/sdp\r\n".to_owned()
        };
        format!(
            "{method} {uri} SIP/2.0\r\nVia: SIP/2.0/UDP {here};branch={branch};rport\r\n\
             From: {}\r\nTo: {}\r\nCall-ID: {}\r\nCSeq: {cseq} {method}\r\n\
             Contact: <sip:caller@{here}>\r\nMax-Forwards: 70\r\n{body}Content-Length: {}\r\n\r\n{sdp}",
            self.from,
            self.to,
            self.call_id,
            sdp.len()
        )
    }

    fn send(&self, message: &str) {
        self.sip.send_to(message.as_bytes(), self.lipcall).unwrap();
    }

    /// Sends the INVITE with `sdp` and waits for lipcall's final answer: its status and text.
    fn invite(&mut self, sdp: &str) -> (u16, String) {
        let uri = format!("sip:lipcall@{}", self.lipcall);
        self.send(&self.request("INVITE", &uri, &self.branch, 1, sdp));
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut buf = [0u8; 8192];
        self.sip
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        while Instant::now() < deadline {
            let Ok((n, _)) = self.sip.recv_from(&mut buf) else {
                continue;
            };
            let text = String::from_utf8_lossy(&buf[..n]).into_owned();
            let Some(code) = text
                .strip_prefix("SIP/2.0 ")
                .and_then(|rest| rest.get(..3))
                .and_then(|code| code.parse::<u16>().ok())
            else {
                continue;
            };
            if code < 200 {
                continue;
            }
            if let Some(to) = header(&text, "To") {
                self.to = to;
            }
            if let Some(contact) = header(&text, "Contact") {
                self.contact = contact
                    .trim_start_matches('<')
                    .split('>')
                    .next()
                    .unwrap_or_default()
                    .to_owned();
            }
            // A failure's ACK is the INVITE's transaction; a 2xx's is a new one to the Contact.
            let ack = if code < 300 {
                let branch = format!("{}-ack", self.branch);
                self.request("ACK", &self.contact, &branch, 1, "")
            } else {
                let uri = format!("sip:lipcall@{}", self.lipcall);
                self.request("ACK", &uri, &self.branch, 1, "")
            };
            self.send(&ack);
            return (code, text);
        }
        panic!("lipcall gave no final answer to the INVITE");
    }

    /// Hangs up; lipcall's 200 is not waited for (its exit is).
    fn bye(&self) {
        let branch = format!("{}-bye", self.branch);
        self.send(&self.request("BYE", &self.contact, &branch, 2, ""));
    }
}

/// A header's value (the first of that name) in a SIP message.
fn header(message: &str, name: &str) -> Option<String> {
    message.split("\r\n").find_map(|line| {
        let (key, value) = line.split_once(':')?;
        key.trim()
            .eq_ignore_ascii_case(name)
            .then(|| value.trim().to_owned())
    })
}

/// Where an SDP sends media: its `c=` address and its audio port.
fn media_address(message: &str) -> SocketAddr {
    let lines: Vec<&str> = message.split("\r\n").collect();
    let ip = lines
        .iter()
        .find_map(|l| l.strip_prefix("c=IN IP4 "))
        .expect("c= line");
    let port = lines
        .iter()
        .find_map(|l| l.strip_prefix("m=audio "))
        .and_then(|rest| rest.split(' ').next())
        .expect("m=audio line");
    format!("{}:{port}", ip.trim()).parse().unwrap()
}

fn offer(c: &str, port: u16) -> String {
    format!(
        "v=0\r\no=caller 1 1 IN IP4 127.0.0.1\r\ns=-\r\nc={c}\r\nt=0 0\r\n\
         m=audio {port} RTP/AVP 0\r\na=rtpmap:0 PCMU/8000\r\na=sendrecv\r\n"
    )
}

/// One PCMU stream: 20 ms packets of one payload.
struct Sender {
    socket: UdpSocket,
    ssrc: u32,
    sequence: u16,
    timestamp: u32,
}

impl Sender {
    fn new(bind: &str, ssrc: u32) -> Self {
        let socket = UdpSocket::bind(bind).unwrap();
        socket.set_nonblocking(true).unwrap();
        Self {
            socket,
            ssrc,
            sequence: 1,
            timestamp: 0,
        }
    }

    /// `packets` of `payload`, one every 20 ms.
    fn send(&mut self, to: SocketAddr, payload: &[u8; 160], packets: usize) {
        let start = Instant::now();
        for i in 0..packets {
            let mut packet = vec![0x80, 0];
            packet.extend(self.sequence.to_be_bytes());
            packet.extend(self.timestamp.to_be_bytes());
            packet.extend(self.ssrc.to_be_bytes());
            packet.extend(payload);
            self.socket.send_to(&packet, to).unwrap();
            self.sequence = self.sequence.wrapping_add(1);
            self.timestamp = self.timestamp.wrapping_add(160);
            let due = start + Duration::from_millis(20 * (i as u64 + 1));
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
        }
    }

    /// How many datagrams lipcall sent this socket.
    fn received(&self) -> usize {
        let mut buf = [0u8; 2048];
        std::iter::from_fn(|| self.socket.recv_from(&mut buf).ok()).count()
    }
}

/// 1 kHz at full scale in mu-law: four samples of +32124, four of -32124.
const TONE: [u8; 160] = {
    let mut tone = [0u8; 160];
    let mut i = 0;
    while i < 160 {
        tone[i] = if i % 8 < 4 { 0x80 } else { 0x00 };
        i += 1;
    }
    tone
};
/// Mu-law zero.
const SILENCE: [u8; 160] = [0xff; 160];

/// The loudest 20 ms of a recording, as RMS.
fn loudest_rms(samples: &[i16]) -> f64 {
    samples
        .chunks(160)
        .map(|c| (c.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>() / c.len() as f64).sqrt())
        .fold(0.0, f64::max)
}

#[test]
fn rtp_from_a_second_address_is_never_played_nor_answered() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let heard = dir.path().join("heard.wav");
    let answer = lipcall_answering(dir.path(), port, "30", &heard);
    let mut peer = Sender::new("127.0.0.1:0", 0x9eed);
    let peer_addr = peer.socket.local_addr().unwrap();
    let mut caller = Caller::new(([127, 0, 0, 1], port).into());
    let (code, ok) = caller.invite(&offer("IN IP4 127.0.0.1", peer_addr.port()));
    assert_eq!(code, 200, "{ok}\n{}", answer.text());
    let lipcall_rtp = media_address(&ok);

    // Strangers: one on another loopback address, one on the caller's own IP.
    let mut stranger = Sender::new("127.0.0.2:0", 0xbad);
    let mut neighbour = Sender::new("127.0.0.1:0", 0xbad2);
    // Before the caller's first packet.
    stranger.send(lipcall_rtp, &TONE, 25);
    peer.send(lipcall_rtp, &SILENCE, 50);
    // After 400 ms of the caller's silence, twice.
    std::thread::sleep(Duration::from_millis(400));
    stranger.send(lipcall_rtp, &TONE, 50);
    std::thread::sleep(Duration::from_millis(400));
    neighbour.send(lipcall_rtp, &TONE, 25);
    peer.send(lipcall_rtp, &SILENCE, 50);
    caller.bye();
    let (code, log) = exit_of(answer, Duration::from_secs(10));
    assert_eq!(code, Some(0), "{log}");

    let (to_stranger, to_neighbour, to_peer) =
        (stranger.received(), neighbour.received(), peer.received());
    eprintln!(
        "lipcall sent {to_stranger} packets to the stranger, {to_neighbour} to the \
         neighbour, {to_peer} to the caller"
    );
    let (_, samples) = common::read_wav_i16(&heard);
    let loudest = loudest_rms(&samples);
    eprintln!(
        "{} s heard, loudest 20 ms at RMS {loudest:.0}",
        samples.len() / 8000
    );
    assert_eq!((to_stranger, to_neighbour), (0, 0), "{log}");
    assert!(to_peer > 100, "{to_peer}: {log}");
    assert!(samples.len() > 8000, "{} samples: {log}", samples.len());
    assert!(
        loudest < 100.0,
        "the strangers' tone was played: {loudest:.0}"
    );
    // Said, naming each stranger, once (the warning is rate-limited).
    for source in [stranger.socket.local_addr(), neighbour.socket.local_addr()] {
        let source = source.unwrap().to_string();
        let said: Vec<&str> = log.lines().filter(|l| l.contains(&source)).collect();
        assert_eq!(said.len(), 1, "{source}: {log}");
        assert!(said[0].contains("dropped"), "{log}");
    }
}

#[test]
fn offers_whose_media_address_is_no_host_get_488_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    for (c, named) in [
        ("IN IP4 0.0.0.0", "0.0.0.0:"),
        ("IN IP4 255.255.255.255", "255.255.255.255:"),
        ("IN IP4 224.0.0.1", "224.0.0.1:"),
        ("IN IP6 ::1", "[::1]:"),
    ] {
        let port = free_port(false);
        let answer = lipcall_answering(dir.path(), port, "30", &dir.path().join("heard.wav"));
        let mut caller = Caller::new(([127, 0, 0, 1], port).into());
        let (code, response) = caller.invite(&offer(c, free_port(false)));
        if code < 300 {
            caller.bye();
        }
        let (status, log) = exit_of(answer, Duration::from_secs(10));
        assert_eq!(code, 488, "{c}: {response}\n{log}");
        assert_eq!(status, Some(1), "{c}: {log}");
        assert!(log.contains(named), "{c}: {log}");
        assert!(!log.contains("panicked"), "{log}");
    }
}

/// A STUN server on 127.0.0.1 that answers every Binding request with `mapped`.
fn lying_stun_server(mapped: SocketAddr) -> SocketAddr {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = socket.local_addr().unwrap();
    std::thread::spawn(move || {
        let mut buf = [0u8; 1500];
        let SocketAddr::V4(mapped) = mapped else {
            return;
        };
        while let Ok((n, from)) = socket.recv_from(&mut buf) {
            if let Some(reply) = stun_binding_success(&buf[..n], mapped) {
                let _ = socket.send_to(&reply, from);
            }
        }
    });
    addr
}

#[test]
fn a_stun_server_answering_a_multicast_address_is_not_believed() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let stun = lying_stun_server("224.0.0.1:4000".parse().unwrap());
    let answer = lipcall_answering_with(
        dir.path(),
        port,
        "30",
        &dir.path().join("heard.wav"),
        &["--stun", &stun.to_string()],
    );
    let mut caller = Caller::new(([127, 0, 0, 1], port).into());
    let (code, ok) = caller.invite(&offer("IN IP4 127.0.0.1", free_port(false)));
    caller.bye();
    let (_, log) = exit_of(answer, Duration::from_secs(10));
    assert_eq!(code, 200, "{ok}\n{log}");
    let ours = media_address(&ok);
    assert_eq!(ours.ip().to_string(), "127.0.0.1", "{ok}\n{log}");
    assert!(
        log.lines()
            .any(|l| l.contains("224.0.0.1:4000") && l.contains("multicast")),
        "{log}"
    );
}

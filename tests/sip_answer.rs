//! `lipcall sip answer` against SIPp as the caller on 127.0.0.1: it survives garbage on its SIP
//! port, answers SIPp's call (hearing its own speech echoed), and ends on SIPp's BYE; an offer
//! it cannot take is refused with 488 and a clear error.

mod common;

use std::net::UdpSocket;
use std::process::Command;
use std::time::Duration;

use common::sip::{Peer, best_alignment, exit_of, free_port, installed, lipcall_answering};

/// What a hostile or broken peer might throw at a SIP port.
fn garbage() -> Vec<Vec<u8>> {
    let mut all: Vec<Vec<u8>> = vec![
        Vec::new(),
        b"\r\n\r\n".to_vec(),
        b"INVITE".to_vec(),
        b"INVITE sip:x@127.0.0.1 SIP/2.0\r\nVia: nonsense\r\n\r\n".to_vec(),
        b"INVITE sip:x@127.0.0.1 SIP/2.0\r\nContent-Length: 99999999\r\n\r\nv=0".to_vec(),
        b"SIP/2.0 200 OK\r\nVia: SIP/2.0/UDP 127.0.0.1:9;branch=z9hG4bKx\r\n\r\n".to_vec(),
        b"BYE sip:x@127.0.0.1 SIP/2.0\r\nCSeq: -1 BYE\r\nCall-ID: \xff\xfe\r\n\r\n".to_vec(),
        vec![0u8; 1500],
        vec![0xffu8; 65000],
    ];
    let mut x = 0x9e37_79b9u32;
    for len in [1usize, 12, 100, 400, 1400] {
        all.push(
            (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as u8
                })
                .collect(),
        );
    }
    all
}

#[test]
fn sip_answer_survives_garbage_takes_sipps_call_and_ends_on_its_bye() {
    if !installed("sipp") {
        common::unavailable("sipp (Debian sip-tester) is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let heard = dir.path().join("heard.wav");
    let answer = lipcall_answering(dir.path(), port, "30", &heard);
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    for datagram in garbage() {
        let _ = socket.send_to(&datagram, ("127.0.0.1", port));
    }
    std::thread::sleep(Duration::from_millis(300));
    assert!(!answer.text().contains("panicked"), "{}", answer.text());

    // SIPp's own caller: INVITE with PCMU, our RTP echoed back, BYE after 4 s.
    let media = free_port(true);
    let sipp = Peer::spawn(
        "sipp",
        Command::new("sipp")
            .args(["-sn", "uac", &format!("127.0.0.1:{port}")])
            .args(["-i", "127.0.0.1", "-p", &free_port(false).to_string()])
            .args([
                "-mp",
                &media.to_string(),
                "-rtp_echo",
                "-m",
                "1",
                "-d",
                "4000",
            ])
            .args(["-nostdin", "-timeout", "30s", "-timeout_error"])
            .current_dir(dir.path()),
    );
    let sipp = sipp.finish(Duration::from_secs(20)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
    let (code, log) = exit_of(answer, Duration::from_secs(8));
    assert_eq!(code, Some(0), "{log}");
    assert!(log.contains("call from"), "{log}");
    assert!(log.contains("the peer hung up"), "{log}");

    let (_, sent) = common::read_wav_i16(&common::demo_8k(dir.path()));
    let (_, got) = common::read_wav_i16(&heard);
    assert!(got.len() > 3 * 8000, "heard {} samples: {log}", got.len());
    let (_, corr) = best_alignment(&sent, &got, 8000, 8000, 1600);
    assert!(corr > 0.95, "the echo is not our speech: {corr:.3}");
}

const G729_CALLER: &str = r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="g729 caller">
  <send retrans="500"><![CDATA[
INVITE sip:lipcall@[remote_ip]:[remote_port] SIP/2.0
Via: SIP/2.0/[transport] [local_ip]:[local_port];branch=[branch]
From: sipp <sip:sipp@[local_ip]:[local_port]>;tag=[pid]SIPpTag00[call_number]
To: <sip:lipcall@[remote_ip]:[remote_port]>
Call-ID: [call_id]
CSeq: 1 INVITE
Contact: sip:sipp@[local_ip]:[local_port]
Max-Forwards: 70
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 1 IN IP4 [local_ip]
s=-
c=IN IP4 [local_ip]
t=0 0
m=audio [media_port] RTP/AVP 18
a=rtpmap:18 G729/8000
]]></send>
  <recv response="100" optional="true"/>
  <recv response="488"/>
  <send><![CDATA[
ACK sip:lipcall@[remote_ip]:[remote_port] SIP/2.0
[last_Via:]
From: sipp <sip:sipp@[local_ip]:[local_port]>;tag=[pid]SIPpTag00[call_number]
[last_To:]
Call-ID: [call_id]
CSeq: 1 ACK
Max-Forwards: 70
Content-Length: 0

]]></send>
</scenario>
"#;

#[test]
fn an_offer_lipcall_cannot_take_is_refused_with_488() {
    if !installed("sipp") {
        common::unavailable("sipp (Debian sip-tester) is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let answer = lipcall_answering(dir.path(), port, "30", &dir.path().join("heard.wav"));
    let scenario = dir.path().join("g729.xml");
    std::fs::write(&scenario, G729_CALLER).unwrap();
    let sipp = Peer::spawn(
        "sipp",
        Command::new("sipp")
            .arg(format!("127.0.0.1:{port}"))
            .arg("-sf")
            .arg(&scenario)
            .args(["-i", "127.0.0.1", "-p", &free_port(false).to_string()])
            .args(["-mp", &free_port(true).to_string(), "-m", "1"])
            .args(["-nostdin", "-timeout", "20s", "-timeout_error"])
            .current_dir(dir.path()),
    );
    let sipp = sipp.finish(Duration::from_secs(15)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
    let (code, log) = exit_of(answer, Duration::from_secs(5));
    assert_eq!(code, Some(1), "{log}");
    assert!(log.contains("no codec in common"), "{log}");
    assert!(!log.contains("panicked"), "{log}");
}

/// lipcall calling lipcall: the caller's BYE ends the answerer's call. (ezk's ACK took a CSeq
/// number the caller never sent, and the answerer held the BYE that came after the gap until
/// its own `--seconds`.)
#[test]
fn lipcall_answering_lipcall_ends_on_the_callers_bye() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let heard = dir.path().join("heard.wav");
    let answer = lipcall_answering(dir.path(), port, "30", &heard);
    let caller = common::run(
        common::lipcall()
            .args(["sip", "call", &format!("sip:lipcall@127.0.0.1:{port}")])
            .arg("--play")
            .arg(common::demo_8k(dir.path()))
            .args(["--seconds", "3", "--codec", "opus"]),
    );
    assert!(
        caller.status.success(),
        "{}",
        String::from_utf8_lossy(&caller.stderr)
    );
    let ended = answer.wait_for("the peer hung up", Duration::from_secs(5));
    let said = answer.text();
    assert!(ended, "the answerer did not end on the BYE:\n{said}");
    assert!(
        !String::from_utf8_lossy(&caller.stderr).contains("did not confirm the hang-up"),
        "{}",
        String::from_utf8_lossy(&caller.stderr)
    );
}

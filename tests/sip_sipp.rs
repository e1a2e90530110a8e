//! `lipcall sip call` against SIPp (`sip-tester`) on 127.0.0.1: a UAS that echoes our RTP
//! (we hear our own speech, in PCMU, Opus and G.722), one that is busy, one that rings and never
//! answers (we CANCEL), one whose SDP is hostile; and a registrar that does not exist.

mod common;

use std::path::Path;
use std::process::Output;
use std::time::{Duration, Instant};

use common::sip::{Peer, answering_scenario, best_alignment, free_port, installed, sipp_uas};

fn have_sipp() -> bool {
    if installed("sipp") {
        return true;
    }
    common::unavailable("sipp (Debian sip-tester) is not installed");
    false
}

fn call(dir: &Path, port: u16, extra: &[&str]) -> (Output, Duration) {
    let started = Instant::now();
    let mut lipcall = common::lipcall();
    if extra.contains(&"--stun") {
        // What the STUN server said is logged at info.
        lipcall.env("RUST_LOG", "lipcall=info");
    }
    let out = lipcall
        .args(["sip", "call", &format!("sip:echo@127.0.0.1:{port}")])
        .arg("--play")
        .arg(common::demo_8k(dir))
        .args(extra)
        .current_dir(dir)
        .output()
        .unwrap();
    (out, started.elapsed())
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Calls an echoing SIPp (with `extra` flags) and checks that what came back is the speech we
/// sent; lipcall's stderr.
fn echo(codec: &str, scenario: Option<String>, min_correlation: f64, extra: &[&str]) -> String {
    if !have_sipp() {
        return String::new();
    }
    let dir = tempfile::tempdir().unwrap();
    let (port, media) = (free_port(false), free_port(true));
    let sipp = sipp_uas(dir.path(), port, media, scenario.as_deref());
    let wav = dir.path().join("heard.wav");
    let weights = dir.path().join("weights.csv");
    let (out, took) = call(
        dir.path(),
        port,
        &[
            "--codec",
            codec,
            "--seconds",
            "5",
            "--wav",
            wav.to_str().unwrap(),
            // Compared with the 8 kHz source.
            "--rate",
            "8000",
            "--weights",
            weights.to_str().unwrap(),
        ]
        .iter()
        .chain(extra)
        .copied()
        .collect::<Vec<_>>(),
    );
    let log = stderr(&out);
    assert!(out.status.success(), "{log}");
    assert!(took < Duration::from_secs(12), "took {took:?}: {log}");
    assert!(log.contains(&format!("media: {codec}")), "{log}");
    // SIPp saw its one call through to our BYE and exits 0.
    let sipp = sipp.finish(Duration::from_secs(10)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );

    let (_, sent) = common::read_wav_i16(&common::demo_8k(dir.path()));
    let (rate, heard) = common::read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    assert!(
        heard.len() > 4 * 8000,
        "heard only {} samples: {log}",
        heard.len()
    );
    // Two seconds of speech, a second in, as four half seconds each aligned on its own
    // (wherever the echo put them): three of the four must be our speech, so one frame the
    // jitter buffer shed under load moves one window, not the verdict.
    let mut windows: Vec<(isize, f64)> = (0..4)
        .map(|k| best_alignment(&sent, &heard, 8000 + 4000 * k, 4000, 1600))
        .collect();
    windows.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (lag, corr) = windows[1];
    eprintln!("{codec}: correlation {corr:.3} with our speech at lag {lag}");
    assert!(
        corr >= min_correlation,
        "{codec}: the echo is not our speech (correlation {corr:.3} at lag {lag}): {log}"
    );
    let rows = std::fs::read_to_string(&weights).unwrap();
    assert!(
        rows.lines().count() > 150,
        "weights: {} rows",
        rows.lines().count()
    );
    log
}

#[test]
fn a_call_into_sipps_echo_hears_our_own_speech_in_pcmu() {
    echo("pcmu", None, 0.97, &[]);
}

/// With a STUN server (coturn), the SDP gives the media address it saw, and the call is heard.
#[test]
fn a_call_with_a_stun_server_offers_the_address_it_saw() {
    let dir = tempfile::tempdir().unwrap();
    let Some(coturn) = common::nat::start_coturn(dir.path(), "127.0.0.1", None) else {
        return;
    };
    let server = coturn.addr.to_string();
    let log = echo("pcmu", None, 0.97, &["--stun", &server]);
    if !log.is_empty() {
        assert!(
            log.contains(&format!(
                "STUN server {server}: our media address outside is 127.0.0.1:"
            )),
            "{log}"
        );
    }
}

#[test]
fn a_call_into_sipps_echo_hears_our_own_speech_in_opus() {
    let scenario =
        answering_scenario("m=audio [media_port] RTP/AVP 111\na=rtpmap:111 opus/48000/2");
    echo("opus", Some(scenario), 0.85, &[]);
}

#[test]
fn a_call_into_sipps_echo_hears_our_own_speech_in_g722() {
    let scenario = answering_scenario("m=audio [media_port] RTP/AVP 9\na=rtpmap:9 G722/8000");
    echo("g722", Some(scenario), 0.97, &[]);
}

const BUSY: &str = r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="busy">
  <recv request="INVITE" crlf="true"/>
  <send><![CDATA[
SIP/2.0 486 Busy Here
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Content-Length: 0

]]></send>
  <recv request="ACK"/>
</scenario>
"#;

#[test]
fn a_busy_peer_is_a_clear_failure() {
    if !have_sipp() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let sipp = sipp_uas(dir.path(), port, free_port(true), Some(BUSY));
    let (out, took) = call(dir.path(), port, &["--seconds", "10"]);
    let log = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(log.contains("486 Busy Here"), "{log}");
    assert!(took < Duration::from_secs(5), "took {took:?}");
    assert!(!log.contains("panicked"), "{log}");
    let sipp = sipp.finish(Duration::from_secs(10)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
}

/// Rings; the CANCEL that comes is answered 200, then the INVITE 487 with the CANCEL's Via,
/// which ends our INVITE only if the CANCEL carried the INVITE's branch (RFC 3261 9.1).
const RINGS: &str = r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="rings">
  <recv request="INVITE" crlf="true">
    <action>
      <ereg regexp="[0-9]+" search_in="hdr" header="CSeq:" assign_to="invite_cseq"/>
    </action>
  </recv>
  <send><![CDATA[
SIP/2.0 180 Ringing
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Content-Length: 0

]]></send>
  <recv request="CANCEL"/>
  <send><![CDATA[
SIP/2.0 200 OK
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Content-Length: 0

]]></send>
  <send><![CDATA[
SIP/2.0 487 Request Terminated
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
CSeq: [$invite_cseq] INVITE
Content-Length: 0

]]></send>
  <recv request="ACK"/>
</scenario>
"#;

#[test]
fn an_unanswered_call_is_cancelled_at_the_time_limit() {
    if !have_sipp() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let sipp = sipp_uas(dir.path(), port, free_port(true), Some(RINGS));
    let (out, took) = call(dir.path(), port, &["--seconds", "2"]);
    let log = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(log.contains("is ringing"), "{log}");
    assert!(
        log.contains("no answer within 2 s; the call was cancelled"),
        "{log}"
    );
    // The 487 ended our INVITE at once: no wait for a CANCEL nobody matched.
    assert!(took < Duration::from_secs(4), "took {took:?}: {log}");
    // SIPp got the CANCEL and finished its scenario.
    let sipp = sipp.finish(Duration::from_secs(10)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
}

#[test]
fn a_hostile_answer_is_a_clear_failure() {
    if !have_sipp() {
        return;
    }
    // Each answers the INVITE with SDP lipcall cannot use.
    for (media, expect) in [
        (
            "m=audio [media_port] RTP/AVP 18\na=rtpmap:18 G729/8000",
            "no codec in common",
        ),
        ("m=audio 0 RTP/AVP 0", "refused"),
        ("m=video [media_port] RTP/AVP 96", "no audio stream"),
        (
            "m=audio [media_port] RTP/AVP 0\nc=IN IP4 0.0.0.0",
            "the peer's media address cannot be used: 0.0.0.0:",
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let port = free_port(false);
        let scenario = answering_scenario(media);
        let _sipp: Peer = sipp_uas(dir.path(), port, free_port(true), Some(&scenario));
        let (out, took) = call(dir.path(), port, &["--seconds", "8"]);
        let log = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{media}: {log}");
        assert!(log.contains(expect), "{media}: {log}");
        assert!(!log.contains("panicked"), "{log}");
        assert!(took < Duration::from_secs(8), "{media}: took {took:?}");
    }
}

#[test]
fn an_unreachable_registrar_is_a_clear_failure() {
    let dir = tempfile::tempdir().unwrap();
    // Nothing listens there.
    let port = free_port(false);
    let password = dir.path().join("password");
    std::fs::write(&password, "secret\n").unwrap();
    let (out, took) = call(
        dir.path(),
        port,
        &[
            "--account",
            &format!("sip:alice@127.0.0.1:{port}"),
            "--password-file",
            password.to_str().unwrap(),
            "--seconds",
            "20",
        ],
    );
    let log = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(log.contains("did not answer within 5 s"), "{log}");
    assert!(took < Duration::from_secs(9), "took {took:?}");
    assert!(
        !log.contains("secret"),
        "the password is never shown: {log}"
    );
}

/// Answers, then after a second puts us on hold (re-INVITE, sendonly) and after two more
/// resumes (sendrecv); SIPp checks that our answers say recvonly, then sendrecv.
const HOLDS: &str = r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="hold and resume">
  <recv request="INVITE" crlf="true">
    <action>
      <ereg regexp=".*" search_in="hdr" header="From:" assign_to="caller"/>
      <ereg regexp="sip:[^>]*" search_in="hdr" header="Contact:" assign_to="caller_contact"/>
    </action>
  </recv>
  <send><![CDATA[
SIP/2.0 200 OK
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 1 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
m=audio [media_port] RTP/AVP 0
a=rtpmap:0 PCMU/8000
a=sendrecv
]]></send>
  <recv request="ACK" crlf="true"/>
  <pause milliseconds="1000"/>
  <send retrans="500"><![CDATA[
INVITE [$caller_contact] SIP/2.0
Via: SIP/2.0/[transport] [local_ip]:[local_port];branch=[branch]
From: <sip:echo@[local_ip]:[local_port]>;tag=[pid]SIPpTag01[call_number]
To: [$caller]
Call-ID: [call_id]
CSeq: 1 INVITE
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Max-Forwards: 70
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 2 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
m=audio [media_port] RTP/AVP 0
a=rtpmap:0 PCMU/8000
a=sendonly
]]></send>
  <recv response="200">
    <action>
      <ereg regexp="a=recvonly" search_in="body" check_it="true" assign_to="held"/>
    </action>
  </recv>
  <send><![CDATA[
ACK [$caller_contact] SIP/2.0
Via: SIP/2.0/[transport] [local_ip]:[local_port];branch=[branch]
From: <sip:echo@[local_ip]:[local_port]>;tag=[pid]SIPpTag01[call_number]
To: [$caller]
Call-ID: [call_id]
CSeq: 1 ACK
X-Held: [$held]
Max-Forwards: 70
Content-Length: 0

]]></send>
  <pause milliseconds="2000"/>
  <send retrans="500"><![CDATA[
INVITE [$caller_contact] SIP/2.0
Via: SIP/2.0/[transport] [local_ip]:[local_port];branch=[branch]
From: <sip:echo@[local_ip]:[local_port]>;tag=[pid]SIPpTag01[call_number]
To: [$caller]
Call-ID: [call_id]
CSeq: 2 INVITE
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Max-Forwards: 70
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 3 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
m=audio [media_port] RTP/AVP 0
a=rtpmap:0 PCMU/8000
a=sendrecv
]]></send>
  <recv response="200">
    <action>
      <ereg regexp="a=sendrecv" search_in="body" check_it="true" assign_to="resumed"/>
    </action>
  </recv>
  <send><![CDATA[
ACK [$caller_contact] SIP/2.0
Via: SIP/2.0/[transport] [local_ip]:[local_port];branch=[branch]
From: <sip:echo@[local_ip]:[local_port]>;tag=[pid]SIPpTag01[call_number]
To: [$caller]
Call-ID: [call_id]
CSeq: 2 ACK
X-Resumed: [$resumed]
Max-Forwards: 70
Content-Length: 0

]]></send>
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
"#;

#[test]
fn a_peer_that_holds_gets_no_media_until_it_resumes() {
    if !have_sipp() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let sipp = sipp_uas(dir.path(), port, free_port(true), Some(HOLDS));
    let (out, _) = call(dir.path(), port, &["--codec", "pcmu", "--seconds", "6"]);
    let log = stderr(&out);
    assert!(out.status.success(), "{log}");
    let sipp = sipp.finish(Duration::from_secs(10)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
    // About 6 s of packets, less the 2 s on hold.
    let sent: u32 = log
        .split("sent_rtp=")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sent_rtp in {log}"));
    assert!((150..=240).contains(&sent), "sent {sent} packets: {log}");
}

/// Answers 183 with PCMA SDP and plays SIPp's own G.711 recording into the call before the
/// 200 two seconds later; then waits for BYE.
const EARLY_MEDIA: &str = r#"<?xml version="1.0" encoding="ISO-8859-1" ?>
<scenario name="early media">
  <recv request="INVITE" crlf="true"/>
  <send><![CDATA[
SIP/2.0 183 Session Progress
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 1 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
m=audio [media_port] RTP/AVP 8
a=rtpmap:8 PCMA/8000
]]></send>
  <nop>
    <action>
      <exec play_pcap_audio="/usr/share/sip-tester/g711a.pcap"/>
    </action>
  </nop>
  <pause milliseconds="2000"/>
  <send><![CDATA[
SIP/2.0 200 OK
[last_Via:]
[last_From:]
[last_To:];tag=[pid]SIPpTag01[call_number]
[last_Call-ID:]
[last_CSeq:]
Contact: <sip:[local_ip]:[local_port];transport=[transport]>
Content-Type: application/sdp
Content-Length: [len]

v=0
o=sipp 1 1 IN IP4 [local_ip]
s=-
c=IN IP4 [media_ip]
t=0 0
m=audio [media_port] RTP/AVP 8
a=rtpmap:8 PCMA/8000
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
"#;

#[test]
fn early_media_is_heard_while_it_rings() {
    if !have_sipp() {
        return;
    }
    if !Path::new("/usr/share/sip-tester/g711a.pcap").exists() {
        common::unavailable("SIPp's g711a.pcap is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let sipp = sipp_uas(dir.path(), port, free_port(true), Some(EARLY_MEDIA));
    let wav = dir.path().join("heard.wav");
    let (out, _) = call(
        dir.path(),
        port,
        &["--seconds", "5", "--wav", wav.to_str().unwrap()],
    );
    let log = stderr(&out);
    assert!(out.status.success(), "{log}");
    let early = log.find("sends early media").expect("early media noticed");
    let answered = log.find("in a SIP call").expect("answered");
    assert!(early < answered, "{log}");
    // Heard from the 183 on: well over the 3 s after the answer.
    let (_, heard) = common::read_wav_i16(&wav);
    assert!(
        heard.len() > 4 * 8000,
        "heard {} samples: {log}",
        heard.len()
    );
    let sipp = sipp.finish(Duration::from_secs(10)).expect("SIPp ended");
    assert!(
        sipp.status.success(),
        "SIPp: {}",
        String::from_utf8_lossy(&sipp.stdout)
    );
}

//! Hostile SIP peers, written here on raw UDP sockets on 127.0.0.1, against a real `lipcall sip
//! answer` or `sip call` (issue 43): a flood of INVITEs that never ACK their refusal during a
//! call, one of requests for no call at all, a callee that opens a fresh early dialog with every
//! provisional answer, and a peer that floods its call with re-INVITEs it never ACKs. What
//! lipcall keeps for them must stay small (its resident memory is read from /proc), its log
//! short, and the call must go on.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use common::sip::{
    Logged, Peer, exit_of, flood, free_port, header, lipcall_answering, receive, status,
};

/// What lipcall may keep for a flood, at its peak, over what it held before it.
const MAX_GROWTH_MB: f64 = 50.0;
/// Log lines a whole test may cause: the call's own few, never one per hostile message.
const MAX_LOG_LINES: usize = 20;

/// A field of lipcall's /proc/PID/status in MB (`VmRSS` now, `VmHWM` the peak); `None` once it
/// has exited.
fn memory(lipcall: &Logged, field: &str) -> Option<f64> {
    common::memory_mb(lipcall.peer.child.as_ref().expect("running").id(), field)
}

fn memory_mb(lipcall: &Logged, field: &str) -> f64 {
    memory(lipcall, field).unwrap_or_else(|| panic!("lipcall has exited: {}", lipcall.text()))
}

/// An offer of PCMU on `media`.
fn sdp(media: u16) -> String {
    format!(
        "v=0\r\no=hostile 1 1 IN IP4 127.0.0.1\r\ns=-\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n\
         m=audio {media} RTP/AVP 0\r\na=rtpmap:0 PCMU/8000\r\n"
    )
}

/// One side of a dialog with lipcall, as the hostile peer sees it.
struct Dialog {
    socket: UdpSocket,
    lipcall: SocketAddr,
    /// Where in-dialog requests go: lipcall's Contact.
    target: String,
    call_id: String,
    /// Our own From (tag included) and lipcall's (its tag included), as in-dialog requests
    /// carry them.
    ours: String,
    theirs: String,
    media: u16,
}

impl Dialog {
    fn request(&self, method: &str, branch: &str, cseq: u32, body: &str) -> String {
        let me = self.socket.local_addr().unwrap();
        let content_type = if body.is_empty() {
            ""
        } else {
            "Content-Type: application/sdp\r\n"
        };
        format!(
            "{method} {target} SIP/2.0\r\nVia: SIP/2.0/UDP {me};branch=z9hG4bK{branch}\r\n\
             From: {ours}\r\nTo: {theirs}\r\nCall-ID: {call_id}\r\nCSeq: {cseq} {method}\r\n\
             Contact: <sip:hostile@{me}>\r\nMax-Forwards: 70\r\n{content_type}\
             Content-Length: {len}\r\n\r\n{body}",
            target = self.target,
            ours = self.ours,
            theirs = self.theirs,
            call_id = self.call_id,
            len = body.len(),
        )
    }

    fn send(&self, message: &str) {
        self.socket
            .send_to(message.as_bytes(), self.lipcall)
            .unwrap();
    }

    /// Hangs up (the BYE numbered `cseq`): true once lipcall answered it with 200 within
    /// `limit`.
    fn bye(&self, cseq: u32, limit: Duration) -> bool {
        let bye = self.request("BYE", "bye", cseq, "");
        let deadline = Instant::now() + limit;
        let mut resent = Instant::now();
        self.send(&bye);
        while Instant::now() < deadline {
            if let Some((message, _)) = receive(&self.socket)
                && header(&message, "CSeq") == Some(&format!("{cseq} BYE"))
                && status(&message) == Some(200)
            {
                return true;
            }
            if resent.elapsed() > Duration::from_secs(2) {
                self.send(&bye);
                resent = Instant::now();
            }
        }
        false
    }
}

/// Hangs up the call lipcall is in (our BYE numbered `cseq`), and waits for lipcall to exit
/// cleanly without having said much; its log.
fn hang_up(call: &Dialog, cseq: u32, lipcall: Logged) -> String {
    assert!(
        call.bye(cseq, Duration::from_secs(20)),
        "no 200 for our BYE: {}",
        lipcall.text()
    );
    let (code, log) = exit_of(lipcall, Duration::from_secs(10));
    assert_eq!(code, Some(0), "{log}");
    assert_said_little(&log);
    log
}

fn assert_said_little(log: &str) {
    let lines = log.lines().count();
    assert!(lines <= MAX_LOG_LINES, "{lines} log lines:\n{log}");
}

/// Calls `sip answer` on `port` from a raw socket: the dialog once lipcall's 200 is ACKed.
fn call_lipcall(port: u16) -> Dialog {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let me = socket.local_addr().unwrap();
    let lipcall: SocketAddr = ([127, 0, 0, 1], port).into();
    let mut dialog = Dialog {
        socket,
        lipcall,
        target: format!("sip:lipcall@{lipcall}"),
        call_id: "the-call".into(),
        ours: format!("<sip:hostile@{me}>;tag=caller"),
        theirs: format!("<sip:lipcall@{lipcall}>"),
        media: free_port(false),
    };
    dialog.send(&dialog.request("INVITE", "call", 1, &sdp(dialog.media)));
    let ok = loop {
        let (message, _) = receive(&dialog.socket).expect("lipcall answers the call");
        if status(&message) == Some(200) {
            break message;
        }
    };
    dialog.theirs = header(&ok, "To").unwrap().to_owned();
    let contact = header(&ok, "Contact").unwrap();
    dialog.target = contact
        .trim_start_matches('<')
        .split('>')
        .next()
        .unwrap()
        .to_owned();
    dialog.send(&dialog.request("ACK", "call-ack", 1, ""));
    dialog
}

/// `sip answer` in a call from a raw socket.
fn answering_in_a_call(dir: &std::path::Path) -> (Logged, Dialog) {
    let port = free_port(false);
    let answer = lipcall_answering(dir, port, "60", &dir.join("heard.wav"));
    let call = call_lipcall(port);
    assert!(
        answer.wait_for("in a SIP call", Duration::from_secs(10)),
        "{}",
        answer.text()
    );
    (answer, call)
}

#[test]
fn invites_that_never_ack_their_refusal_during_a_call_cost_lipcall_nothing_it_keeps() {
    let dir = tempfile::tempdir().unwrap();
    let (answer, call) = answering_in_a_call(dir.path());
    std::thread::sleep(Duration::from_secs(1));
    let before = memory_mb(&answer, "VmRSS");

    let flooder = UdpSocket::bind("127.0.0.1:0").unwrap();
    let me = flooder.local_addr().unwrap();
    let lipcall = call.lipcall;
    let offer = sdp(free_port(false));
    let invite = |n: usize| {
        format!(
            "INVITE sip:lipcall@{lipcall} SIP/2.0\r\nVia: SIP/2.0/UDP {me};branch=z9hG4bKf{n}\r\n\
             From: <sip:flood@{me}>;tag=f{n}\r\nTo: <sip:lipcall@{lipcall}>\r\n\
             Call-ID: flood-{n}\r\nCSeq: 1 INVITE\r\nContact: <sip:flood@{me}>\r\n\
             Max-Forwards: 70\r\nContent-Type: application/sdp\r\nContent-Length: {}\r\n\r\n{offer}",
            offer.len()
        )
    };
    let started = Instant::now();
    let refused = flood(
        &flooder,
        lipcall,
        40_000,
        200,
        Duration::from_secs(30),
        invite,
        |response| {
            (status(response) == Some(486))
                .then(|| {
                    header(response, "Call-ID")?
                        .strip_prefix("flood-")?
                        .parse()
                        .ok()
                })
                .flatten()
        },
    );
    let took = started.elapsed();
    let peak = memory_mb(&answer, "VmHWM");
    let after = memory_mb(&answer, "VmRSS");
    eprintln!(
        "40,000 INVITEs in {took:.1?}: {} refused with 486; RSS {before:.1} MB before, \
         {after:.1} MB after, peak {peak:.1} MB",
        refused.len()
    );
    assert!(
        refused.len() >= 39_000,
        "only {} of 40,000 INVITEs got 486 Busy Here",
        refused.len()
    );
    assert!(
        peak - before < MAX_GROWTH_MB,
        "lipcall grew from {before:.1} to {peak:.1} MB for 40,000 INVITEs"
    );

    // The call itself went on.
    let log = hang_up(&call, 2, answer);
    assert!(log.contains("the peer hung up"), "{log}");
}

#[test]
fn requests_for_no_call_of_lipcalls_are_answered_without_being_kept() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let answer = lipcall_answering(dir.path(), port, "60", &dir.path().join("heard.wav"));
    std::thread::sleep(Duration::from_secs(1));
    let before = memory_mb(&answer, "VmRSS");
    let flooder = UdpSocket::bind("127.0.0.1:0").unwrap();
    let me = flooder.local_addr().unwrap();
    let lipcall: SocketAddr = ([127, 0, 0, 1], port).into();
    // What each asks, and what it must get: a dialog or transaction lipcall does not have, a
    // method it does not implement, a keepalive.
    let kinds = [
        ("BYE", "", 481),
        ("BYE", ";tag=made-up", 481),
        ("CANCEL", "", 481),
        ("NOTIFY", ";tag=made-up", 481),
        ("INFO", "", 405),
        ("OPTIONS", "", 200),
    ];
    let request = |n: usize| {
        let (method, to_tag, _) = kinds[n % kinds.len()];
        format!(
            "{method} sip:lipcall@{lipcall} SIP/2.0\r\nVia: SIP/2.0/UDP {me};branch=z9hG4bKo{n}\r\n\
             From: <sip:flood@{me}>;tag=f{n}\r\nTo: <sip:lipcall@{lipcall}>{to_tag}\r\n\
             Call-ID: other-{n}\r\nCSeq: 1 {method}\r\nMax-Forwards: 70\r\n\
             Content-Length: 0\r\n\r\n"
        )
    };
    let started = Instant::now();
    let answered = flood(
        &flooder,
        lipcall,
        30_000,
        200,
        Duration::from_secs(30),
        request,
        |response| {
            let n: usize = header(response, "Call-ID")?
                .strip_prefix("other-")?
                .parse()
                .ok()?;
            (status(response) == Some(kinds[n % kinds.len()].2)).then_some(n)
        },
    );
    let took = started.elapsed();
    let peak = memory_mb(&answer, "VmHWM");
    eprintln!(
        "30,000 requests for no call in {took:.1?}: {} answered as expected; RSS {before:.1} MB \
         before, peak {peak:.1} MB",
        answered.len()
    );
    assert!(
        answered.len() >= 29_000,
        "only {} of 30,000 answered as expected",
        answered.len()
    );
    assert!(
        peak - before < MAX_GROWTH_MB,
        "lipcall grew from {before:.1} to {peak:.1} MB for 30,000 requests"
    );
    // It still takes a call.
    hang_up(&call_lipcall(port), 2, answer);
}

/// `sip call` to a raw socket: lipcall's INVITE and where it came from.
fn called_by_lipcall(dir: &std::path::Path) -> (Logged, UdpSocket, String, SocketAddr) {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let me = socket.local_addr().unwrap();
    let caller = Peer::spawn_logged(
        "lipcall sip call",
        common::lipcall()
            .args(["sip", "call", &format!("sip:callee@{me}")])
            .arg("--play")
            .arg(common::demo_8k(dir))
            .args(["--seconds", "60"]),
    );
    let (invite, from) = loop {
        let (message, from) = receive(&socket).expect("lipcall's INVITE");
        if message.starts_with("INVITE ") {
            break (message, from);
        }
    };
    (caller, socket, invite, from)
}

/// A response to lipcall's `invite` with our To-tag `tag` (and `extra` headers and body).
fn response_to(invite: &str, code: &str, tag: &str, extra: &str, body: &str) -> String {
    let copied: String = ["Via", "From", "Call-ID", "CSeq"]
        .iter()
        .map(|name| format!("{name}: {}\r\n", header(invite, name).unwrap()))
        .collect();
    format!(
        "SIP/2.0 {code}\r\n{copied}To: {};tag={tag}\r\n{extra}Content-Length: {}\r\n\r\n{body}",
        header(invite, "To").unwrap(),
        body.len()
    )
}

#[test]
fn a_callee_opening_an_early_dialog_per_answer_is_cancelled_after_a_few() {
    let dir = tempfile::tempdir().unwrap();
    let (caller, socket, invite, lipcall) = called_by_lipcall(dir.path());
    let before = memory_mb(&caller, "VmRSS");
    let me = socket.local_addr().unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(1)))
        .unwrap();
    let contact = format!("Contact: <sip:callee@{me}>\r\n");
    let broken = "Content-Type: application/sdp\r\n";
    let mut sent = 0;
    let mut peak = before;
    let mut cancel = None;
    let deadline = Instant::now() + Duration::from_secs(30);
    while sent < 20_000 && cancel.is_none() && Instant::now() < deadline {
        for _ in 0..20 {
            // Every other one a 183 whose description lipcall cannot take.
            let answer = if sent % 2 == 0 {
                response_to(&invite, "180 Ringing", &format!("e{sent}"), &contact, "")
            } else {
                let extra = format!("{contact}{broken}");
                response_to(
                    &invite,
                    "183 Session Progress",
                    &format!("e{sent}"),
                    &extra,
                    "v=0\r\nbroken\r\n",
                )
            };
            socket.send_to(answer.as_bytes(), lipcall).unwrap();
            sent += 1;
        }
        // lipcall ends as soon as it cancels: its peak is read while it runs.
        peak = memory(&caller, "VmHWM").unwrap_or(peak).max(peak);
        while let Some((message, _)) = receive(&socket) {
            if message.starts_with("CANCEL ") {
                cancel = Some(message);
            }
        }
    }
    eprintln!(
        "{sent} provisional answers with fresh To-tags; RSS {before:.1} MB before, peak {peak:.1} MB"
    );
    let cancel =
        cancel.unwrap_or_else(|| panic!("no CANCEL after {sent} early dialogs: {}", caller.text()));
    assert!(sent <= 400, "the CANCEL came after {sent} early dialogs");
    // RFC 3261 9.1: the CANCEL names the INVITE (its branch, Call-ID and CSeq number).
    for name in ["Via", "Call-ID"] {
        assert_eq!(header(&cancel, name), header(&invite, name), "{cancel}");
    }
    assert_eq!(
        header(&cancel, "CSeq").unwrap().replace("CANCEL", "INVITE"),
        header(&invite, "CSeq").unwrap()
    );
    assert!(
        peak - before < MAX_GROWTH_MB,
        "lipcall grew from {before:.1} to {peak:.1} MB for {sent} early dialogs"
    );
    let (code, log) = exit_of(caller, Duration::from_secs(10));
    assert_eq!(code, Some(1), "{log}");
    assert!(log.contains("early dialogs"), "{log}");
    assert_said_little(&log);
}

/// Floods the call with 3,000 re-INVITEs that are never ACKed: each must be answered at once
/// (one taken, the others 500 with Retry-After while it is in progress, RFC 3261 14.2), without
/// lipcall keeping them; then the caller's BYE still ends the call.
fn reinvite_flood(dialog: &Dialog, lipcall: Logged) {
    std::thread::sleep(Duration::from_secs(1));
    let before = memory_mb(&lipcall, "VmRSS");
    let offer = sdp(dialog.media);
    let started = Instant::now();
    // The last re-INVITE lipcall took (answered 200): ezk's dialog takes the next request's CSeq
    // at most 64 past the last it saw, and the refused ones it never saw.
    let taken = std::cell::Cell::new(1);
    let answered = flood(
        &dialog.socket,
        dialog.lipcall,
        3_000,
        64,
        Duration::from_secs(30),
        |n| dialog.request("INVITE", &format!("re{n}"), 2 + n as u32, &offer),
        |response| {
            let (cseq, method) = header(response, "CSeq")?.split_once(' ')?;
            let cseq: u32 = cseq.parse().ok()?;
            if status(response) == Some(200) {
                taken.set(taken.get().max(cseq));
            }
            (method == "INVITE").then(|| cseq.checked_sub(2).map(|n| n as usize))?
        },
    );
    let took = started.elapsed();
    let peak = memory_mb(&lipcall, "VmHWM");
    eprintln!(
        "3,000 re-INVITEs in {took:.1?}: {} answered; RSS {before:.1} MB before, peak {peak:.1} MB",
        answered.len()
    );
    assert!(
        answered.len() >= 2_900,
        "only {} of 3,000 re-INVITEs answered in {took:.1?}: {}",
        answered.len(),
        lipcall.text()
    );
    assert!(
        peak - before < MAX_GROWTH_MB,
        "lipcall grew from {before:.1} to {peak:.1} MB for 3,000 re-INVITEs"
    );
    hang_up(dialog, taken.get() + 1, lipcall);
}

#[test]
fn a_callee_flooding_its_call_with_re_invites_gets_them_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let (caller, socket, invite, lipcall) = called_by_lipcall(dir.path());
    let media = free_port(false);
    let me = socket.local_addr().unwrap();
    let ok = response_to(
        &invite,
        "200 OK",
        "callee",
        &format!("Contact: <sip:callee@{me}>\r\nContent-Type: application/sdp\r\n"),
        &sdp(media),
    );
    socket.send_to(ok.as_bytes(), lipcall).unwrap();
    loop {
        let (message, _) = receive(&socket).expect("lipcall's ACK");
        if message.starts_with("ACK ") {
            break;
        }
    }
    let contact = header(&invite, "Contact").unwrap();
    let dialog = Dialog {
        socket,
        lipcall,
        target: contact
            .trim_start_matches('<')
            .split('>')
            .next()
            .unwrap()
            .to_owned(),
        call_id: header(&invite, "Call-ID").unwrap().to_owned(),
        ours: format!("{};tag=callee", header(&invite, "To").unwrap()),
        theirs: header(&invite, "From").unwrap().to_owned(),
        media,
    };
    reinvite_flood(&dialog, caller);
}

#[test]
fn a_caller_flooding_its_call_with_re_invites_gets_them_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let (answer, dialog) = answering_in_a_call(dir.path());
    reinvite_flood(&dialog, answer);
}

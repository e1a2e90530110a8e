//! `sip call|answer --frame-ms 10`, lipcall to lipcall over SIP on loopback: `a=ptime:10` on
//! both sides sends Opus in 10 ms packets both ways; an answer of `a=ptime:20` is honoured.

mod common;

use common::net::{fields, num};
use common::sip::{Logged, free_port, lipcall_answering_with};

/// The caller's log (its summary of the answerer's stream) and the answerer's, of a 4 s call.
fn call(caller_args: &[&str], answer_args: &[&str]) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let heard = dir.path().join("heard.wav");
    let answer: Logged = lipcall_answering_with(dir.path(), port, "30", &heard, answer_args);
    let out = common::run(
        common::lipcall()
            .args(["sip", "call", &format!("sip:lipcall@127.0.0.1:{port}")])
            .arg("--play")
            .arg(common::demo_8k(dir.path()))
            .args(["--seconds", "4", "--codec", "opus"])
            .args(caller_args),
    );
    // The caller's BYE ends the answerer, which then prints its summary.
    answer.wait_for("the peer hung up", std::time::Duration::from_secs(5));
    let answered = answer.text();
    drop(answer);
    (String::from_utf8_lossy(&out.stderr).into_owned(), answered)
}

#[test]
fn ten_ms_frames_both_ways_where_both_ask_and_twenty_where_the_answer_says_ptime_20() {
    let (caller, answerer) = call(&["--frame-ms", "10"], &["--frame-ms", "10"]);
    assert!(caller.contains("sending opus in 10 ms frames"), "{caller}");
    assert!(
        answerer.contains("sending opus in 10 ms frames"),
        "{answerer}"
    );
    let ten = fields(&caller, "peer ");
    assert_eq!(ten["codec"], "opus", "{caller}");
    assert_eq!(num(&ten, "decode_errors"), 0.0, "{caller}");

    // The answer asks for 20 ms packets (and sends them): the caller sends 20 though it
    // asked for 10.
    let (caller, answerer) = call(&["--frame-ms", "10"], &[]);
    assert!(caller.contains("sending opus in 20 ms frames"), "{caller}");
    assert!(!answerer.contains("ms frames"), "{answerer}");
    let twenty = fields(&caller, "peer ");
    assert_eq!(num(&twenty, "decode_errors"), 0.0, "{caller}");
    // Calls of the same length: twice the packets at 10 ms.
    let (a, b) = (num(&ten, "received"), num(&twenty, "received"));
    eprintln!("packets received: {a} at 10 ms, {b} at 20 ms");
    assert!(b >= 100.0 && a >= 1.6 * b, "{a} vs {b}");
}

//! lipcall and a real softphone (Debian's baresip 1.0) on 127.0.0.1: lipcall registers with a
//! kamailio that demands digest authentication and calls baresip through it; baresip calls
//! `lipcall sip answer`. Each side's microphone is a WAV file (baresip's `aufile`), each side
//! records what it hears (baresip's `sndfile`), and either side hangs up.

mod common;

use std::time::Duration;

use common::sip::{
    PASSWORD, Peer, baresip, baresip_heard, best_alignment, bob_registered, free_port, have,
    kamailio, kamailio_with, lipcall_answering, median_snr, reversed_8k, tell_baresip,
};

/// The strongest correlation (in absolute value) between a viseme column of WEIGHTS.csv and
/// the energy of the frames of `audio` its rows name.
fn weights_following_speech(csv: &str, audio: &[i16]) -> f64 {
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 200, "{} rows of weights", rows.len());
    let energy: Vec<f64> = rows
        .iter()
        .map(|r| {
            let at = r[0] as usize * 160;
            let frame = &audio[at.min(audio.len())..(at + 160).min(audio.len())];
            let power = frame.iter().map(|&s| f64::from(s).powi(2)).sum::<f64>();
            10.0 * (power / 160.0 + 1.0).log10()
        })
        .collect();
    let correlation = |a: &[f64], b: &[f64]| {
        let (ma, mb) = (
            a.iter().sum::<f64>() / a.len() as f64,
            b.iter().sum::<f64>() / b.len() as f64,
        );
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt().max(1e-12)
    };
    (2..rows[0].len())
        .map(|c| {
            let column: Vec<f64> = rows.iter().map(|r| r[c]).collect();
            correlation(&column, &energy).abs()
        })
        .fold(0.0, f64::max)
}

#[test]
fn lipcall_registers_with_kamailio_calls_baresip_and_hears_it() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let kam_port = free_port(false);
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let bob_speech = reversed_8k(dir.path());
    let bob = bob_registered(dir.path(), kam_port, "auto", &bob_speech);
    let heard = dir.path().join("lipcall-heard.wav");
    let weights = dir.path().join("weights.csv");
    let ours = common::demo_8k(dir.path());
    let out = common::lipcall()
        .args(["sip", "call", &format!("sip:bob@127.0.0.1:{kam_port}")])
        .arg("--play")
        .arg(&ours)
        .args(["--account", &format!("sip:alice@127.0.0.1:{kam_port}")])
        .env("LIPCALL_SIP_PASSWORD", PASSWORD)
        .args(["--codec", "pcmu", "--dtmf", "1#9", "--seconds", "6"])
        .arg("--wav")
        .arg(&heard)
        .arg("--weights")
        .arg(&weights)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{log}\nbaresip: {}", bob.text());
    assert!(
        log.contains(&format!("registered with 127.0.0.1:{kam_port}")),
        "{log}"
    );
    assert!(
        !log.contains(PASSWORD),
        "the password is never shown: {log}"
    );

    // Our BYE ended baresip's call too; our DTMF reached it.
    assert!(
        bob.wait_for("session closed", Duration::from_secs(5)),
        "baresip: {}",
        bob.text()
    );
    let bob_log = bob.text();
    for key in ['1', '#', '9'] {
        assert!(
            bob_log.contains(&format!("received event: '{key}' (end=1)")),
            "DTMF {key} did not reach baresip: {bob_log}"
        );
    }

    // What we heard is baresip's speech, as good as G.711 carries it.
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    let (snr, g711) = median_snr(&sent, &got);
    eprintln!("SNR {snr:.2} dB; a G.711 round trip of the same WAV: {g711:.2} dB");
    assert!(
        snr >= g711 - 1.0,
        "SNR {snr:.2} dB against G.711's {g711:.2} dB"
    );
    // Baresip heard ours.
    let (_, ours_sent) = common::read_wav_i16(&ours);
    let (_, bob_got) = common::read_wav_i16(&baresip_heard(dir.path()));
    let (_, corr) = best_alignment(&ours_sent, &bob_got, 8000, 8000, 4000);
    assert!(corr > 0.95, "baresip did not hear our speech: {corr:.3}");

    // The weights move with the speech: some viseme follows the loudness of what we heard.
    let csv = std::fs::read_to_string(&weights).unwrap();
    let moving = weights_following_speech(&csv, &got);
    assert!(
        moving > 0.5,
        "no viseme weight follows the speech (best |r| {moving:.2})"
    );
}

#[test]
fn baresip_calls_lipcall_which_answers_until_baresip_hangs_up() {
    if !have(&["baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (lipcall_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let heard = dir.path().join("lipcall-heard.wav");
    let ours = common::demo_8k(dir.path());
    let answer = lipcall_answering(dir.path(), lipcall_port, "30", &heard);
    let bob_speech = reversed_8k(dir.path());
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &bob_speech,
    );
    tell_baresip(
        control,
        "dial",
        &format!("sip:lipcall@127.0.0.1:{lipcall_port}"),
    );
    assert!(
        answer.wait_for("in a SIP call", Duration::from_secs(10)),
        "lipcall did not answer: {}\nbaresip: {}",
        answer.text(),
        bob.text()
    );
    std::thread::sleep(Duration::from_secs(4));
    tell_baresip(control, "hangup", "");
    // lipcall ends on baresip's BYE, well before its 30 s.
    let mut answer = answer;
    let mut child = answer.peer.child.take().unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(8);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "lipcall did not end: {}",
            answer.text()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    std::thread::sleep(Duration::from_millis(200));
    let log = answer.text();
    assert!(status.success(), "{log}");
    assert!(log.contains("the peer hung up"), "{log}");

    // Both directions heard.
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    assert!(
        got.len() > 3 * 8000,
        "lipcall heard {} samples: {log}",
        got.len()
    );
    let (lag, corr) = best_alignment(&sent, &got, 8000, 8000, 1600);
    assert!(
        corr > 0.95,
        "lipcall did not hear baresip: {corr:.3} at lag {lag}"
    );
    let (_, ours_sent) = common::read_wav_i16(&ours);
    let (_, bob_got) = common::read_wav_i16(&baresip_heard(dir.path()));
    let (_, corr) = best_alignment(&ours_sent, &bob_got, 8000, 8000, 4000);
    assert!(corr > 0.95, "baresip did not hear lipcall: {corr:.3}");
}

#[test]
fn a_wrong_password_is_refused_clearly() {
    if !have(&["kamailio"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let port = free_port(false);
    let _kamailio = kamailio(dir.path(), port, "");
    let started = std::time::Instant::now();
    let out = common::lipcall()
        .args(["sip", "call", &format!("sip:bob@127.0.0.1:{port}")])
        .arg("--play")
        .arg(common::demo_8k(dir.path()))
        .args(["--account", &format!("sip:alice@127.0.0.1:{port}")])
        .env("LIPCALL_SIP_PASSWORD", "not-the-password")
        .args(["--seconds", "20"])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(
        log.contains("refused our credentials: wrong user name or password"),
        "{log}"
    );
    assert!(!log.contains("not-the-password"), "{log}");
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn sip_answer_registers_with_sha256_refreshes_and_is_reached_through_kamailio() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (kam_port, lipcall_port) = (free_port(false), free_port(false));
    let (bob_port, control) = (free_port(false), free_port(false));
    // SHA-256 digests, and bindings of 20 s: only a refresh keeps lipcall reachable past them.
    let _kamailio = kamailio(
        dir.path(),
        kam_port,
        "modparam(\"auth\", \"algorithm\", \"SHA-256\")\n\
         modparam(\"registrar\", \"max_expires\", 20)\n\
         modparam(\"registrar\", \"min_expires\", 20)",
    );
    let heard = dir.path().join("lipcall-heard.wav");
    let answer = Peer::spawn_logged(
        "lipcall sip answer",
        common::lipcall()
            .args([
                "sip",
                "answer",
                "--listen",
                &format!("127.0.0.1:{lipcall_port}"),
            ])
            .arg("--play")
            .arg(common::demo_8k(dir.path()))
            .args(["--account", &format!("sip:alice@127.0.0.1:{kam_port}")])
            .env("LIPCALL_SIP_PASSWORD", PASSWORD)
            .args(["--seconds", "60"])
            .arg("--wav")
            .arg(&heard),
    );
    assert!(
        answer.wait_for("registered with", Duration::from_secs(10)),
        "{}",
        answer.text()
    );
    std::thread::sleep(Duration::from_secs(23));
    let bob_speech = reversed_8k(dir.path());
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &bob_speech,
    );
    tell_baresip(control, "dial", &format!("sip:alice@127.0.0.1:{kam_port}"));
    assert!(
        answer.wait_for("in a SIP call", Duration::from_secs(10)),
        "lipcall was not reached through kamailio: {}\nbaresip: {}",
        answer.text(),
        bob.text()
    );
    std::thread::sleep(Duration::from_secs(3));
    tell_baresip(control, "hangup", "");
    assert!(
        answer.wait_for("the peer hung up", Duration::from_secs(8)),
        "{}",
        answer.text()
    );
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    let (_, corr) = best_alignment(&sent, &got, 8000, 8000, 1600);
    assert!(corr > 0.95, "lipcall did not hear baresip: {corr:.3}");
}

#[test]
fn a_call_cancelled_before_the_answer_stops_baresip_ringing_through_kamailio() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let kam_port = free_port(false);
    let _kamailio = kamailio(dir.path(), kam_port, "");
    let bob = bob_registered(dir.path(), kam_port, "manual", &reversed_8k(dir.path()));
    let started = std::time::Instant::now();
    let out = common::lipcall()
        .args(["sip", "call", &format!("sip:bob@127.0.0.1:{kam_port}")])
        .arg("--play")
        .arg(common::demo_8k(dir.path()))
        .args(["--account", &format!("sip:alice@127.0.0.1:{kam_port}")])
        .env("LIPCALL_SIP_PASSWORD", PASSWORD)
        .args(["--seconds", "3"])
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{log}");
    assert!(log.contains("is ringing"), "{log}");
    assert!(
        log.contains("no answer within 3 s; the call was cancelled"),
        "{log}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "{:?}: {log}",
        started.elapsed()
    );
    // kamailio matched our CANCEL to the INVITE and passed it on: baresip stopped ringing.
    assert!(
        bob.wait_for("session closed", Duration::from_secs(3)),
        "baresip still rings: {}",
        bob.text()
    );
}

#[test]
fn a_proxy_that_challenges_the_invite_gets_its_answer() {
    if !have(&["kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let kam_port = free_port(false);
    // Calls from our domain must answer a 407 first.
    let challenge = format!(
        "if (is_method(\"INVITE\") && !pv_proxy_authenticate(\"$fd\", \"{PASSWORD}\", \"0\")) {{ proxy_challenge(\"$fd\", \"0\"); exit; }}"
    );
    let kamailio = kamailio_with(dir.path(), kam_port, "", &challenge);
    let bob = bob_registered(dir.path(), kam_port, "auto", &reversed_8k(dir.path()));
    let call = |password: &str| {
        common::lipcall()
            .args(["sip", "call", &format!("sip:bob@127.0.0.1:{kam_port}")])
            .arg("--play")
            .arg(common::demo_8k(dir.path()))
            .args(["--account", &format!("sip:alice@127.0.0.1:{kam_port}")])
            .env("LIPCALL_SIP_PASSWORD", password)
            .args(["--seconds", "3"])
            .output()
            .unwrap()
    };
    let out = call(PASSWORD);
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{log}\nkamailio: {}", kamailio.text());
    assert!(log.contains("in a SIP call"), "{log}");
    assert!(
        bob.wait_for("session closed", Duration::from_secs(5)),
        "{}",
        bob.text()
    );
}

#[test]
fn srtp_keyed_by_sdes_with_baresip_both_ways() {
    if !have(&["baresip", "sox"]) {
        return;
    }
    // lipcall calls a baresip that insists on SRTP.
    let dir = tempfile::tempdir().unwrap();
    let (bob_port, control) = (free_port(false), free_port(false));
    let bob_speech = reversed_8k(dir.path());
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;answermode=auto;audio_codecs=PCMU;mediaenc=srtp-mand",
        &bob_speech,
    );
    let heard = dir.path().join("lipcall-heard.wav");
    let out = common::lipcall()
        .args([
            "sip",
            "call",
            &format!("sip:bob@127.0.0.1:{bob_port}"),
            "--srtp",
        ])
        .arg("--play")
        .arg(common::demo_8k(dir.path()))
        .args(["--codec", "pcmu", "--seconds", "5"])
        .arg("--wav")
        .arg(&heard)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{log}\nbaresip: {}", bob.text());
    assert!(log.contains("SRTP (keys exchanged in SDP)"), "{log}");
    assert!(log.contains("auth_failed=0"), "{log}");
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    let (_, corr) = best_alignment(&sent, &got, 8000, 8000, 1600);
    assert!(
        corr > 0.95,
        "lipcall did not hear baresip over SRTP: {corr:.3}"
    );
    let (_, ours) = common::read_wav_i16(&common::demo_8k(dir.path()));
    let (_, bob_got) = common::read_wav_i16(&baresip_heard(dir.path()));
    let (_, corr) = best_alignment(&ours, &bob_got, 8000, 8000, 4000);
    assert!(
        corr > 0.95,
        "baresip did not hear lipcall over SRTP: {corr:.3}"
    );
    drop(bob);

    // A baresip that insists on SRTP calls `sip answer`, which takes the offer.
    let dir = tempfile::tempdir().unwrap();
    let (lipcall_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let heard = dir.path().join("lipcall-heard.wav");
    let answer = lipcall_answering(dir.path(), lipcall_port, "6", &heard);
    let bob_speech = reversed_8k(dir.path());
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU;mediaenc=srtp-mand",
        &bob_speech,
    );
    tell_baresip(
        control,
        "dial",
        &format!("sip:lipcall@127.0.0.1:{lipcall_port}"),
    );
    assert!(
        answer.wait_for("played", Duration::from_secs(15)),
        "{}\nbaresip: {}",
        answer.text(),
        bob.text()
    );
    std::thread::sleep(Duration::from_millis(300));
    let log = answer.text();
    assert!(log.contains("SRTP (keys exchanged in SDP)"), "{log}");
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    let (_, corr) = best_alignment(&sent, &got, 8000, 8000, 1600);
    assert!(
        corr > 0.95,
        "sip answer did not hear baresip over SRTP: {corr:.3}: {log}"
    );
}

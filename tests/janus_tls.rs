//! Janus as deployments on the internet run it: its API over HTTPS with a certificate (here a
//! self-signed one the test makes with openssl and hands to lipcall as the system's store
//! does, through SSL_CERT_FILE) and an `api_secret`. Each test runs in a network namespace of
//! its own (tests/common/netns.rs).

mod common;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use common::janus::{IN_ROOM, envelope, envelope_correlation, free_tcp_port, start_janus_edited};
use common::net::{finish, spawn, spawn_listening};
use common::{lipcall, repo_file};

const SECRET: &str = "s3cret janus";

/// A self-signed certificate for 127.0.0.1: (certificate, key).
fn self_signed(dir: &Path) -> (String, String) {
    let cert = dir.join("janus-cert.pem");
    let key = dir.join("janus-key.pem");
    let status = Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
        ])
        .args([
            "-subj",
            "/CN=127.0.0.1",
            "-addext",
            "subjectAltName=IP:127.0.0.1",
        ])
        .arg("-keyout")
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .output()
        .expect("openssl (Debian package openssl)");
    assert!(status.status.success(), "{status:?}");
    (
        cert.to_string_lossy().into_owned(),
        key.to_string_lossy().into_owned(),
    )
}

fn janus_https_with_secret(dir: &Path, cert: &str, key: &str) -> common::janus::Janus {
    start_janus_edited(dir, "https", |name, text| match name {
        "janus.transport.http.jcfg" => format!(
            "general: {{\n\tjson = \"compact\"\n\tbase_path = \"/janus\"\n\thttp = false\n\t\
             https = true\n\tsecure_ip = \"127.0.0.1\"\n\tsecure_port = PORT\n}}\n\
             admin: {{\n\tadmin_http = false\n\tadmin_https = false\n}}\n\
             certificates: {{\n\tcert_pem = \"{cert}\"\n\tcert_key = \"{key}\"\n}}\n"
        ),
        "janus.jcfg" => text.replace(
            "\tserver_name = \"lipcall-janus\"",
            &format!("\tserver_name = \"lipcall-janus\"\n\tapi_secret = \"{SECRET}\""),
        ),
        _ => text,
    })
}

/// Janus with its WebSocket transport over TLS (wss) and an api_secret: the Janus and its
/// `wss://127.0.0.1:PORT` URL.
fn janus_wss_with_secret(dir: &Path, cert: &str, key: &str) -> (common::janus::Janus, String) {
    let config = dir.join("janus-config");
    std::fs::create_dir_all(&config).unwrap();
    let port = free_tcp_port();
    std::fs::write(
        config.join("janus.transport.websockets.jcfg"),
        format!(
            "general: {{\n\tjson = \"compact\"\n\tws = false\n\twss = true\n\t\
             wss_ip = \"127.0.0.1\"\n\twss_port = {port}\n}}\n\
             admin: {{\n\tadmin_ws = false\n\tadmin_wss = false\n}}\n\
             certificates: {{\n\tcert_pem = \"{cert}\"\n\tcert_key = \"{key}\"\n}}\n"
        ),
    )
    .unwrap();
    let janus = start_janus_edited(dir, "http", |name, text| match name {
        "janus.jcfg" => text
            .replace(
                "\tserver_name = \"lipcall-janus\"",
                &format!("\tserver_name = \"lipcall-janus\"\n\tapi_secret = \"{SECRET}\""),
            )
            .replace(",libjanus_websockets.so", ""),
        _ => text,
    });
    let deadline = Instant::now() + Duration::from_secs(15);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            Instant::now() < deadline,
            "Janus did not open its WebSocket port"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    (janus, format!("wss://127.0.0.1:{port}"))
}

/// `send` and `receive` meet in `room` at `url`, with the secret: how well the speech is heard.
fn call_through(dir: &Path, url: &str, cert: &str, room: &str) -> f64 {
    let speech = repo_file("assets/speech/demo.wav");
    let wav = dir.join(format!("{room}.wav"));
    let receiver = spawn_listening(
        lipcall()
            .env("SSL_CERT_FILE", cert)
            .args(["receive", "--janus", url, "--room", room])
            .env("LIPCALL_JANUS_SECRET", SECRET)
            .args(["--name", "Bob", "--seconds", "13"])
            .arg("--wav")
            .arg(&wav),
        IN_ROOM,
    );
    let secret = dir.join(format!("{room}.secret"));
    std::fs::write(&secret, format!("{SECRET}\n")).unwrap();
    let sender = spawn(
        lipcall()
            .env("SSL_CERT_FILE", cert)
            .arg("send")
            .arg(&speech)
            .args(["--janus", url, "--room", room])
            .arg("--janus-secret-file")
            .arg(&secret)
            .args(["--name", "Ann"]),
    );
    let (_, sent) = finish(sender, Duration::from_secs(30), "lipcall send --janus");
    let (_, received) = receiver.finish(Duration::from_secs(30), "lipcall receive --janus");
    let r = envelope_correlation(&envelope(&speech), &envelope(&wav));
    eprintln!("{url}: level contour r {r:.3}\nsender: {sent}\nreceiver: {received}");
    assert!(received.contains("left"), "{received}");
    r
}

/// Without the secret, Janus's refusal is said at once and the receive exits 1.
fn refused_without_the_secret(url: &str, cert: &str, room: &str) {
    let out = lipcall()
        .env("SSL_CERT_FILE", cert)
        .args(["receive", "--janus", url, "--room", room, "--seconds", "2"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("Janus error 403"), "{stderr}");
}

#[test]
fn a_janus_over_wss_with_an_api_secret_carries_a_call() {
    if !common::janus::runs_here("a_janus_over_wss_with_an_api_secret_carries_a_call") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (cert, key) = self_signed(dir.path());
    let (_janus, url) = janus_wss_with_secret(dir.path(), &cert, &key);
    let r = call_through(dir.path(), &url, &cert, "over-wss");
    assert!(r > 0.9, "heard over WSS: r {r:.3}");

    refused_without_the_secret(&url, &cert, "over-wss");
}

#[test]
fn a_janus_over_https_with_an_api_secret_carries_a_call() {
    if !common::janus::runs_here("a_janus_over_https_with_an_api_secret_carries_a_call") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (cert, key) = self_signed(dir.path());
    let janus = janus_https_with_secret(dir.path(), &cert, &key);
    let r = call_through(dir.path(), &janus.url, &cert, "secure");
    assert!(r > 0.9, "heard over HTTPS: r {r:.3}");

    refused_without_the_secret(&janus.url, &cert, "secure");

    // A certificate nobody vouches for: refused, with TLS's reason.
    let out = lipcall()
        .env("SSL_CERT_FILE", "/nonexistent")
        .env("SSL_CERT_DIR", "/nonexistent")
        .args([
            "receive",
            "--janus",
            &janus.url,
            "--room",
            "secure",
            "--seconds",
            "2",
        ])
        .env("LIPCALL_JANUS_SECRET", SECRET)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("cannot reach Janus") && stderr.contains("certificate"),
        "{stderr}"
    );
}

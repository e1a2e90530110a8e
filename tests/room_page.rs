//! tools/room_page.py over HTTPS: browsers open the microphone only on localhost or over
//! HTTPS, so a link sent to someone else needs a certificate. With --self-signed it makes one
//! and warns; the page then comes over TLS checked against that certificate.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::repo_file;

struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The page fetched by Python's urllib, trusting only `cafile`: (status, body) or the error.
fn fetch(url: &str, cafile: &str) -> String {
    let out = Command::new("python3")
        .args([
            "-c",
            "import ssl, sys, urllib.request\n\
             ctx = ssl.create_default_context(cafile=sys.argv[2])\n\
             try:\n    print(urllib.request.urlopen(sys.argv[1], context=ctx, timeout=10).read().decode())\n\
             except Exception as e:\n    print('FAILED', e)",
            url,
            cafile,
        ])
        .output()
        .expect("python3");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_room_page_is_served_over_https_with_a_self_signed_certificate_and_a_warning() {
    let child = Command::new("python3")
        .arg(repo_file("tools/room_page.py"))
        .args(["--bind", "127.0.0.1", "--port", "0", "--self-signed"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn();
    let Ok(mut child) = child else {
        common::unavailable("no python3 for tools/room_page.py");
        return;
    };
    let stderr = child.stderr.take().unwrap();
    let server = Server(child);
    let mut lines = BufReader::new(stderr).lines();
    let (mut port, mut cert, mut page) = (None, None, None);
    let deadline = Instant::now() + Duration::from_secs(30);
    while page.is_none() && Instant::now() < deadline {
        let Some(Ok(line)) = lines.next() else { break };
        if let Some(p) = line.strip_prefix("lipcall: listening on 127.0.0.1:") {
            port = p.trim().parse::<u16>().ok();
        }
        if let Some(rest) = line.strip_prefix("room_page: WARNING: a self-signed certificate (") {
            cert = rest.split(')').next().map(str::to_string);
            assert!(line.contains("every browser will warn"), "{line}");
        }
        if let Some(url) = line.strip_prefix("room page: ") {
            page = Some(url.to_string());
        }
    }
    let (port, cert, page) = (port.unwrap(), cert.unwrap(), page.unwrap());
    assert!(
        page.starts_with(&format!("https://127.0.0.1:{port}/room.html")),
        "{page}"
    );
    let body = fetch(&format!("https://127.0.0.1:{port}/room.html"), &cert);
    assert!(body.contains("room.js"), "{body}");
    // Trusting nothing else, the system's store does not vouch for it.
    let refused = fetch(
        &format!("https://127.0.0.1:{port}/room.html"),
        "/etc/ssl/certs/ca-certificates.crt",
    );
    assert!(refused.starts_with("FAILED"), "{refused}");
    drop(server);

    let out = Command::new("python3")
        .arg(repo_file("tools/room_page.py"))
        .args(["--port", "0", "--cert", "/nonexistent.pem"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--cert and --key go together"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

//! SIP over TLS (issue 45) on 127.0.0.1: certificates made with openssl in a temp dir; a bad
//! one (another authority, another name, expired) and a plain TCP service posing as TLS each
//! end `sip call` with exit 1 and a line naming the problem.

mod common;

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::sip::{Peer, free_port, have};

/// An authority (`NAME.pem`, `NAME.key`) in `dir`.
fn authority(dir: &Path, name: &str) -> PathBuf {
    let pem = dir.join(format!("{name}.pem"));
    common::run(
        Command::new("openssl")
            .args([
                "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
            ])
            .arg("-keyout")
            .arg(dir.join(format!("{name}.key")))
            .arg("-out")
            .arg(&pem)
            .args(["-subj", &format!("/CN=lipcall test {name}")]),
    );
    pem
}

/// When a server certificate is valid.
enum Validity {
    Days(u32),
    /// A day in 2020: long expired.
    Expired,
}

/// A server certificate `NAME.pem` (key `NAME.key`) for `alt_names` (`IP:…`, `DNS:…`), signed
/// by the authority `ca` of [`authority`].
fn server_certificate(
    dir: &Path,
    ca: &str,
    name: &str,
    alt_names: &str,
    validity: Validity,
) -> PathBuf {
    let key = dir.join(format!("{name}.key"));
    let csr = dir.join(format!("{name}.csr"));
    let pem = dir.join(format!("{name}.pem"));
    let extensions = dir.join(format!("{name}.ext"));
    std::fs::write(&extensions, format!("subjectAltName={alt_names}\n")).unwrap();
    common::run(
        Command::new("openssl")
            .args(["req", "-new", "-newkey", "rsa:2048", "-nodes"])
            .arg("-keyout")
            .arg(&key)
            .arg("-out")
            .arg(&csr)
            .args(["-subj", &format!("/CN={name}")]),
    );
    let ca_pem = dir.join(format!("{ca}.pem"));
    let ca_key = dir.join(format!("{ca}.key"));
    match validity {
        Validity::Days(days) => common::run(
            Command::new("openssl")
                .args(["x509", "-req", "-days", &days.to_string()])
                .arg("-in")
                .arg(&csr)
                .arg("-CA")
                .arg(&ca_pem)
                .arg("-CAkey")
                .arg(&ca_key)
                .args(["-set_serial", "7"])
                .arg("-extfile")
                .arg(&extensions)
                .arg("-out")
                .arg(&pem),
        ),
        Validity::Expired => {
            // `openssl ca` takes explicit dates; OpenSSL 3.0's x509 has only -days.
            let database = dir.join(format!("{name}.index"));
            std::fs::write(&database, "").unwrap();
            let config = dir.join(format!("{name}.cnf"));
            std::fs::write(
                &config,
                format!(
                    "[ca]\ndefault_ca=test\n[test]\ndatabase={}\nnew_certs_dir={}\n\
                     serial={}\ndefault_md=sha256\npolicy=any\n[any]\ncommonName=supplied\n",
                    database.display(),
                    dir.display(),
                    dir.join(format!("{name}.serial")).display()
                ),
            )
            .unwrap();
            std::fs::write(dir.join(format!("{name}.serial")), "11\n").unwrap();
            common::run(
                Command::new("openssl")
                    .args(["ca", "-batch", "-notext", "-config"])
                    .arg(&config)
                    .arg("-cert")
                    .arg(&ca_pem)
                    .arg("-keyfile")
                    .arg(&ca_key)
                    .args(["-startdate", "20200101000000Z"])
                    .args(["-enddate", "20200102000000Z"])
                    .arg("-extfile")
                    .arg(&extensions)
                    .arg("-in")
                    .arg(&csr)
                    .arg("-out")
                    .arg(&pem),
            )
        }
    };
    pem
}

/// `openssl s_server` on 127.0.0.1:`port` with the certificate `name` of [`server_certificate`].
fn tls_server(dir: &Path, name: &str, port: u16) -> common::sip::Logged {
    let server = Peer::spawn_logged(
        "openssl s_server",
        Command::new("openssl")
            .args(["s_server", "-accept", &format!("127.0.0.1:{port}")])
            .arg("-cert")
            .arg(dir.join(format!("{name}.pem")))
            .arg("-key")
            .arg(dir.join(format!("{name}.key"))),
    );
    assert!(
        server.wait_for("ACCEPT", Duration::from_secs(10)),
        "s_server did not start: {}",
        server.text()
    );
    server
}

/// `sip call` over TLS to 127.0.0.1:`port` trusting `ca`: its exit status and log.
fn call_over_tls(dir: &Path, port: u16, ca: &Path) -> (Option<i32>, String) {
    let out = common::lipcall()
        .args([
            "sip",
            "call",
            &format!("sip:bob@127.0.0.1:{port};transport=tls"),
        ])
        .arg("--play")
        .arg(common::demo_8k(dir))
        .args(["--seconds", "8"])
        .arg("--ca")
        .arg(ca)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The error line of a failed `sip call`.
fn error_line(log: &str) -> &str {
    log.lines()
        .find(|l| l.contains("error") || l.contains("cannot connect"))
        .unwrap_or(log)
}

#[test]
fn bad_certificates_and_a_plain_tcp_peer_are_named_and_exit_1() {
    if !have(&["openssl", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ca = authority(d, "ca");
    authority(d, "other-ca");
    server_certificate(d, "other-ca", "stranger", "IP:127.0.0.1", Validity::Days(2));
    server_certificate(d, "ca", "misnamed", "DNS:other.example", Validity::Days(2));
    server_certificate(d, "ca", "expired", "IP:127.0.0.1", Validity::Expired);
    server_certificate(d, "ca", "good", "IP:127.0.0.1", Validity::Days(2));

    let cases = [
        ("stranger", "not signed by an authority we trust"),
        ("misnamed", "its certificate is not for 127.0.0.1"),
        ("expired", "its certificate has expired"),
    ];
    for (name, expected) in cases {
        let port = free_port(false);
        let _server = tls_server(d, name, port);
        let (code, log) = call_over_tls(d, port, &ca);
        assert_eq!(code, Some(1), "{name}: {log}");
        let line = error_line(&log);
        eprintln!("{name}: {line}");
        assert!(
            line.contains(expected) && line.contains(&format!("TLS to 127.0.0.1:{port}")),
            "{name}: {line}"
        );
    }

    // A plain TCP service (a SIP server without TLS) on the port.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    std::thread::spawn(move || {
        for stream in listener.incoming().take(2) {
            let Ok(mut stream) = stream else { continue };
            let mut buf = [0u8; 2048];
            let _ = stream.read(&mut buf);
            let _ = stream.write_all(b"SIP/2.0 400 Bad Request\r\nContent-Length: 0\r\n\r\n");
        }
    });
    let (code, log) = call_over_tls(d, port, &ca);
    assert_eq!(code, Some(1), "{log}");
    assert!(
        error_line(&log).contains("does not speak TLS"),
        "{}",
        error_line(&log)
    );

    // The good certificate gets past TLS: the call fails later, for want of a SIP server.
    let port = free_port(false);
    let _server = tls_server(d, "good", port);
    let (_, log) = call_over_tls(d, port, &ca);
    assert!(!log.contains("cannot connect over TLS"), "{log}");
    assert!(log.contains("(TLS)"), "{log}");
}

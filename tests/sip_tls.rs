//! SIP over TLS (issue 45) on 127.0.0.1: certificates made with openssl in a temp dir; a bad
//! one (another authority, another name, expired) and a plain TCP service posing as TLS each
//! end `sip call` with exit 1 and a line naming the problem; a call through a kamailio that
//! speaks only TLS to a baresip that demands SRTP; `sip answer --srtp` refusing plain RTP.

mod common;

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::sip::{
    PASSWORD, Peer, baresip, baresip_heard, baresip_with, best_alignment, exit_of, free_port, have,
    lipcall_answering_with, median_snr, reversed_8k, tell_baresip,
};

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
    assert!(log.contains("over TLS"), "{log}");
}

/// kamailio listening on TLS only (`cert` for 127.0.0.1) as registrar (digest for
/// [`PASSWORD`]) and proxy: record-routed, and reaching each client over the connection it
/// registered on (nathelper's aliases), as a provider runs it.
fn kamailio_tls(dir: &Path, port: u16, cert: &str) -> common::sip::Logged {
    let tls_cfg = dir.join("tls.cfg");
    std::fs::write(
        &tls_cfg,
        format!(
            "[server:default]\nmethod = TLSv1.2+\nverify_certificate = no\n\
             require_certificate = no\nprivate_key = {key}\ncertificate = {pem}\n\n\
             [client:default]\nmethod = TLSv1.2+\nverify_certificate = no\n\
             require_certificate = no\n",
            key = dir.join(format!("{cert}.key")).display(),
            pem = dir.join(format!("{cert}.pem")).display(),
        ),
    )
    .unwrap();
    let modules = [
        "tls",
        "tm",
        "sl",
        "rr",
        "pv",
        "maxfwd",
        "usrloc",
        "registrar",
        "textops",
        "siputils",
        "nathelper",
        "auth",
    ];
    let loads: String = modules
        .iter()
        .map(|m| format!("loadmodule \"{m}.so\"\n"))
        .collect();
    let config = format!(
        r#"#!KAMAILIO
debug=2
log_stderror=yes
children=2
tcp_children=2
enable_tls=yes
auto_aliases=no
listen=tls:127.0.0.1:{port}
alias="127.0.0.1:{port}"
mpath="{modules}"
{loads}modparam("tls", "config", "{tls}")
modparam("usrloc", "db_mode", 0)
modparam("nathelper", "received_avp", "$avp(RECEIVED)")
modparam("registrar", "received_avp", "$avp(RECEIVED)")

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
        if (is_method("ACK") && !t_check_trans() && !loose_route()) {{
            exit;
        }}
        loose_route();
        handle_ruri_alias();
        t_on_reply("ALIAS");
        t_relay();
        exit;
    }}
    if (is_method("REGISTER")) {{
        if (!pv_www_authenticate("$td", "{PASSWORD}", "0")) {{
            www_challenge("$td", "0");
            exit;
        }}
        fix_nated_register();
        save("location");
        exit;
    }}
    record_route();
    add_contact_alias();
    if (!lookup("location")) {{
        sl_send_reply("404", "Not Found");
        exit;
    }}
    t_on_reply("ALIAS");
    t_relay();
}}

onreply_route[ALIAS] {{
    if (status =~ "^[12][0-9][0-9]$" && is_present_hf("Contact")) {{
        add_contact_alias();
    }}
}}
"#,
        modules = common::sip::kamailio_modules(),
        tls = tls_cfg.display(),
    );
    let path = dir.join("kamailio.cfg");
    std::fs::write(&path, config).unwrap();
    let kamailio = Peer::spawn_logged(
        "kamailio",
        Command::new("kamailio")
            .arg("-f")
            .arg(&path)
            .args(["-DD", "-E", "-m", "64", "-M", "16", "-Y"])
            .arg(dir),
    );
    assert!(
        kamailio.wait_for("tls", Duration::from_secs(10))
            && wait_listening(port, Duration::from_secs(10)),
        "kamailio did not start: {}",
        kamailio.text()
    );
    kamailio
}

/// baresip as bob registered over TLS at the kamailio on `kam_port` (trusting `ca`), SRTP
/// mandatory, answering at once, its microphone `source`: returned once registered.
fn tls_bob(
    d: &Path,
    port: u16,
    control: u16,
    kam_port: u16,
    ca: &Path,
    source: &Path,
    kamailio: &common::sip::Logged,
) -> common::sip::Logged {
    let bob = baresip_with(
        d,
        port,
        control,
        &format!(
            "<sip:bob@127.0.0.1:{kam_port};transport=tls>;auth_pass={PASSWORD};answermode=auto;\
             regint=60;audio_codecs=PCMU;mediaenc=srtp-mand"
        ),
        source,
        &format!("sip_cafile {}\n", ca.display()),
    );
    assert!(
        bob.wait_for("200 OK", Duration::from_secs(10)),
        "baresip did not register over TLS: {}\nkamailio: {}",
        bob.text(),
        kamailio.text()
    );
    bob
}

/// Waits until something accepts TCP connections on 127.0.0.1:`port`.
fn wait_listening(port: u16, limit: Duration) -> bool {
    let deadline = std::time::Instant::now() + limit;
    while std::time::Instant::now() < deadline {
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    false
}

#[test]
fn lipcall_registers_over_tls_and_calls_baresip_with_mandatory_srtp() {
    if !have(&["openssl", "kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ca = authority(d, "ca");
    server_certificate(d, "ca", "kamailio", "IP:127.0.0.1", Validity::Days(2));
    let (kam_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let kamailio = kamailio_tls(d, kam_port, "kamailio");
    let bob_speech = reversed_8k(d);
    let bob = tls_bob(d, bob_port, control, kam_port, &ca, &bob_speech, &kamailio);
    let heard = d.join("lipcall-heard.wav");
    let ours = common::demo_8k(d);
    let out = common::lipcall()
        .args([
            "sip",
            "call",
            &format!("sip:bob@127.0.0.1:{kam_port};transport=tls"),
        ])
        .args([
            "--account",
            &format!("sip:alice@127.0.0.1:{kam_port};transport=tls"),
        ])
        .arg("--ca")
        .arg(&ca)
        .env("LIPCALL_SIP_PASSWORD", PASSWORD)
        .arg("--play")
        .arg(&ours)
        .args(["--codec", "pcmu", "--seconds", "6"])
        .arg("--wav")
        .arg(&heard)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.success(),
        "{log}\nbaresip: {}\nkamailio: {}",
        bob.text(),
        kamailio.text()
    );
    assert!(log.contains("over TLS"), "{log}");
    assert!(
        log.contains(&format!("registered with 127.0.0.1:{kam_port}")),
        "{log}"
    );
    assert!(log.contains("SRTP (keys exchanged in SDP)"), "{log}");
    assert!(log.contains("auth_failed=0"), "{log}");
    assert!(
        !log.contains(PASSWORD),
        "the password is never shown: {log}"
    );

    // What we heard is baresip's speech, as good as G.711 carries it.
    let (_, sent) = common::read_wav_i16(&bob_speech);
    let (_, got) = common::read_wav_i16(&heard);
    let (snr, g711) = median_snr(&sent, &got);
    eprintln!(
        "over TLS and SRTP: SNR {snr:.2} dB; a G.711 round trip of the same WAV: {g711:.2} dB"
    );
    assert!(
        snr >= g711 - 1.0,
        "SNR {snr:.2} dB against G.711's {g711:.2} dB"
    );
    // Baresip heard ours.
    let (_, ours_sent) = common::read_wav_i16(&ours);
    let (_, bob_got) = common::read_wav_i16(&baresip_heard(d));
    let (_, corr) = best_alignment(&ours_sent, &bob_got, 8000, 8000, 4000);
    assert!(corr > 0.95, "baresip did not hear our speech: {corr:.3}");
}

#[test]
fn sip_answer_with_srtp_required_refuses_a_plain_offer_with_488() {
    if !have(&["baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (lipcall_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let heard = d.join("lipcall-heard.wav");
    let answer = lipcall_answering_with(d, lipcall_port, "15", &heard, &["--srtp"]);
    let bob = baresip(
        d,
        bob_port,
        control,
        "<sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &reversed_8k(d),
    );
    tell_baresip(
        control,
        "dial",
        &format!("sip:lipcall@127.0.0.1:{lipcall_port}"),
    );
    let (code, log) = exit_of(answer, Duration::from_secs(20));
    assert_eq!(code, Some(1), "{log}");
    assert!(log.contains("offered plain RTP"), "{log}");
    assert!(
        bob.wait_for("488 Not Acceptable Here", Duration::from_secs(5)),
        "baresip: {}",
        bob.text()
    );
}

#[test]
fn the_app_registers_over_tls_and_calls_baresip_with_mandatory_srtp() {
    use lipcall::app::engine::{CallSpec, Command, Encryption, lock};
    use lipcall::app::sip_call::{PhoneCommand, PhoneNetwork};
    use lipcall::net::sip::agent::Account;

    if !have(&["openssl", "kamailio", "baresip", "sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ca = authority(d, "ca");
    server_certificate(d, "ca", "kamailio", "IP:127.0.0.1", Validity::Days(2));
    let (kam_port, bob_port, control) = (free_port(false), free_port(false), free_port(false));
    let kamailio = kamailio_tls(d, kam_port, "kamailio");
    let bob = tls_bob(
        d,
        bob_port,
        control,
        kam_port,
        &ca,
        &reversed_8k(d),
        &kamailio,
    );
    let engine = common::app::headless_engine("Alice", None);
    engine.send(Command::Phone(PhoneCommand::Network(PhoneNetwork {
        ca: Some(std::fs::read(&ca).unwrap()),
        ..PhoneNetwork::default()
    })));
    let account = Account::parse(
        &format!("sip:alice@127.0.0.1:{kam_port};transport=tls"),
        PASSWORD,
    )
    .unwrap();
    engine.send(Command::Phone(PhoneCommand::Account(Some(account))));
    let wait = |what: &str, done: &dyn Fn(&lipcall::app::engine::Shared) -> bool| {
        let deadline = std::time::Instant::now() + Duration::from_secs(20);
        loop {
            {
                let s = lock(&engine.shared);
                if done(&s) {
                    return;
                }
                assert!(
                    std::time::Instant::now() < deadline,
                    "{what}: call {:?}, phone {:?}\nbaresip: {}\nkamailio: {}",
                    s.call,
                    s.phone,
                    bob.text(),
                    kamailio.text()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    wait("registered over TLS", &|s| {
        s.phone.registration.starts_with("registered with")
    });
    engine.send(Command::Call(Box::new(CallSpec {
        address: format!("sip:bob@127.0.0.1:{kam_port};transport=tls"),
        name: "Alice".into(),
        ..CallSpec::default()
    })));
    wait("bob is heard over SRTP", &|s| {
        s.call.encryption == Encryption::HopByHop
            && s.peers
                .views()
                .iter()
                .any(|p| p.name.contains("bob") && p.frames_received > 50 && p.frames_animated > 50)
    });
    engine.send(Command::Leave);
    assert!(
        bob.wait_for("session closed", Duration::from_secs(10)),
        "baresip: {}",
        bob.text()
    );
}

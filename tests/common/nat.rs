//! coturn (Debian's `coturn`) as the STUN and TURN server of the NAT tests, and the address
//! their media meets on.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// coturn as a plain STUN server on a free loopback port, killed when dropped.
pub struct Coturn {
    child: Child,
    pub addr: std::net::SocketAddr,
}

impl Drop for Coturn {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// coturn on `ip`: a STUN server only, or with `turn_user` (NAME:PASSWORD) a TURN server
/// too, relaying from `ip`.
pub fn start_coturn(dir: &Path, ip: &str, turn_user: Option<&str>) -> Option<Coturn> {
    let port = std::net::UdpSocket::bind((ip, 0))
        .and_then(|s| s.local_addr())
        .map(|a| a.port())
        .unwrap();
    let mut command = Command::new("turnserver");
    command.args(["-n", "--verbose", "--no-cli", "--no-tls", "--no-dtls"]);
    match turn_user {
        None => command.arg("--stun-only"),
        Some(user) => command
            .args(["--lt-cred-mech", "--realm", "lipcall.test", "--user", user])
            .args(["--relay-ip", ip]),
    };
    let child = command
        .args(["--listening-ip", ip, "--listening-port"])
        .arg(port.to_string())
        .arg("--pidfile")
        .arg(dir.join("turnserver.pid"))
        .arg("--log-file")
        .arg(dir.join("turnserver.log"))
        .arg("--simple-log")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn();
    let Ok(child) = child else {
        super::unavailable("no `turnserver` (Debian package coturn)");
        return None;
    };
    let coturn = Coturn {
        child,
        addr: std::net::SocketAddr::new(ip.parse().unwrap(), port),
    };
    // Ready once it answers.
    let probe = std::net::UdpSocket::bind((ip, 0)).unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let asked =
            lipcall::net::stun::reflexive_address(&probe, coturn.addr, Duration::from_millis(300));
        if asked == Ok(probe.local_addr().unwrap()) {
            return Some(coturn);
        }
        assert!(
            Instant::now() < deadline,
            "coturn never answered: {asked:?}"
        );
    }
}

/// The address the media meets on: the namespace's own, or outside one this machine's.
pub fn media_ip() -> String {
    if std::env::var(super::netns::ENV).is_ok_and(|v| v != "off") {
        return super::netns::MEDIA_ADDRESS.to_string();
    }
    let probe = std::net::UdpSocket::bind("0.0.0.0:0").unwrap();
    probe.connect("192.0.2.1:9").unwrap();
    probe.local_addr().unwrap().ip().to_string()
}

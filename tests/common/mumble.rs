//! A private murmurd (Debian's `mumble-server`) for the Mumble tests: its own ini and database
//! in a temp dir, on a free loopback port, killed at the end.

use std::net::{TcpListener, TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Whether murmurd can be run here.
pub fn murmurd_installed() -> bool {
    Command::new("murmurd")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok()
}

/// Whether the Mumble tests can run here (else says why: a failure under CI).
pub fn runs_here(test: &str) -> bool {
    if murmurd_installed() {
        return true;
    }
    super::unavailable(&format!(
        "{test}: murmurd (Debian's mumble-server) is not installed"
    ));
    false
}

/// A loopback port free for both TCP and UDP (murmurd listens on both).
fn free_port() -> u16 {
    loop {
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("a free loopback port");
        if UdpSocket::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

pub struct Murmur {
    child: Option<Child>,
    pub port: u16,
    ini: PathBuf,
}

impl Murmur {
    /// Starts murmurd in `dir` with `extra` ini lines (a password, a user limit, ...).
    pub fn start(dir: &Path, extra: &str) -> Self {
        let state = dir.join("murmur");
        std::fs::create_dir_all(&state).unwrap();
        // Started as root, murmurd runs as the mumble-server user: it must reach its folder.
        for d in [dir, state.as_path()] {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o777)).unwrap();
        }
        let port = free_port();
        let ini = state.join("murmur.ini");
        std::fs::write(
            &ini,
            format!(
                "database={db}\nhost=127.0.0.1\nport={port}\nlogfile={log}\nwelcometext=lipcall test\n\
                 bandwidth=72000\n{extra}\n",
                db = state.join("murmur.sqlite").display(),
                log = state.join("murmur.log").display(),
            ),
        )
        .unwrap();
        let mut murmur = Self {
            child: None,
            port,
            ini,
        };
        murmur.launch();
        murmur
    }

    /// Starts the stopped server again (same database and certificate, same port), once it
    /// listens and has its certificate.
    pub fn launch(&mut self) {
        let child = Command::new("murmurd")
            .arg("-fg")
            .arg("-ini")
            .arg(&self.ini)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("murmurd");
        self.child = Some(child);
        let deadline = Instant::now() + Duration::from_secs(20);
        while TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "murmurd did not listen on {}",
                self.port
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        // The certificate is made at the first start, after the port is open.
        std::thread::sleep(Duration::from_millis(500));
    }

    /// Adds channels under Root (ids 1, 2, ... in order) to the server's database and
    /// restarts it: murmurd makes none from its ini, and unregistered users may not.
    pub fn add_channels(&mut self, names: &[&str]) {
        self.stop();
        let db = self.ini.with_file_name("murmur.sqlite");
        let rows: Vec<String> = names
            .iter()
            .enumerate()
            .map(|(i, n)| format!("(1, {}, 0, '{n}', 1)", i + 1))
            .collect();
        let script = format!(
            "import sqlite3, sys\nc = sqlite3.connect(sys.argv[1])\n\
             c.execute(\"insert into channels values {}\")\nc.commit()\n",
            rows.join(", ")
        );
        let status = Command::new("python3")
            .arg("-c")
            .arg(script)
            .arg(&db)
            .status()
            .expect("python3");
        assert!(status.success(), "channels not added to {}", db.display());
        self.launch();
    }

    pub fn address(&self) -> String {
        format!("127.0.0.1:{}", self.port)
    }

    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Kills and starts it again (same database and certificate, same port).
    pub fn restart(&mut self, pause: Duration) {
        self.stop();
        std::thread::sleep(pause);
        self.launch();
    }
}

impl Drop for Murmur {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A lipcall command with its own config folder (its client certificate, known servers).
pub fn lipcall_as(dir: &Path, who: &str) -> Command {
    let mut cmd = super::lipcall();
    cmd.env("XDG_CONFIG_HOME", dir.join(format!("config-{who}")));
    cmd
}

//! A network namespace for each Janus test, so that all its traffic (HTTP signalling on
//! 127.0.0.1, WebRTC media on [`MEDIA_ADDRESS`]) stays inside it, whatever interfaces the
//! machine has.
//!
//! ICE agents ignore loopback: libnice (Janus) gathers no loopback candidates, so the media
//! needs a non-loopback address. The namespace has one, on an interface that exists only
//! there (`lc0`: a dummy, or one end of a veth pair whose other end is in the namespace too),
//! and a default route through it, so that "the address towards the rest of the network"
//! (lipcall's `host_ips`, Chromium's default address) is that one too. Nothing leaves: what is
//! routed out of `lc0` goes nowhere.
//!
//! A test calls [`ran_in_own_namespace`] first. Outside a namespace it creates one, runs the
//! same test binary inside it for just that test, forwards its output and fails if it failed;
//! inside (the variable [`ENV`] holds the namespace's name) the test runs its body. Creating
//! a namespace needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN): without it the test says why and
//! runs on the host's network, as does `LIPCALL_TEST_NETNS=off`.

use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::sync::Once;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Set to the namespace's name for the test run inside it; `off` keeps the tests on the host.
pub const ENV: &str = "LIPCALL_TEST_NETNS";

/// The namespace's only non-loopback address, where ICE meets.
pub const MEDIA_ADDRESS: &str = "10.213.0.1";

/// What the namespaces are called: `lipcall-test-<pid of the test binary>-<n>`.
const PREFIX: &str = "lipcall-test-";

/// Longer than any Janus test takes on a loaded machine; only a hang gets this far.
const LIMIT: Duration = Duration::from_secs(300);

/// Runs the calling test, `test` (its name, as `--exact` takes it), in a network namespace of
/// its own. True when it ran there and passed: the caller returns. False: the caller runs its
/// body here, because this is the run inside the namespace, or no namespace can be had (the
/// reason is printed).
pub fn ran_in_own_namespace(test: &str) -> bool {
    match std::env::var(ENV).as_deref() {
        Ok("off") => {
            eprintln!("{ENV}=off: on the host's network");
            return false;
        }
        Ok(_) => return false,
        Err(_) => {}
    }
    match Namespace::create() {
        Ok(namespace) => {
            namespace.run(test);
            true
        }
        Err(reason) => {
            eprintln!(
                "on the host's network (ICE on its interface addresses): no network namespace \
                 of its own: {reason}"
            );
            false
        }
    }
}

/// A network namespace, with its processes, gone when dropped (a failing test too).
struct Namespace {
    name: String,
}

impl Namespace {
    fn create() -> Result<Self, String> {
        static STALE: Once = Once::new();
        STALE.call_once(remove_stale);
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let name = format!(
            "{PREFIX}{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        ip(&["netns", "add", &name])?;
        let namespace = Self { name };
        namespace.set_up()?;
        Ok(namespace)
    }

    fn set_up(&self) -> Result<(), String> {
        let ns = self.name.as_str();
        ip(&["-n", ns, "link", "set", "lo", "up"])?;
        // Kernels without the dummy driver have veth (containers are built on it).
        ip(&["-n", ns, "link", "add", "lc0", "type", "dummy"]).or_else(|dummy| {
            ip(&[
                "-n", ns, "link", "add", "lc0", "type", "veth", "peer", "name", "lc1",
            ])
            .and_then(|()| ip(&["-n", ns, "link", "set", "lc1", "up"]))
            .map_err(|veth| format!("{dummy}; {veth}"))
        })?;
        ip(&[
            "-n",
            ns,
            "addr",
            "add",
            &format!("{MEDIA_ADDRESS}/24"),
            "dev",
            "lc0",
        ])?;
        ip(&["-n", ns, "link", "set", "lc0", "up"])?;
        ip(&["-n", ns, "route", "add", "default", "dev", "lc0"])
    }

    /// Runs this test binary's `test` inside, forwarding its output, and fails if it fails.
    fn run(&self, test: &str) {
        let exe = std::env::current_exe().expect("the test binary's path");
        let mut child = Command::new("ip")
            .args(["netns", "exec", &self.name])
            .arg(&exe)
            .args(["--exact", test, "--nocapture", "--test-threads=1"])
            // A test run by name with --ignored runs in its namespace too.
            .arg("--include-ignored")
            .env(ENV, &self.name)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot run {} in {}: {e}", exe.display(), self.name));
        eprintln!(
            "{test}: in network namespace {} ({MEDIA_ADDRESS})",
            self.name
        );
        let (tx, messages) = mpsc::channel();
        forward_lines(
            child.stdout.take().expect("stdout"),
            Message::Out,
            tx.clone(),
        );
        forward_lines(
            child.stderr.take().expect("stderr"),
            Message::Err,
            tx.clone(),
        );
        std::thread::spawn(move || {
            let _ = tx.send(Message::Exited(child.wait()));
        });
        let deadline = Instant::now() + LIMIT;
        let mut passed = false;
        let mut show = |message: Message| match message {
            Message::Out(line) => {
                passed |= line.starts_with("test result: ok. 1 passed;");
                println!("{line}");
            }
            Message::Err(line) => eprintln!("{line}"),
            Message::Exited(_) => {}
        };
        let status = loop {
            match messages.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                Ok(Message::Exited(status)) => break status,
                Ok(message) => show(message),
                Err(_) => {
                    self.kill_processes();
                    panic!("{test} did not finish within {LIMIT:?} in {}", self.name);
                }
            }
        };
        // A process the test left running would hold its output open.
        self.kill_processes();
        messages.into_iter().for_each(&mut show);
        let status = status.expect("the test run inside the namespace");
        assert!(status.success(), "{test} failed in {}", self.name);
        assert!(
            passed,
            "no test named {test} ran in {}: give ran_in_own_namespace the test's own name",
            self.name
        );
    }

    fn kill_processes(&self) {
        kill_processes_in(&self.name);
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        self.kill_processes();
        if let Err(e) = ip(&["netns", "delete", &self.name]) {
            eprintln!("cannot delete network namespace {}: {e}", self.name);
        }
    }
}

enum Message {
    Out(String),
    Err(String),
    Exited(std::io::Result<std::process::ExitStatus>),
}

fn forward_lines(
    from: impl Read + Send + 'static,
    wrap: fn(String) -> Message,
    to: mpsc::Sender<Message>,
) {
    std::thread::spawn(move || {
        for line in BufReader::new(from).lines() {
            let Ok(line) = line else { break };
            if to.send(wrap(line)).is_err() {
                break;
            }
        }
    });
}

/// `ip ARGS`, its error output as the error.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run `ip` (iproute2): {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`ip {}`: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Kills what still runs in the namespace: what a test killed by the time limit, or one that
/// leaked a process, left behind.
fn kill_processes_in(namespace: &str) {
    let Ok(out) = Command::new("ip")
        .args(["netns", "pids", namespace])
        .stderr(Stdio::null())
        .output()
    else {
        return;
    };
    for pid in String::from_utf8_lossy(&out.stdout).split_whitespace() {
        eprintln!("killing process {pid}, left in network namespace {namespace}");
        let _ = Command::new("kill").args(["-KILL", pid]).status();
    }
}

/// Namespaces of test binaries that were killed before they could delete theirs.
fn remove_stale() {
    let Ok(out) = Command::new("ip").args(["netns", "list"]).output() else {
        return;
    };
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let Some(name) = line.split_whitespace().next() else {
            continue;
        };
        let Some(pid) = name
            .strip_prefix(PREFIX)
            .and_then(|rest| rest.split_once('-'))
            .map(|(pid, _)| pid)
        else {
            continue;
        };
        if !std::path::Path::new("/proc").join(pid).exists() {
            kill_processes_in(name);
            let _ = ip(&["netns", "delete", name]);
        }
    }
}

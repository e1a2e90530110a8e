//! A Mumble connection's I/O: the TLS stream (its own thread, reading with a short timeout and
//! writing what the core queued) and the UDP socket (the socket thread every sans-I/O core in
//! lipcall runs on). When the server goes away (the stream ends or breaks, or the server says
//! nothing for [`super::client::SERVER_SILENT`]) the TLS thread says so and reconnects, a
//! second after the loss and then at doubling intervals up to [`RETRY_MAX`], until it gets back
//! in or the connection is closed. Every wait has a bound: the TCP connect, the TLS handshake
//! as a whole, the join up to ServerSync, each write, and the close.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use openssl::ssl::{HandshakeError, SslConnector, SslMethod, SslStream, SslVerifyMode};

use super::MumbleError;
use super::client::{Channel, ClientConfig, ClientCore, ClientEvent, ClientStats};
use super::events::Member;
use super::identity::{Identity, KnownServers, Trust, fingerprint};
use crate::net::backoff::Backoff;
use crate::net::host_port::{AddressError, HostPort};
use crate::net::peer::ReceiverStats;
use crate::net::transport::{Driver, PeerFrame, SansIo, Transmit};

/// The port Mumble servers listen on unless told otherwise.
pub const DEFAULT_PORT: u16 = 64738;
/// How long a TLS read waits before the thread looks at its queue again.
const READ_WAIT: Duration = Duration::from_millis(5);
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// How long the TLS handshake may take, all of it.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a handshake read waits before the deadline and the stop are looked at again.
const HANDSHAKE_WAIT: Duration = Duration::from_millis(50);
/// How long a write may block (a server that reads nothing counts as lost).
const WRITE_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the server may take from our Authenticate to its ServerSync or Reject.
const JOIN_TIMEOUT: Duration = Duration::from_secs(10);
/// The first reconnect comes this long after a loss; each failed one doubles the wait.
const RETRY: Duration = Duration::from_secs(1);
const RETRY_MAX: Duration = Duration::from_secs(16);
/// How often a wait looks at whether the connection was closed.
const STOP_POLL: Duration = Duration::from_millis(20);
/// How long a close waits for the TLS thread (it may be in a reconnect's handshake: it ends on
/// its own, within that handshake's bounds).
const CLOSE_WAIT: Duration = Duration::from_millis(500);
/// Bytes of a UDP datagram buffer (Mumble's own limit is 1024).
const DATAGRAM: usize = 2048;
/// The UDP thread's longest wait.
const UDP_POLL: Duration = Duration::from_millis(5);

/// What the connection reports, beyond the core's own events.
#[derive(Debug, Clone, PartialEq)]
pub enum Notice {
    Client(ClientEvent),
    /// The server went away (`reason`); reconnecting.
    Lost(String),
    /// A reconnect failed (once per distinct reason); the next comes after `retry`.
    RejoinFailed {
        reason: String,
        retry: Duration,
    },
    /// Back in, as `session`.
    Rejoined(u32),
    /// The server came back with another certificate than the one trusted: not the server we
    /// joined, so no more reconnects (why, with both fingerprints).
    Untrusted(String),
}

/// How to reach a server and as whom.
#[derive(Debug, Clone)]
pub struct ConnectConfig {
    /// HOST or HOST:PORT.
    pub address: String,
    pub client: ClientConfig,
    /// Our certificate and the known servers; [`super::identity::default_dir`] by default.
    pub identity_dir: PathBuf,
}

/// `HOST[:PORT]` with Mumble's port where none is given, as `host:port` text.
pub fn with_port(address: &str) -> Result<String, AddressError> {
    let mut server = HostPort::parse(address)?;
    server.port = Some(server.port_or(DEFAULT_PORT));
    Ok(server.to_string())
}

struct Shared {
    driver: Driver<ClientCore>,
    notices: Mutex<Vec<Notice>>,
    stop: AtomicBool,
}

impl Shared {
    fn notify(&self, notice: Notice) {
        self.notices
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(notice);
    }

    /// Moves the core's events into the notices.
    fn drain_events(&self) {
        let events: Vec<ClientEvent> = self
            .driver
            .access(|core| std::iter::from_fn(|| core.poll_event()).collect());
        for e in events {
            self.notify(Notice::Client(e));
        }
    }
}

/// A connection to a Mumble server, joined.
pub struct Connection {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    server: String,
    /// The address the server was reached at first.
    address: SocketAddr,
    fingerprint: String,
    trust: Trust,
}

impl std::fmt::Debug for Connection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Connection")
            .field("server", &self.server)
            .finish_non_exhaustive()
    }
}

type Tls = SslStream<TcpStream>;

/// TCP, then TLS with our certificate; the server's certificate checked against the known
/// ones. Its fingerprint and how it stands come back with the stream. The handshake ends by
/// [`HANDSHAKE_TIMEOUT`], or as soon as `stop` is set.
fn open_tls(
    server: &str,
    identity: &Identity,
    known: &KnownServers,
    stop: &AtomicBool,
) -> Result<(Tls, SocketAddr, String, Trust), MumbleError> {
    let unreachable = |reason: String| MumbleError::Unreachable {
        server: server.to_string(),
        reason,
    };
    let tls_error = |reason: String| MumbleError::Tls {
        server: server.to_string(),
        reason,
    };
    let target = HostPort::parse(server).map_err(|e| unreachable(e.to_string()))?;
    let addrs = target
        .resolve_all(DEFAULT_PORT)
        .map_err(|e| unreachable(e.to_string()))?;
    let mut last = String::from("no address");
    let mut tcp = None;
    for addr in addrs {
        match TcpStream::connect_timeout(&addr, CONNECT_TIMEOUT) {
            Ok(s) => {
                tcp = Some((s, addr));
                break;
            }
            Err(e) => last = e.to_string(),
        }
    }
    let (tcp, addr) = tcp.ok_or_else(|| unreachable(last))?;
    tcp.set_nodelay(true)?;
    tcp.set_read_timeout(Some(HANDSHAKE_WAIT))?;
    tcp.set_write_timeout(Some(WRITE_TIMEOUT))?;
    let mut builder =
        SslConnector::builder(SslMethod::tls_client()).map_err(|e| tls_error(e.to_string()))?;
    // Mumble servers use self-signed certificates: trust is the known fingerprint, below.
    builder.set_verify(SslVerifyMode::NONE);
    builder
        .set_certificate(&identity.certificate)
        .and_then(|()| builder.set_private_key(&identity.key))
        .map_err(|e| tls_error(e.to_string()))?;
    let connector = builder.build();
    let mut config = connector
        .configure()
        .map_err(|e| tls_error(e.to_string()))?;
    config.set_verify_hostname(false);
    let deadline = Instant::now() + HANDSHAKE_TIMEOUT;
    let mut handshake = config.connect(&target.host, tcp);
    let stream = loop {
        match handshake {
            Ok(stream) => break stream,
            Err(HandshakeError::WouldBlock(mid)) => {
                if stop.load(Ordering::Relaxed) {
                    return Err(tls_error("closed during the TLS handshake".into()));
                }
                if Instant::now() > deadline {
                    return Err(tls_error(format!(
                        "no TLS handshake within {} s (not a Mumble server, or a stalled one)",
                        HANDSHAKE_TIMEOUT.as_secs()
                    )));
                }
                handshake = mid.handshake();
            }
            Err(e) => {
                let reset = matches!(&e, HandshakeError::Failure(mid) if mid
                    .error()
                    .io_error()
                    .is_some_and(|io| io.kind() == ErrorKind::ConnectionReset));
                let reason = e.to_string();
                return Err(
                    if reset || reason.to_ascii_lowercase().contains("unexpected eof") {
                        // murmur drops a connection before TLS when every session slot is taken
                        // (a reset when our hello was still unread).
                        MumbleError::Rejected(
                            "the server closed the connection before TLS: the server is full \
                             (or it bans this address)"
                                .into(),
                        )
                    } else {
                        tls_error(reason)
                    },
                );
            }
        }
    };
    let certificate = stream
        .ssl()
        .peer_certificate()
        .ok_or_else(|| tls_error("the server showed no certificate".into()))?;
    let print = fingerprint(&certificate)?;
    let trust = known.check(server, &print)?;
    Ok((stream, addr, print, trust))
}

fn write_queued(stream: &mut Tls, shared: &Shared) -> std::io::Result<()> {
    while let Some(bytes) = shared.driver.access(ClientCore::poll_control) {
        stream.write_all(&bytes)?;
    }
    stream.flush()
}

/// Reads what is there (waiting at most the socket's read timeout) into the core; `Err` when
/// the stream ended or broke.
fn read_some(stream: &mut Tls, shared: &Shared, buf: &mut [u8]) -> Result<(), String> {
    match stream.read(buf) {
        Ok(0) => Err("the server closed the connection".into()),
        Ok(n) => {
            shared
                .driver
                .with(|core| core.handle_stream(&buf[..n], Instant::now()));
            match shared.driver.access(ClientCore::take_fatal) {
                Some(e) => Err(e.to_string()),
                None => Ok(()),
            }
        }
        Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(()),
        Err(e) => Err(e.to_string()),
    }
}

/// Authenticates on a fresh stream and waits for the server's ServerSync (our session) or
/// Reject. Events other than those go on to the notices.
fn join(stream: &mut Tls, shared: &Shared) -> Result<u32, MumbleError> {
    shared.driver.with(|core| core.connected(Instant::now()));
    stream.get_ref().set_read_timeout(Some(READ_WAIT))?;
    let deadline = Instant::now() + JOIN_TIMEOUT;
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        if shared.stop.load(Ordering::Relaxed) {
            return Err(MumbleError::NotConnected);
        }
        write_queued(stream, shared)?;
        if let Err(reason) = read_some(stream, shared, &mut buf) {
            return Err(MumbleError::Unreachable {
                server: "the server".into(),
                reason,
            });
        }
        let events: Vec<ClientEvent> = shared
            .driver
            .access(|core| std::iter::from_fn(|| core.poll_event()).collect());
        let mut session = None;
        for e in events {
            match e {
                ClientEvent::Rejected(reason) => return Err(MumbleError::Rejected(reason)),
                ClientEvent::Synced { session: s, .. } => {
                    session = Some(s);
                    shared.notify(Notice::Client(e));
                }
                other => shared.notify(Notice::Client(other)),
            }
        }
        if let Some(s) = session {
            return Ok(s);
        }
        if Instant::now() > deadline {
            return Err(MumbleError::Timeout(
                "the Mumble server did not answer our authentication within 10 s".into(),
            ));
        }
    }
}

/// What others may ask of a connection while its owner drives it (the app's channel panel,
/// self-mute): cheap to clone; once the connection is gone it asks nothing and says nothing.
#[derive(Clone, Debug, Default)]
pub struct Remote(Weak<Shared>);

impl Remote {
    fn access<T>(&self, f: impl FnOnce(&mut ClientCore) -> T) -> Option<T> {
        self.0.upgrade().map(|shared| shared.driver.access(f))
    }

    pub fn join_channel(&self, id: u32) {
        self.access(|core| core.join_channel(id));
    }

    /// Tells the server whether we muted ourselves (others see it).
    pub fn set_self_mute(&self, muted: bool) {
        self.access(|core| core.set_self_mute(muted, Instant::now()));
    }

    pub fn channels(&self) -> Vec<Channel> {
        self.access(|core| core.channels()).unwrap_or_default()
    }

    /// Everyone on the server now, ourselves included.
    pub fn members(&self) -> Vec<Member> {
        self.access(|core| core.members()).unwrap_or_default()
    }

    pub fn current_channel(&self) -> Option<String> {
        self.access(|core| core.current_channel()).flatten()
    }

    pub fn udp_working(&self) -> bool {
        self.access(|core| core.udp_working()).unwrap_or(false)
    }
}

impl Connection {
    /// Connects, authenticates and joins; returns once in (or with why not).
    pub fn connect(config: ConnectConfig) -> Result<Self, MumbleError> {
        let server = with_port(&config.address).map_err(|e| MumbleError::Unreachable {
            server: config.address.clone(),
            reason: e.to_string(),
        })?;
        let identity = Identity::load_or_create(&config.identity_dir)?;
        let known = KnownServers::new(&config.identity_dir);
        let (mut stream, addr, print, trust) =
            open_tls(&server, &identity, &known, &AtomicBool::new(false))?;
        let bind: SocketAddr = if addr.is_ipv4() {
            ([0, 0, 0, 0], 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let socket = UdpSocket::bind(bind)?;
        let core = ClientCore::new(config.client.clone(), addr, Instant::now());
        let driver = Driver::start(socket, core, "lipcall-mumble-udp", UDP_POLL)?;
        let shared = Arc::new(Shared {
            driver,
            notices: Mutex::new(Vec::new()),
            stop: AtomicBool::new(false),
        });
        join(&mut stream, &shared)?;
        let thread_shared = Arc::clone(&shared);
        let thread_server = server.clone();
        let thread = std::thread::Builder::new()
            .name("lipcall-mumble-tls".into())
            .spawn(move || run(stream, &thread_shared, &thread_server, &identity, &known))?;
        Ok(Self {
            shared,
            thread: Some(thread),
            server,
            address: addr,
            fingerprint: print,
            trust,
        })
    }

    /// `host:port` of the server.
    pub fn server(&self) -> &str {
        &self.server
    }

    /// The address the server was reached at (no lookup).
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// A handle on this connection for others ([`Remote`]).
    pub fn remote(&self) -> Remote {
        Remote(Arc::downgrade(&self.shared))
    }

    /// The server certificate's SHA-256 fingerprint, and whether it was first seen now.
    pub fn fingerprint(&self) -> (&str, &Trust) {
        (&self.fingerprint, &self.trust)
    }

    /// What happened since the last call (who came and went: since the last call, however
    /// often it changed in between).
    pub fn poll(&self) -> Vec<Notice> {
        self.shared
            .driver
            .access(|core| core.report_presence(Instant::now()));
        self.shared.drain_events();
        std::mem::take(
            &mut *self
                .shared
                .notices
                .lock()
                .unwrap_or_else(|p| p.into_inner()),
        )
    }

    pub fn send_voice(&self, payload: &[u8], ticks: u32) -> Result<(), MumbleError> {
        self.shared
            .driver
            .with(|core| core.send_voice(payload, ticks))
    }

    pub fn skip_frames(&self, frames: u32) {
        self.shared.driver.access(|core| core.skip_frames(frames));
    }

    pub fn pull(&self, now: Instant, out: &mut Vec<PeerFrame>) {
        self.shared.driver.access(|core| core.pull(now, out));
    }

    /// Every user who spoke: session, name, reception, whether they left.
    pub fn speakers(&self) -> Vec<(u32, String, ReceiverStats, bool)> {
        self.shared.driver.access(|core| core.speakers())
    }

    /// Speakers who left and are too many to be listed by [`Self::speakers`].
    pub fn speakers_unlisted(&self) -> u64 {
        self.shared.driver.access(|core| core.speakers_unlisted())
    }

    pub fn session(&self) -> Option<u32> {
        self.shared.driver.access(|core| core.session())
    }

    pub fn stats(&self) -> ClientStats {
        self.shared.driver.access(|core| core.stats)
    }

    pub fn udp_working(&self) -> bool {
        self.shared.driver.access(|core| core.udp_working())
    }

    pub fn current_channel(&self) -> Option<String> {
        self.shared.driver.access(|core| core.current_channel())
    }

    pub fn channels(&self) -> Vec<Channel> {
        self.shared.driver.access(|core| core.channels())
    }

    pub fn join_channel(&self, id: u32) {
        self.shared.driver.access(|core| core.join_channel(id));
    }

    /// Tells the server whether we muted ourselves (others see it).
    pub fn set_self_mute(&self, muted: bool) {
        self.shared
            .driver
            .access(|core| core.set_self_mute(muted, Instant::now()));
    }

    /// Everyone on the server now, ourselves included.
    pub fn members(&self) -> Vec<Member> {
        self.shared.driver.access(|core| core.members())
    }

    /// Disconnects (the TLS stream is shut down; the server sees us leave). Waits at most
    /// [`CLOSE_WAIT`]: a thread still in a reconnect's handshake ends on its own.
    pub fn close(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        crate::net::join::join_within(&mut self.thread, CLOSE_WAIT);
    }
}

impl Drop for Connection {
    fn drop(&mut self) {
        self.close();
    }
}

/// Sleeps `pause`, or less if the connection is closed meanwhile; `true` if it was.
fn stopped_during(shared: &Shared, pause: Duration) -> bool {
    let until = Instant::now() + pause;
    while Instant::now() < until {
        if shared.stop.load(Ordering::Relaxed) {
            return true;
        }
        std::thread::sleep(STOP_POLL);
    }
    shared.stop.load(Ordering::Relaxed)
}

/// The TLS thread: pumps the stream; on loss, reconnects (a second later, then backing off).
fn run(mut stream: Tls, shared: &Shared, server: &str, identity: &Identity, known: &KnownServers) {
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        let lost = loop {
            if shared.stop.load(Ordering::Relaxed) {
                let _ = write_queued(&mut stream, shared);
                let _ = stream.shutdown();
                return;
            }
            if let Err(e) = write_queued(&mut stream, shared) {
                break format!("writing to the server: {e}");
            }
            if let Err(reason) = read_some(&mut stream, shared, &mut buf) {
                break reason;
            }
            if let Some(quiet) = shared
                .driver
                .access(|core| core.server_silent(Instant::now()))
            {
                break format!(
                    "nothing from the server for {} s: our pings went unanswered",
                    quiet.as_secs()
                );
            }
            shared.drain_events();
        };
        let kicked = shared
            .driver
            .access(|core| core.kicked().map(str::to_string));
        shared
            .driver
            .access(|core| core.disconnected(Instant::now()));
        shared.drain_events();
        if kicked.is_some() {
            // Said by the core's Removed event; coming back would only be refused or kick
            // the one who took our place.
            return;
        }
        shared.notify(Notice::Lost(lost));
        let mut said: Option<String> = None;
        let mut retries = Backoff::new(RETRY, RETRY_MAX);
        let mut retry = retries.next_wait();
        stream = loop {
            if stopped_during(shared, retry) {
                return;
            }
            let attempt =
                open_tls(server, identity, known, &shared.stop).and_then(|(mut s, ..)| {
                    let session = join(&mut s, shared)?;
                    Ok((s, session))
                });
            match attempt {
                Ok((s, session)) => {
                    shared.notify(Notice::Rejoined(session));
                    break s;
                }
                Err(e @ MumbleError::CertificateChanged { .. }) => {
                    shared.notify(Notice::Untrusted(e.to_string()));
                    return;
                }
                Err(_) if shared.stop.load(Ordering::Relaxed) => return,
                Err(e) => {
                    retry = retries.next_wait();
                    let reason = e.to_string();
                    if said.as_deref() != Some(reason.as_str()) {
                        shared.notify(Notice::RejoinFailed {
                            reason: reason.clone(),
                            retry,
                        });
                        said = Some(reason);
                    }
                }
            }
        };
    }
}

/// The UDP socket thread drives the core through its inherent methods.
impl SansIo for ClientCore {
    const BUFFER: usize = DATAGRAM;

    fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        self.datagram(data, from, now);
    }

    fn poll_timeout(&self) -> Instant {
        self.next_wake()
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.wake(now);
    }

    fn poll_transmit(&mut self) -> Option<Transmit> {
        self.next_transmit()
    }

    fn transmitted(&mut self, _transmit: Transmit, sent: bool) {
        if !sent {
            tracing::debug!("Mumble UDP: a datagram could not be sent");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_port_is_added() {
        let with = |a: &str| with_port(a).unwrap();
        assert_eq!(with("127.0.0.1"), "127.0.0.1:64738");
        assert_eq!(with("127.0.0.1:1234"), "127.0.0.1:1234");
        assert_eq!(with("mumble.example"), "mumble.example:64738");
        assert_eq!(with("::1"), "[::1]:64738");
        assert_eq!(with("[::1]:99"), "[::1]:99");
        assert!(with_port("host:port").is_err());
    }
}

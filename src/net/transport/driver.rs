//! The one socket thread under a sans-I/O core: it owns a UDP socket, hands the core each
//! datagram as it arrives and runs its timeouts when due, and sends what the core queues. The
//! owner's handle calls the same core (behind the one lock here, never inside the core) and
//! sends what its call queued at once. The session and the Janus media both run on it. A SIP
//! call's RTCP may have a socket of its own (RFC 3550: the RTP port + 1): a second thread reads
//! it into the same core, and RTCP to send goes out through it.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::stamp;

/// A datagram for the socket.
#[derive(Debug)]
pub struct Transmit {
    pub to: SocketAddr,
    pub data: Vec<u8>,
    /// What it is, for the core's counters.
    pub kind: TransmitKind,
}

/// What a datagram to send is, for the counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransmitKind {
    Rtp,
    Rtcp,
    Control,
    /// Whatever a WebRTC connection sends (STUN, DTLS, SRTP, SRTCP).
    WebRtc,
}

/// A protocol's state and rules without I/O, as the socket thread drives it.
pub trait SansIo {
    /// Bytes of the buffer a datagram is read into (one that fills it may have been cut
    /// short).
    const BUFFER: usize;
    /// A datagram from `from` that arrived at `now`: the kernel's receive stamp, which may be
    /// a little before the time the core was last given (a burst read after a stall).
    fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant);
    /// When [`Self::handle_timeout`] is next due.
    fn poll_timeout(&self) -> Instant;
    /// Does what is due at `now`.
    fn handle_timeout(&mut self, now: Instant);
    /// The next datagram to send, if any.
    fn poll_transmit(&mut self) -> Option<Transmit>;
    /// A datagram from [`Self::poll_transmit`] went out (`sent`) or failed to.
    fn transmitted(&mut self, transmit: Transmit, sent: bool);
}

/// The most waiting datagrams [`Driver::with_waiting`] reads.
const WAITING_MOST: usize = 64;

struct Shared<C> {
    core: Mutex<C>,
    socket: UdpSocket,
    /// RTCP's own socket, where it has one.
    rtcp: Option<UdpSocket>,
    stop: AtomicBool,
}

fn lock<C>(m: &Mutex<C>) -> MutexGuard<'_, C> {
    // A panic while holding the lock leaves data that is still consistent enough for counters
    // and buffers; keep serving rather than cascading the panic.
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl<C: SansIo> Shared<C> {
    /// Sends what the core has to send.
    fn flush(&self, core: &mut C) {
        while let Some(transmit) = core.poll_transmit() {
            let socket = match (&self.rtcp, transmit.kind) {
                (Some(rtcp), TransmitKind::Rtcp) => rtcp,
                _ => &self.socket,
            };
            let sent = socket.send_to(&transmit.data, transmit.to).is_ok();
            core.transmitted(transmit, sent);
        }
    }
}

/// A core driven by its socket thread; the thread stops when this is dropped.
pub struct Driver<C> {
    shared: Arc<Shared<C>>,
    threads: Vec<JoinHandle<()>>,
}

impl<C: SansIo + Send + 'static> Driver<C> {
    /// Starts the thread `name` reading `socket` for `core`, waking at least every `poll` (to
    /// see whether to stop). What the core queued before is sent first.
    pub fn start(socket: UdpSocket, core: C, name: &str, poll: Duration) -> std::io::Result<Self> {
        Self::start_with_rtcp(socket, None, core, name, poll)
    }

    /// As [`Driver::start`], with RTCP on a socket of its own (`rtcp`, where given): what it
    /// receives goes to the same core, and [`TransmitKind::Rtcp`] goes out through it.
    pub fn start_with_rtcp(
        socket: UdpSocket,
        rtcp: Option<UdpSocket>,
        core: C,
        name: &str,
        poll: Duration,
    ) -> std::io::Result<Self> {
        socket.set_read_timeout(Some(poll))?;
        stamp::enable(&socket);
        let reader = socket.try_clone()?;
        let rtcp_reader = match &rtcp {
            Some(rtcp) => {
                rtcp.set_read_timeout(Some(poll))?;
                stamp::enable(rtcp);
                Some(rtcp.try_clone()?)
            }
            None => None,
        };
        let shared = Arc::new(Shared {
            core: Mutex::new(core),
            socket,
            rtcp,
            stop: AtomicBool::new(false),
        });
        {
            let mut core = lock(&shared.core);
            shared.flush(&mut core);
        }
        let mut driver = Self {
            shared,
            threads: Vec::new(),
        };
        let thread_shared = Arc::clone(&driver.shared);
        driver.threads.push(
            std::thread::Builder::new()
                .name(name.into())
                .spawn(move || run(&thread_shared, &reader, poll))?,
        );
        if let Some(reader) = rtcp_reader {
            let thread_shared = Arc::clone(&driver.shared);
            driver.threads.push(
                std::thread::Builder::new()
                    .name(format!("{name}-rtcp"))
                    .spawn(move || read_into(&thread_shared, &reader))?,
            );
        }
        Ok(driver)
    }
}

impl<C: SansIo> Driver<C> {
    /// Runs `f` on the core, then sends what it queued.
    pub fn with<T>(&self, f: impl FnOnce(&mut C) -> T) -> T {
        let mut core = lock(&self.shared.core);
        let out = f(&mut core);
        self.shared.flush(&mut core);
        out
    }

    /// Runs `f` on the core, sending nothing (for calls that queue nothing).
    pub fn access<T>(&self, f: impl FnOnce(&mut C) -> T) -> T {
        f(&mut lock(&self.shared.core))
    }

    /// Hands the core the datagrams waiting on the socket (the socket thread held up: a busy
    /// machine), then runs `f` on it and sends what both queued. A puller that plays from the
    /// core calls this, so that what arrived in time is played, whichever thread ran.
    pub fn with_waiting<T>(&self, f: impl FnOnce(&mut C) -> T) -> T {
        let mut core = lock(&self.shared.core);
        let mut buf = vec![0u8; C::BUFFER];
        // At most a socket buffer's worth: a flood is left to the socket thread.
        for _ in 0..WAITING_MOST {
            let Ok((n, from, arrived)) = stamp::recv_waiting(&self.shared.socket, &mut buf) else {
                break;
            };
            core.handle_datagram(&buf[..n.min(buf.len())], from, arrived);
        }
        let out = f(&mut core);
        self.shared.flush(&mut core);
        out
    }

    pub fn socket(&self) -> &UdpSocket {
        &self.shared.socket
    }

    /// Stops the thread (at once if it is waiting, else after the datagram in hand).
    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl<C> Drop for Driver<C> {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// The socket thread: datagrams into the core as they come, its timeouts when due.
fn run<C: SansIo>(shared: &Shared<C>, socket: &UdpSocket, poll: Duration) {
    let mut buf = vec![0u8; C::BUFFER];
    let mut waits = Some(poll);
    while !shared.stop.load(Ordering::Relaxed) {
        // Read afresh: the owner's calls may have set an earlier one.
        let deadline = lock(&shared.core).poll_timeout();
        // In whole milliseconds: the timeout is not set anew for every wake.
        let remaining = deadline
            .saturating_duration_since(Instant::now())
            .as_millis();
        let wait = Duration::from_millis(u64::try_from(remaining).unwrap_or(u64::MAX))
            .clamp(Duration::from_millis(1), poll);
        if waits != Some(wait) && socket.set_read_timeout(Some(wait)).is_ok() {
            waits = Some(wait);
        }
        // Errors are timeouts, and ICMP errors from earlier sends: neither stops the thread.
        let received = stamp::recv_from(socket, &mut buf).ok();
        let now = Instant::now();
        if received.is_none() && now < deadline {
            continue;
        }
        let mut core = lock(&shared.core);
        if let Some((n, from, arrived)) = received {
            // When it arrived, not when this thread got to it (a busy machine).
            core.handle_datagram(&buf[..n.min(buf.len())], from, arrived);
        }
        if now >= core.poll_timeout() {
            core.handle_timeout(now);
        }
        shared.flush(&mut core);
    }
}

/// A second socket's thread: its datagrams into the core (the first thread runs the timeouts).
fn read_into<C: SansIo>(shared: &Shared<C>, socket: &UdpSocket) {
    let mut buf = vec![0u8; C::BUFFER];
    while !shared.stop.load(Ordering::Relaxed) {
        let Ok((n, from, arrived)) = stamp::recv_from(socket, &mut buf) else {
            continue;
        };
        let mut core = lock(&shared.core);
        core.handle_datagram(&buf[..n.min(buf.len())], from, arrived);
        shared.flush(&mut core);
    }
}

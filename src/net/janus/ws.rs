//! Janus's WebSocket transport (`ws://`, `wss://`, subprotocol `janus-protocol`): one socket
//! carries requests (naming their session and handle in the body), their immediate answers and
//! every event. A thread owns the socket: it writes what the owner queues, sends the session's
//! keepalive, hands answers back to the request waiting for them and events to the same
//! channel the HTTP long poll feeds. TLS goes through the system's OpenSSL and certificate
//! store, as for HTTPS. Connecting and the handshake (TLS included) have a deadline, so a
//! server that accepts and stays silent is an error, not a hang.

use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};

use serde_json::Value;
use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{HandshakeError, Message, WebSocket};

use super::JanusError;
use super::events::{KEEPALIVE, Polled, hand_over, transaction};
use super::messages::{self, JanusAuth};
use super::url::JanusUrl;
use crate::net::host_port::HostPort;

/// How long a request waits for its immediate answer, and a write for the socket to take it.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(5);
/// How long connecting and the WebSocket handshake (TLS included) may take together.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long one read or write of the handshake blocks before the deadline is looked at.
const HANDSHAKE_SLICE: Duration = Duration::from_millis(100);
/// How long the socket thread blocks in a read before it looks at what to write.
const READ_SLICE: Duration = Duration::from_millis(10);
/// Answers nobody waits for (keepalive acks, answers that came too late) kept at most.
const ANSWERS_KEPT: usize = 64;
/// Requests queued for writing at most.
const REQUESTS_QUEUED: usize = 64;

type Socket = WebSocket<MaybeTlsStream<Deadlined>>;

/// The TCP stream under the WebSocket. While `handshake_until` is set, a read or write that
/// would block is tried again until then, and then fails as timed out: the handshake never
/// waits past it, and OpenSSL and tungstenite, whose blocking handshakes take a would-block
/// for a bug (a panic), never see one. Afterwards a would-block goes up as it is.
struct Deadlined {
    stream: TcpStream,
    handshake_until: Option<Instant>,
}

impl Deadlined {
    fn retry<T>(&mut self, mut io: impl FnMut(&mut TcpStream) -> io::Result<T>) -> io::Result<T> {
        loop {
            match io(&mut self.stream) {
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    match self.handshake_until {
                        Some(until) if Instant::now() < until => {}
                        Some(_) => {
                            return Err(io::Error::new(io::ErrorKind::TimedOut, "no answer"));
                        }
                        None => return Err(e),
                    }
                }
                other => return other,
            }
        }
    }
}

impl Read for Deadlined {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.retry(|s| s.read(buf))
    }
}

impl Write for Deadlined {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.retry(|s| s.write(buf))
    }

    fn flush(&mut self) -> io::Result<()> {
        self.retry(|s| s.flush())
    }
}

/// Connects to `url` and does the WebSocket handshake (TLS first for `wss://`), all within
/// [`HANDSHAKE_TIMEOUT`].
fn handshake(
    url: &str,
    request: tungstenite::handshake::client::Request,
) -> Result<Socket, JanusError> {
    let unreachable = |reason: String| JanusError::Http {
        url: url.to_string(),
        reason,
    };
    let until = Instant::now() + HANDSHAKE_TIMEOUT;
    let timed_out = || {
        JanusError::Timeout(format!(
            "Janus at {url} did not answer the WebSocket handshake within {} s",
            HANDSHAKE_TIMEOUT.as_secs()
        ))
    };
    let target = JanusUrl::parse(url)?;
    let addrs = HostPort {
        host: target.host,
        port: Some(target.port),
    }
    .resolve_all(target.port)
    .map_err(|e| unreachable(e.to_string()))?;
    let mut refused = None;
    let mut stream = None;
    for addr in addrs {
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break;
        }
        match TcpStream::connect_timeout(&addr, left) {
            Ok(s) => {
                stream = Some(s);
                break;
            }
            Err(e) => refused = Some(e),
        }
    }
    let stream = match (stream, refused) {
        (Some(s), _) => s,
        (None, Some(e)) if e.kind() != io::ErrorKind::TimedOut => {
            return Err(unreachable(e.to_string()));
        }
        (None, _) => return Err(timed_out()),
    };
    let setup = |s: &TcpStream| {
        s.set_nodelay(true)?;
        s.set_read_timeout(Some(HANDSHAKE_SLICE))?;
        s.set_write_timeout(Some(HANDSHAKE_SLICE))
    };
    setup(&stream).map_err(|e| unreachable(e.to_string()))?;
    let deadlined = Deadlined {
        stream,
        handshake_until: Some(until),
    };
    let mut socket = match tungstenite::client_tls_with_config(request, deadlined, None, None) {
        Ok((socket, _)) => socket,
        Err(HandshakeError::Failure(tungstenite::Error::Http(response))) => {
            return Err(JanusError::NotJanus {
                url: url.to_string(),
                reason: format!("HTTP status {}", response.status()),
            });
        }
        Err(_) if Instant::now() >= until => return Err(timed_out()),
        Err(HandshakeError::Failure(e)) => return Err(unreachable(e.to_string())),
        Err(HandshakeError::Interrupted(_)) => {
            return Err(unreachable("the handshake was interrupted".into()));
        }
    };
    let stream = match socket.get_mut() {
        MaybeTlsStream::Plain(s) => s,
        MaybeTlsStream::NativeTls(s) => s.get_mut(),
        _ => return Err(unreachable("an unexpected stream".into())),
    };
    stream.handshake_until = None;
    let running = |s: &TcpStream| {
        s.set_read_timeout(Some(READ_SLICE))?;
        s.set_write_timeout(Some(ANSWER_TIMEOUT))
    };
    running(&stream.stream).map_err(|e| unreachable(e.to_string()))?;
    Ok(socket)
}

/// The owner's end: requests out, answers in.
pub(super) struct WsCarrier {
    url: String,
    auth: JanusAuth,
    outgoing: SyncSender<String>,
    answers: Receiver<Value>,
    session: Arc<AtomicU64>,
}

impl WsCarrier {
    /// Connects and starts the socket's thread; events go to `events`.
    pub(super) fn open(
        url: &str,
        auth: &JanusAuth,
        events: SyncSender<Polled>,
        stop: Arc<AtomicBool>,
        counter: Arc<AtomicU64>,
    ) -> Result<Self, JanusError> {
        let unreachable = |reason: String| JanusError::Http {
            url: url.to_string(),
            reason,
        };
        let mut request = url
            .into_client_request()
            .map_err(|e| unreachable(e.to_string()))?;
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tungstenite::http::HeaderValue::from_static("janus-protocol"),
        );
        let socket = handshake(url, request)?;
        let (outgoing, to_write) = sync_channel(REQUESTS_QUEUED);
        let (answer_tx, answers) = sync_channel(ANSWERS_KEPT);
        let session = Arc::new(AtomicU64::new(0));
        let thread = SocketThread {
            socket,
            url: url.to_string(),
            auth: auth.clone(),
            to_write,
            answers: answer_tx,
            events,
            stop,
            counter,
            session: Arc::clone(&session),
        };
        std::thread::Builder::new()
            .name("lipcall-janus-ws".into())
            .spawn(move || thread.run())
            .map_err(|e| JanusError::Protocol(format!("cannot start the WebSocket thread: {e}")))?;
        Ok(Self {
            url: url.to_string(),
            auth: auth.clone(),
            outgoing,
            answers,
            session,
        })
    }

    /// The session the keepalives are for.
    pub(super) fn set_session(&mut self, session: u64) {
        self.session.store(session, Ordering::Relaxed);
    }

    /// Sends `body` and waits for its immediate answer (`ack`, `success` or `error`).
    pub(super) fn request(&mut self, body: Value) -> Result<Value, JanusError> {
        let transaction = body["transaction"].clone();
        let text = self.auth.sign(body).to_string();
        let gone = || JanusError::Lost(format!("the WebSocket to {} closed", self.url));
        self.outgoing.try_send(text).map_err(|e| match e {
            TrySendError::Full(_) => JanusError::Timeout("too many requests queued".into()),
            TrySendError::Disconnected(_) => gone(),
        })?;
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.answers.recv_timeout(left) {
                Ok(answer) if answer["transaction"] == transaction => {
                    return messages::check(answer);
                }
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout) => {
                    return Err(JanusError::Timeout(format!(
                        "no answer from Janus within {} s",
                        ANSWER_TIMEOUT.as_secs()
                    )));
                }
                Err(RecvTimeoutError::Disconnected) => return Err(gone()),
            }
        }
    }
}

struct SocketThread {
    socket: Socket,
    url: String,
    auth: JanusAuth,
    to_write: Receiver<String>,
    answers: SyncSender<Value>,
    events: SyncSender<Polled>,
    stop: Arc<AtomicBool>,
    counter: Arc<AtomicU64>,
    session: Arc<AtomicU64>,
}

impl SocketThread {
    fn run(mut self) {
        let mut last_keepalive = Instant::now();
        let lost = loop {
            if self.stop.load(Ordering::Relaxed) && self.flush().is_ok() {
                // The destroy the owner queued last has gone out.
                let _ = self.socket.close(None);
                let _ = self.socket.flush();
                return;
            }
            if let Err(e) = self.flush() {
                break e;
            }
            let session = self.session.load(Ordering::Relaxed);
            if session != 0 && last_keepalive.elapsed() >= KEEPALIVE {
                last_keepalive = Instant::now();
                let mut keepalive = messages::keepalive(&transaction(&self.counter));
                keepalive["session_id"] = session.into();
                if let Err(e) = self.write(self.auth.sign(keepalive).to_string()) {
                    break e;
                }
            }
            match self.socket.read() {
                Ok(Message::Text(text)) => {
                    if let Err(e) = self.dispatch(text.as_str()) {
                        break e;
                    }
                }
                Ok(Message::Close(_)) => {
                    break JanusError::Lost(format!("Janus closed the WebSocket {}", self.url));
                }
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => break self.unreachable(e),
            }
        };
        hand_over(&self.events, &self.stop, Polled::Lost(lost));
    }

    fn unreachable(&self, e: tungstenite::Error) -> JanusError {
        JanusError::Http {
            url: self.url.clone(),
            reason: e.to_string(),
        }
    }

    fn flush(&mut self) -> Result<(), JanusError> {
        while let Ok(text) = self.to_write.try_recv() {
            self.write(text)?;
        }
        Ok(())
    }

    fn write(&mut self, text: String) -> Result<(), JanusError> {
        self.socket
            .send(Message::text(text))
            .map_err(|e| self.unreachable(e))
    }

    /// An answer goes to the request waiting for it, anything else is an event.
    fn dispatch(&mut self, text: &str) -> Result<(), JanusError> {
        let message: Value = serde_json::from_str(text).map_err(|e| JanusError::NotJanus {
            url: self.url.clone(),
            reason: e.to_string(),
        })?;
        match message["janus"].as_str() {
            Some("ack" | "success" | "error") if !message["transaction"].is_null() => {
                // Nobody waiting (a keepalive's ack): dropped once the few kept are full.
                let _ = self.answers.try_send(message);
            }
            Some("keepalive") | None => {}
            Some(_) => {
                hand_over(&self.events, &self.stop, Polled::Event(message));
            }
        }
        Ok(())
    }
}

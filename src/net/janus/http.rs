//! A Janus session over its API. Over HTTP(S), requests are POSTs answered at once (`success`,
//! `ack` or `error`); what comes later (a plugin's answer to an asynchronous request, room
//! events) is fetched by a long poll, a GET on the session that Janus holds up to 30 s. One
//! thread runs the long poll and the keepalive and hands events over a channel; requests are
//! made on the caller's thread. Over a WebSocket ([`super::ws`]) one socket carries both.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use serde_json::Value;

use ureq::tls::{RootCerts, TlsConfig, TlsProvider};

use super::JanusError;
use super::events::{KEEPALIVE, Polled, hand_over, transaction};
use super::messages::{self, JanusAuth};
use super::url::{JanusUrl, Transport};
use super::ws::WsCarrier;

/// How long an asynchronous request may take before its event comes.
const EVENT_TIMEOUT: Duration = Duration::from_secs(10);
/// Events the long poll hands over before it waits for them to be read: a server flooding
/// events is slowed to the reader's pace instead of filling memory.
const EVENTS_IN_FLIGHT: usize = 256;
/// Events of other requests kept while waiting for one answer; past this the oldest go.
const EVENTS_SET_ASIDE: usize = 1024;
/// The most events taken from one long-poll answer (lipcall asks for at most 10).
const EVENTS_PER_ANSWER: usize = 100;

/// How requests reach Janus.
enum Carrier {
    Http { api: Api, base: String },
    WebSocket(WsCarrier),
}

/// A Janus session.
pub struct Client {
    carrier: Carrier,
    session: u64,
    events: Receiver<Polled>,
    /// Events read while waiting for another one.
    queued: VecDeque<Value>,
    next_transaction: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    lost: Option<String>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client")
            .field("websocket", &matches!(self.carrier, Carrier::WebSocket(_)))
            .field("session", &self.session)
            .finish_non_exhaustive()
    }
}

/// An HTTP(S) client of the API with its credentials: https through the system's OpenSSL and
/// certificate store (`SSL_CERT_FILE` adds a private CA).
#[derive(Clone)]
struct Api {
    agent: ureq::Agent,
    auth: JanusAuth,
}

impl Api {
    fn new(timeout: Duration, auth: &JanusAuth) -> Self {
        let tls = TlsConfig::builder()
            .provider(TlsProvider::NativeTls)
            .root_certs(RootCerts::PlatformVerifier)
            .build();
        let agent = ureq::Agent::config_builder()
            .timeout_global(Some(timeout))
            .tls_config(tls)
            // Janus answers errors in JSON with status 200; anything else is reported with
            // its status.
            .http_status_as_error(false)
            .build()
            .into();
        Self {
            agent,
            auth: auth.clone(),
        }
    }

    fn post(&self, url: &str, body: Value) -> Result<Value, JanusError> {
        let http = |e: ureq::Error| JanusError::Http {
            url: url.to_string(),
            reason: e.to_string(),
        };
        let mut response = self
            .agent
            .post(url)
            .send_json(self.auth.sign(body))
            .map_err(http)?;
        if !response.status().is_success() {
            return Err(JanusError::Http {
                url: url.to_string(),
                reason: format!("HTTP status {}", response.status()),
            });
        }
        let reply: Value = response
            .body_mut()
            .read_json()
            .map_err(|e| not_janus(url, e))?;
        messages::check(reply)
    }
}

/// A server that answered, but not with Janus's JSON.
fn not_janus(url: &str, e: ureq::Error) -> JanusError {
    JanusError::NotJanus {
        url: url.to_string(),
        reason: e.to_string(),
    }
}

impl Client {
    /// Creates a session on the Janus at `base` (`http(s)://host:8088/janus`, or
    /// `ws(s)://host:8188` for its WebSocket transport).
    pub fn connect(base: &str, auth: &JanusAuth) -> Result<Self, JanusError> {
        let base = base.trim().trim_end_matches('/').to_string();
        let counter = Arc::new(AtomicU64::new(1));
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, events) = sync_channel(EVENTS_IN_FLIGHT);
        if JanusUrl::parse(&base)?.transport == Transport::WebSocket {
            let mut ws = WsCarrier::open(&base, auth, tx, Arc::clone(&stop), Arc::clone(&counter))?;
            let reply = ws.request(messages::create_session(&transaction(&counter)))?;
            let session = messages::success_id(&reply)?;
            ws.set_session(session);
            return Ok(Self::new(
                Carrier::WebSocket(ws),
                session,
                events,
                counter,
                stop,
            ));
        }
        let api = Api::new(Duration::from_secs(5), auth);
        let reply = api.post(&base, messages::create_session(&transaction(&counter)))?;
        let session = messages::success_id(&reply)?;
        let poller = Poller {
            url: format!("{base}/{session}"),
            api: Api::new(Duration::from_secs(45), auth),
            keepalive_api: api.clone(),
            counter: Arc::clone(&counter),
            stop: Arc::clone(&stop),
            tx,
        };
        std::thread::Builder::new()
            .name("lipcall-janus-poll".into())
            .spawn(move || poller.run())
            .map_err(|e| JanusError::Protocol(format!("cannot start the long-poll thread: {e}")))?;
        Ok(Self::new(
            Carrier::Http { api, base },
            session,
            events,
            counter,
            stop,
        ))
    }

    fn new(
        carrier: Carrier,
        session: u64,
        events: Receiver<Polled>,
        next_transaction: Arc<AtomicU64>,
        stop: Arc<AtomicBool>,
    ) -> Self {
        Self {
            carrier,
            session,
            events,
            queued: VecDeque::new(),
            next_transaction,
            stop,
            lost: None,
        }
    }

    /// A request to the session (`handle`: to one of its plugin handles), answered at once.
    fn exchange(&mut self, handle: Option<u64>, body: Value) -> Result<Value, JanusError> {
        match &mut self.carrier {
            Carrier::Http { api, base } => {
                let url = match handle {
                    Some(h) => format!("{base}/{}/{h}", self.session),
                    None => format!("{base}/{}", self.session),
                };
                api.post(&url, body)
            }
            Carrier::WebSocket(ws) => {
                let mut body = body;
                body["session_id"] = self.session.into();
                if let Some(h) = handle {
                    body["handle_id"] = h.into();
                }
                ws.request(body)
            }
        }
    }

    pub fn session(&self) -> u64 {
        self.session
    }

    /// Attaches a plugin; returns the handle id.
    pub fn attach(&mut self, plugin: &str) -> Result<u64, JanusError> {
        let t = transaction(&self.next_transaction);
        let reply = self.exchange(None, messages::attach(&t, plugin))?;
        messages::success_id(&reply)
    }

    /// A plugin request answered at once (`create`, `exists`, ...): the plugin's data.
    pub fn request(&mut self, handle: u64, body: Value) -> Result<Value, JanusError> {
        let t = transaction(&self.next_transaction);
        let reply = self.exchange(Some(handle), messages::message(&t, body, None))?;
        messages::plugin_data(&reply).cloned()
    }

    /// A plugin request answered by a later event (`join`, `publish`, `start`): the whole
    /// event (plugin data and any `jsep`), the plugin's error as an error.
    pub fn call(
        &mut self,
        handle: u64,
        body: Value,
        jsep: Option<(&str, &str)>,
    ) -> Result<Value, JanusError> {
        let t = transaction(&self.next_transaction);
        let reply = self.exchange(Some(handle), messages::message(&t, body, jsep))?;
        if reply["janus"] != "ack" {
            // Some requests are answered at once even when they could have been later.
            messages::plugin_data(&reply)?;
            return Ok(reply);
        }
        let event = self.wait_for(&t)?;
        messages::plugin_data(&event)?;
        Ok(event)
    }

    /// Tells Janus our candidates are all in the SDP already sent on `handle`.
    pub fn trickle_completed(&mut self, handle: u64) -> Result<(), JanusError> {
        let t = transaction(&self.next_transaction);
        self.exchange(Some(handle), messages::trickle_completed(&t))
            .map(|_| ())
    }

    fn wait_for(&mut self, transaction: &str) -> Result<Value, JanusError> {
        let deadline = Instant::now() + EVENT_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.events.recv_timeout(left) {
                Ok(Polled::Event(e)) if e["transaction"] == transaction => return Ok(e),
                Ok(Polled::Event(e)) => {
                    if self.queued.len() == EVENTS_SET_ASIDE {
                        self.queued.pop_front();
                        tracing::debug!("too many Janus events waiting; the oldest dropped");
                    }
                    self.queued.push_back(e);
                }
                Ok(Polled::Lost(e)) => {
                    self.lost = Some(e.to_string());
                    return Err(e);
                }
                Err(RecvTimeoutError::Timeout) => {
                    return Err(JanusError::Timeout(format!(
                        "no answer from Janus within {} s",
                        EVENT_TIMEOUT.as_secs()
                    )));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(JanusError::Protocol("the long-poll thread ended".into()));
                }
            }
        }
    }

    /// The next event not asked for (room news, hangups), if one has come.
    pub fn next_event(&mut self) -> Result<Option<Value>, JanusError> {
        if let Some(e) = self.queued.pop_front() {
            return Ok(Some(e));
        }
        if let Some(reason) = &self.lost {
            return Err(JanusError::Lost(reason.clone()));
        }
        match self.events.try_recv() {
            Ok(Polled::Event(e)) => Ok(Some(e)),
            Ok(Polled::Lost(e)) => {
                self.lost = Some(e.to_string());
                Err(e)
            }
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => {
                Err(JanusError::Protocol("the event thread ended".into()))
            }
        }
    }

    /// Detaches a plugin handle (hanging up its peer connection).
    pub fn detach(&mut self, handle: u64) -> Result<(), JanusError> {
        let t = transaction(&self.next_transaction);
        self.exchange(Some(handle), messages::detach(&t))
            .map(|_| ())
    }

    /// Destroys the session: Janus hangs up its peer connections and tells the room.
    pub fn destroy(&mut self) -> Result<(), JanusError> {
        if self.lost.is_some() {
            self.stop.store(true, Ordering::Relaxed);
            return Ok(());
        }
        let t = transaction(&self.next_transaction);
        let destroyed = self.exchange(None, messages::destroy(&t)).map(|_| ());
        // After the request: a WebSocket's thread sends what is queued, then closes.
        self.stop.store(true, Ordering::Relaxed);
        destroyed
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        if !self.stop.load(Ordering::Relaxed) {
            let _ = self.destroy();
        }
    }
}

struct Poller {
    url: String,
    api: Api,
    keepalive_api: Api,
    counter: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    tx: SyncSender<Polled>,
}

impl Poller {
    fn run(self) {
        let mut last_keepalive = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            if last_keepalive.elapsed() >= KEEPALIVE {
                last_keepalive = Instant::now();
                let t = transaction(&self.counter);
                if let Err(e) = self.keepalive_api.post(&self.url, messages::keepalive(&t)) {
                    self.hand_over(Polled::Lost(e));
                    return;
                }
            }
            match self.poll() {
                Ok(events) => {
                    for e in events {
                        if !self.hand_over(Polled::Event(e)) {
                            return;
                        }
                    }
                }
                Err(_) if self.stop.load(Ordering::Relaxed) => return,
                Err(e) => {
                    self.hand_over(Polled::Lost(e));
                    return;
                }
            }
        }
    }

    fn hand_over(&self, polled: Polled) -> bool {
        hand_over(&self.tx, &self.stop, polled)
    }

    fn poll(&self) -> Result<Vec<Value>, JanusError> {
        let http = |e: ureq::Error| JanusError::Http {
            url: self.url.clone(),
            reason: e.to_string(),
        };
        let mut request = self.api.agent.get(&self.url).query("maxev", "10");
        for (key, value) in self.api.auth.query() {
            request = request.query(key, value);
        }
        let mut response = request.call().map_err(http)?;
        if !response.status().is_success() {
            return Err(JanusError::Http {
                url: self.url.clone(),
                reason: format!("HTTP status {}", response.status()),
            });
        }
        let reply: Value = response
            .body_mut()
            .read_json()
            .map_err(|e| not_janus(&self.url, e))?;
        let mut events = match reply {
            Value::Array(events) => events,
            one => vec![one],
        };
        events.truncate(EVENTS_PER_ANSWER);
        let mut out = Vec::with_capacity(events.len());
        for e in events {
            match e["janus"].as_str() {
                Some("keepalive") => {}
                Some("error") => {
                    return Err(messages::check(e).err().unwrap_or_else(|| {
                        JanusError::Protocol("an error without an error".into())
                    }));
                }
                _ => out.push(e),
            }
        }
        Ok(out)
    }
}

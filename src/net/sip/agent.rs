//! The SIP user agent of one call, on its own thread with its own tokio runtime (the ezk stack
//! is async; the rest of lipcall is not): registration ([`super::register`]), one outgoing call
//! (INVITE, ringing, CANCEL, answer, BYE) or the first incoming one, answered at once or as the
//! owner decides. The owner talks to it through channels: events come out, a hang-up and a
//! decision go in.
//!
//! ezk runs the dialogs and transactions; the SDP goes through [`super::sdp`] by way of
//! [`SdpMedia`], ezk's media backend, which only negotiates: the RTP itself is
//! [`super::media`]'s, on the socket whose address the SDP gives.

use std::net::SocketAddr;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use ezk_sip_core::transport::TargetTransportInfo;
use ezk_sip_core::{Endpoint, IncomingRequest, Layer, MayTake};
use ezk_sip_types::header::typed::Contact;
use ezk_sip_types::uri::{NameAddr, SipUri};
use ezk_sip_types::{Method, StatusCode};
use ezk_sip_ua::dialog::DialogLayer;
use ezk_sip_ua::invite::InviteLayer;
use ezk_sip_ua::register::Registration;
use ezk_sip_ua::{AcceptCallError, Call, CallError, CallEvent, InboundCall};
use tokio::select;
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};

use super::address::host_port;
pub use super::backend::AgentEvent;
use super::backend::{SdpMedia, send};
use super::dial;
pub use super::error::SipError;
use super::guard::{Guard, REFUSAL_WAIT, answer_statelessly};
use super::quiet::Repeated;
pub use super::register::Account;
use super::register::{
    Home, Limited, REGISTER_EXPIRY, REGISTER_TIMEOUT, keep_registered, register, uri,
};
use super::sdp::{self, LocalAudio, SdpError};
use super::transport::{self, SipTransport, SrtpPolicy, with_port};
use crate::codec::any::Codec;

/// What the agent does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Role {
    /// Calls this `sip:` URI.
    Call(String),
    /// Answers the first call that comes.
    Answer,
    /// Rings with the first call that comes and answers or refuses it as the owner decides
    /// ([`Agent::decide`]).
    Ask,
}

/// Longest display name shown of a caller; the rest is cut.
const CALLER_NAME_CHARS: usize = 64;

/// Who calls, as the user knows them: From's display name where it has one (printable
/// characters only, at most [`CALLER_NAME_CHARS`]), else its URI.
fn caller_name(from: &NameAddr) -> String {
    let name: String = from
        .name
        .as_deref()
        .unwrap_or_default()
        .chars()
        .filter(|c| !c.is_control())
        .take(CALLER_NAME_CHARS)
        .collect();
    match name.trim() {
        "" => format!("{:?}", from.uri),
        name => name.to_owned(),
    }
}

/// What to do with a ringing call ([`Role::Ask`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    Answer,
    /// 603 Decline.
    Decline,
    /// 486 Busy Here: the owner is in another call.
    Busy,
}

#[derive(Debug, Clone)]
pub struct AgentConfig {
    /// Where the SIP socket listens (UDP), and the address TCP and TLS connect from.
    pub bind: SocketAddr,
    pub account: Option<Account>,
    pub audio: LocalAudio,
    pub role: Role,
    /// PEM certificates of an authority trusted beside the system's roots (TLS).
    pub ca: Option<Vec<u8>>,
    /// Whether an offer without SRTP is refused (488).
    pub srtp: SrtpPolicy,
}

impl AgentConfig {
    /// How the signalling goes: the account's transport (calls go through its registrar),
    /// else the called URI's; an unregistered `sip answer` listens on UDP.
    pub fn transport(&self) -> Result<SipTransport, SipError> {
        match (&self.account, &self.role) {
            (Some(account), _) => Ok(account.transport),
            (None, Role::Call(target)) => SipTransport::of_uri(target),
            (None, Role::Answer | Role::Ask) => Ok(SipTransport::Udp),
        }
    }
}

/// The agent's thread and its channels.
pub struct Agent {
    hang_up: UnboundedSender<()>,
    decisions: UnboundedSender<Decision>,
    events: mpsc::Receiver<AgentEvent>,
    thread: Option<JoinHandle<()>>,
    /// The call's end (or failure) was reported.
    last_word: bool,
    /// The owner already waited for the thread to end ([`Agent::wait`]): dropping the agent
    /// does not wait again.
    waited: bool,
}

impl std::fmt::Debug for Agent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Agent").finish_non_exhaustive()
    }
}

impl Agent {
    pub fn start(config: AgentConfig) -> Result<Self, SipError> {
        let (events_tx, events) = mpsc::channel();
        let (hang_up, commands) = unbounded_channel();
        let (decisions, decided) = unbounded_channel();
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| SipError::Thread(e.to_string()))?;
        let thread = std::thread::Builder::new()
            .name("lipcall-sip".into())
            .spawn(move || {
                runtime.block_on(async move {
                    if let Err(e) = run(config, &events_tx, commands, decided).await {
                        let _ = events_tx.send(AgentEvent::Failed(e));
                    }
                });
            })
            .map_err(|e| SipError::Thread(e.to_string()))?;
        Ok(Self {
            hang_up,
            decisions,
            events,
            thread: Some(thread),
            last_word: false,
            waited: false,
        })
    }

    /// Ends the call (a CANCEL while it rings, a BYE once answered) and the registration.
    pub fn hang_up(&self) {
        let _ = self.hang_up.send(());
    }

    /// Answers or refuses the call that rings ([`Role::Ask`]); said before a call rings, it
    /// applies to the first that does.
    pub fn decide(&self, decision: Decision) {
        let _ = self.decisions.send(decision);
    }

    /// The next event within `timeout`. An agent that stopped without saying how the call
    /// ended (its thread panicked in the SIP stack) reports that as a failure.
    pub fn next_event(&mut self, timeout: Duration) -> Option<AgentEvent> {
        match self.events.recv_timeout(timeout) {
            Ok(event) => Some(self.seen(event)),
            Err(mpsc::RecvTimeoutError::Timeout) => None,
            Err(mpsc::RecvTimeoutError::Disconnected) => self.gone(),
        }
    }

    pub fn try_event(&mut self) -> Option<AgentEvent> {
        match self.events.try_recv() {
            Ok(event) => Some(self.seen(event)),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => self.gone(),
        }
    }

    /// Notes whether `event` is the agent's last word (the call ended or failed).
    fn seen(&mut self, event: AgentEvent) -> AgentEvent {
        self.last_word |= matches!(event, AgentEvent::Ended { .. } | AgentEvent::Failed(_));
        event
    }

    /// Said once: the agent's thread ended without a last word.
    fn gone(&mut self) -> Option<AgentEvent> {
        if std::mem::replace(&mut self.last_word, true) {
            return None;
        }
        Some(AgentEvent::Failed(SipError::Protocol(
            "the SIP stack stopped unexpectedly".into(),
        )))
    }

    /// Waits up to `limit` for the agent to finish (its BYE answered, the binding removed).
    pub fn wait(&mut self, limit: Duration) -> bool {
        self.waited = true;
        crate::net::join::join_within(&mut self.thread, limit)
    }
}

impl Drop for Agent {
    fn drop(&mut self) {
        self.hang_up();
        // A peer that never answers our BYE must not hold the process: the thread is left
        // to end with it.
        if !self.waited {
            self.wait(Duration::from_secs(2));
        }
    }
}

/// Hands the first INVITE outside a dialog to the agent. What else no layer took is answered
/// statelessly, so that a flood of them leaves nothing behind: another caller gets 486 Busy
/// Here, a request for a dialog or transaction we do not have 481.
struct IncomingLayer {
    calls: tokio::sync::mpsc::Sender<IncomingRequest>,
}

#[async_trait::async_trait]
impl Layer for IncomingLayer {
    fn name(&self) -> &'static str {
        "lipcall-incoming"
    }

    async fn receive(&self, endpoint: &Endpoint, request: MayTake<'_, IncomingRequest>) {
        let invite = request.line.method == Method::INVITE;
        let new_call = invite && request.base_headers.to.tag.is_none();
        let mut request = request.take();
        if new_call {
            match self.calls.try_send(request) {
                Ok(()) => return,
                Err(refused) => request = refused.into_inner(),
            }
        } else if request.base_headers.to.tag.is_some() {
            endpoint
                .layer::<Guard>()
                .matched_no_dialog(&request.line.method);
        }
        let code = if new_call {
            StatusCode::BUSY_HERE
        } else {
            StatusCode::CALL_OR_TRANSACTION_DOES_NOT_EXIST
        };
        answer_statelessly(endpoint, &request, code, None).await;
    }
}

async fn run(
    config: AgentConfig,
    events: &mpsc::Sender<AgentEvent>,
    mut commands: UnboundedReceiver<()>,
    mut decided: UnboundedReceiver<Decision>,
) -> Result<(), SipError> {
    let (calls, mut incoming) = tokio::sync::mpsc::channel(1);
    let mut builder = Endpoint::builder();
    builder.add_layer(Guard::default());
    builder.add_layer(DialogLayer::default());
    builder.add_layer(InviteLayer::default());
    builder.add_layer(IncomingLayer { calls });
    let kind = config.transport()?;
    let tls = match kind {
        SipTransport::Tls => Some(transport::connector(config.ca.as_deref())?),
        SipTransport::Udp | SipTransport::Tcp => None,
    };
    if let Some(tls) = &tls {
        builder.use_native_tls_connector(tokio_native_tls::TlsConnector::from(tls.clone()));
    }
    if kind != SipTransport::Udp && !config.bind.ip().is_unspecified() {
        builder.set_tcp_connect_bind_address(SocketAddr::new(config.bind.ip(), 0));
    }
    let udp = builder
        .bind_udp(config.bind)
        .await
        .map_err(|e| SipError::Bind {
            addr: config.bind,
            why: e.to_string(),
        })?;
    let endpoint = builder.build();
    // TCP and TLS: one connection to the registrar (or the callee), kept for the whole call;
    // ezk pings it with CRLF every 10 s (RFC 5626 4.4.1), which keeps a NAT's mapping.
    let mut target = TargetTransportInfo::default();
    let bound = match server_uri(&config, kind)? {
        Some(server) => {
            let (connection, address) =
                transport::connect(&endpoint, &server, tls.as_ref(), kind).await?;
            let bound = connection.bound();
            target.transport = Some((connection, address));
            bound
        }
        None => udp.bound(),
    };
    send(events, AgentEvent::Listening(bound, kind));

    let user = config
        .account
        .as_ref()
        .map_or("lipcall", |a| a.user.as_str())
        .to_owned();
    let contact = Contact::new(NameAddr::uri(uri(&format!(
        "sip:{user}@{bound}{}",
        kind.param()
    ))?));
    let id = match &config.account {
        Some(a) => NameAddr::uri(uri(&format!("{}@{}", a.user, a.domain))?),
        None => NameAddr::uri(SipUri::new(bound.into()).user(user.into())),
    };

    let mut stop_registration = None;
    let mut registration_task = None;
    let mut home = Home::default();
    if let Some(account) = &config.account {
        let registrar_name = account.registrar().to_owned();
        let mut registration = Registration::new(
            id.clone(),
            contact.clone(),
            uri(&account.registrar_uri())?,
            REGISTER_EXPIRY,
        );
        let mut auth = Limited::for_registration(account);
        let mut target = target.clone();
        select! {
            registered = register(&endpoint, &mut registration, &mut auth, &mut target, &registrar_name, false) => registered?,
            _ = commands.recv() => {
                send(events, AgentEvent::Ended { by_peer: false });
                return Ok(());
            }
        }
        send(events, AgentEvent::Registered(registrar_name.clone()));
        home = auth.home().clone();
        let (stop, stopped) = tokio::sync::oneshot::channel();
        stop_registration = Some(stop);
        registration_task = Some(tokio::spawn(keep_registered(
            endpoint.clone(),
            registration,
            auth,
            target,
            registrar_name,
            stopped,
        )));
    }

    let media = SdpMedia {
        audio: config.audio.clone(),
        events: events.clone(),
        version: 0,
        signalling_peer: None,
    };
    let result = match &config.role {
        Role::Call(target) => {
            drop(incoming);
            let auth = Limited::for_calls(config.account.as_ref(), home);
            let placed = Placed {
                auth,
                id,
                contact,
                target,
                next_hop: config.account.as_ref().and_then(|a| next_hop(a, target)),
            };
            call(&endpoint, placed, media, events, &mut commands).await
        }
        Role::Answer | Role::Ask => {
            let decided = (config.role == Role::Ask).then_some(&mut decided);
            let channels = Channels {
                events,
                commands: &mut commands,
                decided,
            };
            let require_srtp = config.srtp == SrtpPolicy::Required;
            answer(
                &endpoint,
                &mut incoming,
                contact,
                media,
                channels,
                require_srtp,
            )
            .await
        }
    };

    if let (Some(stop), Some(task)) = (stop_registration, registration_task) {
        let _ = stop.send(());
        let _ = tokio::time::timeout(REGISTER_TIMEOUT, task).await;
    }
    result
}

/// Where the signalling connection of a TCP or TLS agent goes: the registrar, else the callee.
fn server_uri(config: &AgentConfig, kind: SipTransport) -> Result<Option<SipUri>, SipError> {
    if kind == SipTransport::Udp {
        return Ok(None);
    }
    let server = match (&config.account, &config.role) {
        (Some(account), _) => account.registrar_uri(),
        (None, Role::Call(target)) => {
            format!("sip:{}{}", with_port(host_port(target), kind), kind.param())
        }
        (None, Role::Answer | Role::Ask) => return Ok(None),
    };
    uri(&server).map(Some)
}

/// Where a registered account's call goes first: a callee in the account's own domain is
/// reached through its registrar (the outbound proxy), not at the domain's port 5060.
fn next_hop(account: &Account, target: &str) -> Option<SipUri> {
    let server = |text: &str| with_port(text, account.transport).to_ascii_lowercase();
    if server(host_port(target)) != server(&account.domain) {
        return None;
    }
    let user = target
        .trim()
        .trim_start_matches("sips:")
        .trim_start_matches("sip:")
        .split_once('@')
        .map(|(user, _)| user)?;
    uri(&format!(
        "sip:{user}@{}{}",
        account.registrar_with_port(),
        account.transport.param()
    ))
    .ok()
}

/// An outgoing call's identities and route.
struct Placed<'t> {
    auth: Limited,
    id: NameAddr,
    contact: Contact,
    target: &'t str,
    /// The Request-URI where it is not the target's ([`next_hop`]).
    next_hop: Option<SipUri>,
}

async fn call(
    endpoint: &Endpoint,
    placed: Placed<'_>,
    mut media: SdpMedia,
    events: &mpsc::Sender<AgentEvent>,
    commands: &mut UnboundedReceiver<()>,
) -> Result<(), SipError> {
    let Placed {
        auth,
        id,
        contact,
        target,
        next_hop,
    } = placed;
    let target_uri = uri(target)?;
    let session = dial::dial(
        endpoint,
        auth,
        (id, contact),
        target,
        (target_uri, next_hop),
        &mut media,
        events,
        commands,
    )
    .await?;
    let Some(session) = session else {
        send(events, AgentEvent::Ended { by_peer: false });
        return Ok(());
    };
    send(events, AgentEvent::Established);
    let by_peer = dial::follow(session, &mut media, commands).await?;
    send(events, AgentEvent::Ended { by_peer });
    Ok(())
}

/// How an answering agent hears from and talks to its owner; `decided` where the owner decides
/// whether to answer.
struct Channels<'c> {
    events: &'c mpsc::Sender<AgentEvent>,
    commands: &'c mut UnboundedReceiver<()>,
    decided: Option<&'c mut UnboundedReceiver<Decision>>,
}

async fn answer(
    endpoint: &Endpoint,
    incoming: &mut tokio::sync::mpsc::Receiver<IncomingRequest>,
    contact: Contact,
    mut media: SdpMedia,
    channels: Channels<'_>,
    require_srtp: bool,
) -> Result<(), SipError> {
    let Channels {
        events,
        commands,
        decided,
    } = channels;
    let invite = select! {
        invite = incoming.recv() => invite,
        _ = commands.recv() => None,
    };
    let Some(invite) = invite else {
        send(events, AgentEvent::Ended { by_peer: false });
        return Ok(());
    };
    incoming.close();
    media.signalling_peer = Some(invite.tp_info.source.ip());
    send(
        events,
        AgentEvent::Incoming(caller_name(&invite.base_headers.from.uri)),
    );
    // An offer we cannot take is refused as RFC 3264 says (488), before ezk would answer it.
    if !invite.body.is_empty() {
        let offer = std::str::from_utf8(&invite.body)
            .map_err(|_| SdpError::Malformed {
                line: String::new(),
                why: "the offer is not UTF-8",
            })
            .and_then(|offer| sdp::take(offer, &media.audio));
        let refusal = match offer {
            Err(e) => Some(SipError::Sdp(e)),
            Ok(taken) if require_srtp && taken.srtp.is_none() => Some(SipError::PlainOffer),
            Ok(_) => None,
        };
        if let Some(e) = refusal {
            refuse(endpoint, invite, StatusCode::NOT_ACCEPTABLE_HERE).await;
            return Err(e);
        }
    }
    let inbound = match InboundCall::from_invite(endpoint.clone(), invite, contact) {
        Ok(inbound) => inbound,
        Err(refused) => {
            let (invite, why) = *refused;
            refuse(endpoint, invite, StatusCode::BAD_REQUEST).await;
            return Err(SipError::Protocol(format!("the caller's INVITE: {why}")));
        }
    };
    let mut inbound = inbound.with_media(media);
    inbound
        .respond_provisional(StatusCode::RINGING)
        .await
        .map_err(|e| SipError::Protocol(e.to_string()))?;
    if let Some(decided) = decided {
        let refusal = select! {
            decision = decided.recv() => match decision {
                Some(Decision::Answer) => None,
                Some(Decision::Busy) => Some(StatusCode::BUSY_HERE),
                Some(Decision::Decline) | None => Some(StatusCode::DECLINE),
            },
            _ = commands.recv() => Some(StatusCode::DECLINE),
            () = inbound.cancelled() => return Err(SipError::CallerCancelled),
        };
        if let Some(code) = refusal {
            match tokio::time::timeout(REFUSAL_WAIT, inbound.decline(code, None)).await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::debug!("refusing the call: {e}"),
                Err(_) => tracing::debug!("refusing the call: no ACK"),
            }
            send(events, AgentEvent::Ended { by_peer: false });
            return Ok(());
        }
    }
    let call = inbound.accept().await.map_err(|e| match e {
        AcceptCallError::Cancelled => SipError::CallerCancelled,
        AcceptCallError::Media(e) => SipError::Sdp(e),
        other => SipError::Protocol(other.to_string()),
    })?;
    send(events, AgentEvent::Established);
    follow(call, endpoint, events, commands).await
}

/// Answers an INVITE with a failure.
async fn refuse(endpoint: &Endpoint, mut invite: IncomingRequest, code: StatusCode) {
    let transaction = endpoint.create_server_inv_tsx(&mut invite);
    let response = endpoint.create_response(&invite, code, None);
    // The caller's ACK ends the transaction; one that never comes must not hold us.
    match tokio::time::timeout(REFUSAL_WAIT, transaction.respond_failure(response)).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => tracing::debug!("refusing an INVITE: {e}"),
        Err(_) => tracing::debug!("refusing an INVITE: no ACK"),
    }
}

/// An established call until either side hangs up.
async fn follow(
    mut call: Call<SdpMedia>,
    endpoint: &Endpoint,
    events: &mpsc::Sender<AgentEvent>,
    commands: &mut UnboundedReceiver<()>,
) -> Result<(), SipError> {
    let guard = endpoint.layer::<Guard>();
    let mut unacknowledged = Repeated::new("a re-INVITE's answer was never acknowledged");
    loop {
        select! {
            event = call.run() => match event.map_err(|e| SipError::Protocol(e.to_string()))? {
                CallEvent::Internal(internal) => {
                    // A re-INVITE's 200 waits 8.5 s for its ACK: a hang-up does not.
                    let handled = select! {
                        handled = call.handle_internal_event(internal) => Some(handled),
                        _ = commands.recv() => None,
                    };
                    guard.reinvite_done();
                    match handled {
                        None => return hang_up(call, events).await,
                        Some(Ok(())) => {}
                        Some(Err(CallError::Core(ezk_sip_core::Error::RequestTimedOut))) => {
                            unacknowledged.warn("the call goes on");
                        }
                        Some(Err(e)) => return Err(SipError::Protocol(e.to_string())),
                    }
                }
                CallEvent::Media(()) => {}
                CallEvent::Terminated => {
                    send(events, AgentEvent::Ended { by_peer: true });
                    return Ok(());
                }
            },
            _ = commands.recv() => return hang_up(call, events).await,
        }
    }
}

async fn hang_up(call: Call<SdpMedia>, events: &mpsc::Sender<AgentEvent>) -> Result<(), SipError> {
    call.terminate()
        .await
        .map_err(|e| SipError::Protocol(format!("BYE: {e}")))?;
    send(events, AgentEvent::Ended { by_peer: false });
    Ok(())
}

/// The codecs a call offers and accepts: only `chosen`, or every one SIP peers speak.
pub fn codecs(chosen: Option<Codec>) -> Vec<Codec> {
    match chosen {
        Some(codec) => vec![codec],
        None => vec![Codec::Opus, Codec::G722, Codec::Pcmu, Codec::Pcma],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_caller_is_named_by_a_printable_display_name_else_by_uri() {
        let uri = || "sip:bob@127.0.0.1".parse::<SipUri>().unwrap();
        let named = |name: &str| caller_name(&NameAddr::new(name.to_owned(), uri()));
        assert_eq!(named("Bob Builder"), "Bob Builder");
        assert_eq!(named("Bob\r\n\u{7}Builder"), "BobBuilder");
        assert_eq!(named(&"x".repeat(500)).chars().count(), CALLER_NAME_CHARS);
        let by_uri = named(" \t ");
        assert!(by_uri.contains("bob@127.0.0.1"), "{by_uri}");
        assert_eq!(caller_name(&NameAddr::uri(uri())), by_uri);
    }

    #[test]
    fn a_failure_is_the_last_word_and_a_silent_end_is_one() {
        let taken = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let config = AgentConfig {
            bind: taken.local_addr().unwrap(),
            account: None,
            audio: LocalAudio {
                addr: "127.0.0.1:4000".parse().unwrap(),
                rtcp: None,
                codecs: codecs(None),
                session_id: 1,
                key: super::super::sdp::SdesKey([0; 30]),
                offer_srtp: false,
                frame_ms: 20,
            },
            role: Role::Answer,
            ca: None,
            srtp: SrtpPolicy::Optional,
        };
        let mut agent = Agent::start(config).unwrap();
        let event = agent.next_event(Duration::from_secs(5));
        assert!(
            matches!(event, Some(AgentEvent::Failed(SipError::Bind { .. }))),
            "{event:?}"
        );
        assert!(agent.wait(Duration::from_secs(5)));
        assert_eq!(agent.try_event(), None, "nothing after the last word");
        // A thread that ends without one is a failure, said once.
        agent.last_word = false;
        assert!(matches!(agent.try_event(), Some(AgentEvent::Failed(_))));
        assert_eq!(agent.try_event(), None);
    }

    #[test]
    fn a_callee_on_the_accounts_own_server_is_reached_through_its_registrar() {
        let mut account = Account::parse("sips:alice@voip.example", "pw").unwrap();
        account.registrar = Some("10.0.0.1:5071".into());
        let hop = |target| next_hop(&account, target).map(|u| format!("{u:?}"));
        let through = hop("sip:bob@voip.example;transport=tls").unwrap();
        assert!(
            through.contains("10.0.0.1") && through.contains("5071"),
            "{through}"
        );
        assert!(hop("sip:bob@VOIP.example:5061").is_some());
        assert_eq!(hop("sip:bob@voip.example:5070"), None, "another port");
        assert_eq!(hop("sip:carol@elsewhere.example"), None, "another domain");
    }

    #[test]
    fn one_codec_or_every_one_sip_peers_speak() {
        assert_eq!(codecs(Some(Codec::Pcma)), vec![Codec::Pcma]);
        assert_eq!(
            codecs(None),
            vec![Codec::Opus, Codec::G722, Codec::Pcmu, Codec::Pcma]
        );
    }
}

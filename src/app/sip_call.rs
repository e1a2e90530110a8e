//! The app's phone: the SIP account's listener, which registers and rings the user with the
//! first call that comes (answered, declined with 603, or refused with 486 while another call
//! runs), the SIP calls dialled from the app (a `sip:` URI, or a number at the account's
//! domain), and the DTMF keypad. A SIP call becomes the engine's link like any other call
//! ([`PhoneTurn`]), whose progress and end the engine hears through `Link::poll` as it hears
//! every link's; the phone keeps the call's [`SipHandle`] for the keypad.

use std::net::SocketAddr;
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use crate::call::link::{Link, LinkEvent};
use crate::call::sip::{CallState, SipHandle, SipLink, SipSecurity};
use crate::call::sip_sockets::MediaSockets;
use crate::codec::any::Codec;
use crate::net::backoff::Backoff;
use crate::net::sip::address::{bind_towards, host_port};
use crate::net::sip::agent::{Account, Decision, Role, SipError, codecs};
use crate::secrets::forbid_core_dumps;

/// How long a listener that failed (registrar down, refused password) waits to try again; each
/// failure in a row doubles it, up to [`LISTEN_RETRY_MAX`].
const LISTEN_RETRY: Duration = Duration::from_secs(30);
const LISTEN_RETRY_MAX: Duration = Duration::from_secs(480);

/// What the user asks of the phone.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PhoneCommand {
    /// Register with this account and take its calls (none: stop).
    Account(Option<Account>),
    /// Answer the call that rings.
    Answer,
    /// Decline it (603).
    Decline,
    /// DTMF keys into the current SIP call (RFC 4733).
    Keys(String),
    /// How the phone reaches its registrar and callers from behind a NAT.
    Network(PhoneNetwork),
}

/// How the phone reaches its provider: a STUN server whose view of our media address the SDP
/// gives (`HOST:PORT`), a fixed local port for the listener's SIP socket (a port forwarded or
/// allowed in a firewall; any free one where `None`), and the authority a TLS registrar's
/// certificate may be signed by beside the system's roots (PEM).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PhoneNetwork {
    pub stun: Option<String>,
    pub sip_port: Option<u16>,
    pub ca: Option<Vec<u8>>,
    /// Opus's frame length the phone offers (`a=ptime`) and sends where the peer takes it,
    /// ms: the settings' choice, 10, else 20.
    pub frame_ms: u8,
}

impl PhoneNetwork {
    fn frame_ms(&self) -> u8 {
        if self.frame_ms == 10 { 10 } else { 20 }
    }

    fn security(&self) -> SipSecurity {
        SipSecurity {
            ca: self.ca.clone(),
            ..SipSecurity::default()
        }
    }
}

/// The phone as the UI shows it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PhoneStatus {
    /// The account (`USER@DOMAIN`), where one is set.
    pub account: Option<String>,
    /// How its registration stands.
    pub registration: String,
    /// The caller whose call rings, waiting for Answer or Decline.
    pub ringing: Option<String>,
    /// A SIP call is the call and its peer takes DTMF events: the keypad sends.
    pub keypad: bool,
    /// The keys sent in the current call.
    pub keys_sent: String,
    /// The last thing that happened without the user (a missed or refused call).
    pub note: Option<String>,
}

/// A SIP call (dialled, or just answered) for the engine to make its link, sending `codec`
/// until SDP agrees one; once it is, the engine tells the phone ([`SipPhone::in_call`]).
pub struct PhoneTurn {
    pub link: Box<dyn Link>,
    pub handle: SipHandle,
    pub peer: String,
    pub codec: Codec,
    pub state: String,
}

/// Whether `address` is for the phone: a `sip:` URI or a telephone number.
pub fn is_sip_address(address: &str) -> bool {
    let a = address.trim();
    a.get(..4).is_some_and(|p| p.eq_ignore_ascii_case("sip:"))
        || a.get(..5).is_some_and(|p| p.eq_ignore_ascii_case("sips:"))
        || telephone_number(a).is_some()
}

/// The digits (and a leading `+`, `*` or `#`) of a number as people write it: `+46 8-123 45`.
fn telephone_number(text: &str) -> Option<String> {
    // 127.0.0.1 is an address without its port, not a number with dots.
    if text.parse::<std::net::Ipv4Addr>().is_ok() {
        return None;
    }
    let kept: String = text
        .chars()
        .filter(|c| !matches!(c, ' ' | '-' | '.' | '(' | ')'))
        .collect();
    let digits = kept.trim_start_matches(['+', '*', '#']);
    let numeric = !digits.is_empty()
        && digits
            .chars()
            .all(|c| c.is_ascii_digit() || c == '*' || c == '#');
    numeric.then_some(kept)
}

/// The URI a dial string calls: a `sip:` URI as given, a number at the account's domain.
pub fn dial_target(address: &str, account: Option<&Account>) -> Result<String, String> {
    let a = address.trim();
    if let Some(number) = telephone_number(a) {
        return match account {
            Some(account) => Ok(format!("sip:{number}@{}", account.domain)),
            None => Err(format!(
                "{a} is a number: numbers are called at a SIP account's domain; set an account"
            )),
        };
    }
    if is_sip_address(a) {
        if host_port(a).trim().is_empty() {
            return Err(format!("{a} has no host (expected sip:USER@HOST)"));
        }
        return Ok(a.to_owned());
    }
    Err(format!("{a:?} is neither a sip: address nor a number"))
}

/// The phone: the listener while no SIP call runs, the SIP call while one does.
pub struct SipPhone {
    account: Option<Account>,
    listener: Option<SipLink>,
    /// A listener being opened off the engine's worker (the registrar's name looked up).
    opening: Option<Receiver<Result<SipLink, SipError>>>,
    /// When a failed listener is tried again.
    retry_at: Option<Instant>,
    retry: Backoff,
    /// The SIP call that is the engine's link, and its peer.
    call: Option<(SipHandle, String)>,
    status: PhoneStatus,
    network: PhoneNetwork,
}

impl Default for SipPhone {
    fn default() -> Self {
        Self {
            account: None,
            listener: None,
            opening: None,
            retry_at: None,
            retry: Backoff::new(LISTEN_RETRY, LISTEN_RETRY_MAX),
            call: None,
            status: PhoneStatus::default(),
            network: PhoneNetwork::default(),
        }
    }
}

impl SipPhone {
    pub fn status(&self) -> &PhoneStatus {
        &self.status
    }

    /// Where a SIP call to `address` goes: the target URI, and the `HOST[:PORT]` whose route
    /// the call's sockets take (the account's registrar, or the callee's host), to be looked up.
    pub fn dial_plan(&self, address: &str) -> anyhow::Result<(String, String)> {
        let target = dial_target(address, self.account.as_ref()).map_err(anyhow::Error::msg)?;
        let towards = self
            .account
            .as_ref()
            .map_or(target.as_str(), |a| a.registrar());
        let towards = host_port(towards).to_owned();
        Ok((target, towards))
    }

    /// The frame length a call dialled now offers (the call's own choice, which may be newer
    /// than the listener's); the listener keeps the one it registered with.
    pub fn offer_frame_ms(&mut self, frame_ms: u8) {
        self.network.frame_ms = frame_ms;
    }

    /// The STUN server (HOST:PORT) whose view of our media address SDP gives, if any.
    pub fn stun(&self) -> Option<String> {
        self.network.stun.clone()
    }

    /// A SIP call to `target` from `bind` (the local address towards its host), its media on
    /// `media` ([`crate::call::sip_sockets::bind_media`]); the listener stops while it runs (the call's
    /// own agent registers the account and refuses other callers).
    pub fn dial_from(
        &mut self,
        target: String,
        bind: SocketAddr,
        media: MediaSockets,
    ) -> anyhow::Result<PhoneTurn> {
        self.stop_listener();
        let role = Role::Call(target.clone());
        let link = SipLink::open_with(
            bind,
            self.account.clone(),
            role,
            codecs(None),
            self.network.frame_ms(),
            &self.network.security(),
            media,
        )?;
        Ok(self.take_call(link, format!("calling {target}…")))
    }

    /// Carries out the user's command; a call answered becomes the engine's.
    pub fn command(&mut self, command: PhoneCommand) -> anyhow::Result<Option<PhoneTurn>> {
        match command {
            PhoneCommand::Account(account) => {
                if account.is_some() {
                    forbid_core_dumps();
                }
                self.stop_listener();
                self.retry.reset();
                self.status.account = account.as_ref().map(|a| format!("{}@{}", a.user, a.domain));
                self.status.registration = match &account {
                    Some(a) => format!("registering with {}…", a.registrar()),
                    None => String::new(),
                };
                self.account = account;
            }
            PhoneCommand::Answer | PhoneCommand::Decline => {
                self.status.ringing = None;
                let Some(mut listener) = self.listener.take_if(|l| l.ringing().is_some()) else {
                    anyhow::bail!("no call is ringing");
                };
                if command == PhoneCommand::Decline {
                    listener.decide(Decision::Decline);
                    self.status.note = Some(format!("declined the call from {}", listener.peer()));
                    // The listener ends once the caller has the 603; a fresh one follows.
                    self.listener = Some(listener);
                    return Ok(None);
                }
                listener.decide(Decision::Answer);
                let state = format!("answering {}…", listener.peer());
                return Ok(Some(self.take_call(listener, state)));
            }
            PhoneCommand::Network(network) => {
                if network != self.network {
                    self.network = network;
                    // The listener takes them when it registers again.
                    self.stop_listener();
                    self.retry.reset();
                }
            }
            PhoneCommand::Keys(keys) => {
                let Some((call, _)) = &self.call else {
                    anyhow::bail!("DTMF keys need a SIP call");
                };
                if !call.send_digits(&keys) {
                    anyhow::bail!("the SIP peer takes no DTMF events (RFC 4733)");
                }
                self.status.keys_sent.push_str(&keys);
            }
        }
        Ok(None)
    }

    fn take_call(&mut self, mut link: SipLink, state: String) -> PhoneTurn {
        link.keep_stream();
        PhoneTurn {
            handle: link.handle(),
            peer: link.peer().to_owned(),
            link: Box::new(link),
            codec: codecs(None)[0],
            state,
        }
    }

    /// The engine made this SIP call its link.
    pub fn in_call(&mut self, handle: SipHandle, peer: String) {
        self.call = Some((handle, peer));
        self.status.keys_sent.clear();
    }

    /// The engine let go of its link: where that was our call, the user hung up (or called
    /// elsewhere).
    pub fn call_left(&mut self) {
        if let Some((_, peer)) = self.call.take() {
            self.status.note = Some(format!("the call with {peer} ended"));
        }
        self.status.keypad = false;
    }

    /// The engine heard the call end (a hang-up, a failure): said there, nothing to note.
    pub fn call_over(&mut self) {
        self.call = None;
        self.status.keypad = false;
    }

    fn stop_listener(&mut self) {
        // One still opening is dropped on its thread, once its answer finds no one to take it.
        self.opening = None;
        if let Some(mut listener) = self.listener.take() {
            // Its unregistering waits on the registrar: not on the engine's worker.
            let stopping = std::thread::Builder::new()
                .name("sip-listener-stop".into())
                .spawn(move || listener.leave());
            if let Err(e) = stopping {
                tracing::warn!("cannot stop the SIP listener on its own thread: {e}");
            }
        }
        self.status.ringing = None;
        self.retry_at = None;
    }

    /// Follows the listener (while no SIP call runs) and the keypad; `busy`: the engine is
    /// in a call, so a caller is refused with 486.
    pub fn poll(&mut self, busy: bool, now: Instant) {
        match &self.call {
            Some((call, _)) => self.status.keypad = call.keypad(),
            None => self.follow_listener(busy, now),
        }
    }

    fn follow_listener(&mut self, busy: bool, now: Instant) {
        let Some(account) = &self.account else { return };
        let Some(listener) = &mut self.listener else {
            if let Some(opening) = &self.opening {
                let opened = match opening.try_recv() {
                    Ok(opened) => opened,
                    Err(TryRecvError::Empty) => return,
                    Err(TryRecvError::Disconnected) => Err(SipError::Thread(
                        "the SIP listener stopped while opening".into(),
                    )),
                };
                self.opening = None;
                match opened {
                    Ok(listener) => {
                        self.status.registration =
                            format!("registering with {}…", account.registrar());
                        self.listener = Some(listener);
                    }
                    Err(e) => self.listen_failed(&e.to_string(), now),
                }
            } else if self.retry_at.is_none_or(|t| now >= t) {
                self.retry_at = None;
                match open_listener(account.clone(), self.network.clone()) {
                    Ok(opening) => self.opening = Some(opening),
                    Err(e) => self.listen_failed(&e.to_string(), now),
                }
            }
            return;
        };
        for event in listener.poll() {
            let LinkEvent::Progress(notice) = event else {
                continue;
            };
            tracing::info!("SIP: {notice}");
            if notice.starts_with("registered") {
                self.status.registration = notice;
                self.retry.reset();
            }
        }
        if let Some(caller) = listener.ringing().map(str::to_owned) {
            if busy {
                listener.decide(Decision::Busy);
                self.status.ringing = None;
                self.status.note = Some(format!("{caller} called while you were in a call: busy"));
            } else {
                self.status.ringing = Some(caller);
            }
        }
        let failure = match listener.state() {
            CallState::Failed(SipError::CallerCancelled) => {
                self.status.note = Some(format!("missed call from {}", listener.peer()));
                None
            }
            CallState::Failed(e) => Some(e.to_string()),
            CallState::Ended { .. } => None,
            CallState::Setting | CallState::Established => return,
        };
        // One call per agent: a fresh listener takes the next.
        self.listener = None;
        self.status.ringing = None;
        if let Some(why) = failure {
            self.listen_failed(&why, now);
        }
    }

    fn listen_failed(&mut self, why: &str, now: Instant) {
        let wait = self.retry.next_wait();
        tracing::warn!("SIP account: {why}");
        self.status.registration = format!(
            "not registered: {why} (trying again in {} s)",
            wait.as_secs()
        );
        self.retry_at = Some(now + wait);
    }
}

/// Opens the account's listener on a thread of its own: looking up the registrar can take
/// as long as the resolver does.
fn open_listener(
    account: Account,
    network: PhoneNetwork,
) -> Result<Receiver<Result<SipLink, SipError>>, SipError> {
    let (tell, opened) = sync_channel(1);
    std::thread::Builder::new()
        .name("sip-listener-open".into())
        .spawn(move || {
            let _ = tell.send(listen(&account, &network));
        })
        .map_err(|e| SipError::Thread(e.to_string()))?;
    Ok(opened)
}

/// The account's listener: registered, ringing the user with the first call.
fn listen(account: &Account, network: &PhoneNetwork) -> Result<SipLink, SipError> {
    let mut bind: SocketAddr = bind_towards(account.registrar())?;
    if let Some(port) = network.sip_port {
        bind.set_port(port);
    }
    SipLink::open(
        bind,
        Some(account.clone()),
        Role::Ask,
        codecs(None),
        network.frame_ms(),
        &network.security(),
        network.stun.as_deref(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn any_dial_string_is_a_target_or_refused(text in "\\PC{0,40}") {
            let account = Account::parse("sip:alice@pbx.example", "pw").unwrap();
            for account in [None, Some(&account)] {
                match dial_target(&text, account) {
                    Ok(uri) => {
                        prop_assert!(is_sip_address(&text));
                        prop_assert!(uri.to_ascii_lowercase().starts_with("sip"));
                    }
                    Err(why) => prop_assert!(!why.is_empty()),
                }
            }
        }
    }

    #[test]
    fn sip_uris_and_numbers_are_dialled_others_are_not() {
        let account = Account::parse("sip:alice@pbx.example:5070", "pw").unwrap();
        assert_eq!(
            dial_target(" +46 8-123 45 ", Some(&account)),
            Ok("sip:+46812345@pbx.example:5070".to_owned())
        );
        assert_eq!(
            dial_target("sip:bob@127.0.0.1:5080", None),
            Ok("sip:bob@127.0.0.1:5080".to_owned())
        );
        assert_eq!(
            dial_target("*97", Some(&account)),
            Ok("sip:*97@pbx.example:5070".to_owned())
        );
        assert!(
            dial_target("0701234567", None)
                .unwrap_err()
                .contains("set an account")
        );
        assert_eq!(
            dial_target("sip:bob@", Some(&account)),
            Err("sip:bob@ has no host (expected sip:USER@HOST)".to_owned())
        );
        for other in [
            "127.0.0.1:5000",
            "127.0.0.1",
            "http://janus/janus",
            "",
            "+",
            "12a",
        ] {
            assert!(!is_sip_address(other), "{other}");
            assert!(dial_target(other, Some(&account)).is_err(), "{other}");
        }
        for sip in [
            "sip:bob@host",
            "SIP:bob@host",
            "sips:bob@host",
            "112",
            "(08) 123",
        ] {
            assert!(is_sip_address(sip), "{sip}");
        }
    }
}

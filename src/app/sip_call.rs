//! The app's phone: the SIP account's listener, which registers and rings the user with the
//! first call that comes (answered, declined with 603, or refused with 486 while another call
//! runs), the SIP calls dialled from the app (a `sip:` URI, or a number at the account's
//! domain), and the DTMF keypad. A SIP call becomes the engine's link like any other call; the
//! engine's hooks apply what [`SipPhone::poll`] and [`SipPhone::command`] say ([`PhoneTurn`]).

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::call::link::{Link, LinkEvent};
use crate::call::sip::{CallState, SipLink};
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use crate::net::backoff::Backoff;
use crate::net::session::{PeerFrame, PeerInfo};
use crate::net::sip::address::bind_towards;
use crate::net::sip::agent::{Account, Decision, Role, SipError, codecs};
use crate::secrets::forbid_core_dumps;

/// Our side of a SIP call is silence once the engine has sent nothing for this long (no
/// microphone).
const QUIET_AFTER: Duration = Duration::from_millis(60);

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

/// What the engine does for the phone.
pub enum PhoneTurn {
    /// This call (dialled, or just answered) becomes the engine's link, sending `codec`
    /// until SDP agrees one.
    Switch {
        link: Box<dyn Link>,
        codec: Codec,
        state: String,
    },
    /// The SIP call's state line; the codec it sends in now and whether the media is SRTP,
    /// once SDP agreed them.
    Status {
        state: Option<String>,
        media: Option<(Codec, bool)>,
    },
    /// The SIP call is over (hung up by the peer, refused, failed): back to idle, saying this.
    Over(String),
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
        return Ok(a.to_owned());
    }
    Err(format!("{a:?} is neither a sip: address nor a number"))
}

/// The phone: the listener while no SIP call runs, the SIP call while one does.
pub struct SipPhone {
    account: Option<Account>,
    listener: Option<SipLink>,
    /// When a failed listener is tried again.
    retry_at: Option<Instant>,
    retry: Backoff,
    /// The SIP call, shared with the engine's link ([`SharedCall`]).
    call: Option<Arc<Mutex<SipLink>>>,
    /// The codec and SRTP last told to the engine.
    media: Option<(Codec, bool)>,
    established: bool,
    status: PhoneStatus,
}

impl Default for SipPhone {
    fn default() -> Self {
        Self {
            account: None,
            listener: None,
            retry_at: None,
            retry: Backoff::new(LISTEN_RETRY, LISTEN_RETRY_MAX),
            call: None,
            media: None,
            established: false,
            status: PhoneStatus::default(),
        }
    }
}

fn lock(call: &Mutex<SipLink>) -> MutexGuard<'_, SipLink> {
    call.lock().unwrap_or_else(|e| e.into_inner())
}

impl SipPhone {
    pub fn status(&self) -> &PhoneStatus {
        &self.status
    }

    /// A SIP call to `address`; the listener stops while it runs (the call's own agent
    /// registers the account and refuses other callers).
    pub fn dial(&mut self, address: &str) -> anyhow::Result<PhoneTurn> {
        let target = dial_target(address, self.account.as_ref()).map_err(anyhow::Error::msg)?;
        self.stop_listener();
        let towards = self
            .account
            .as_ref()
            .map_or(target.as_str(), |a| a.registrar());
        let bind = bind_towards(towards)?;
        let role = Role::Call(target.clone());
        let link = SipLink::open(bind, self.account.clone(), role, codecs(None), false, None)?;
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
            PhoneCommand::Keys(keys) => {
                let Some(call) = &self.call else {
                    anyhow::bail!("DTMF keys need a SIP call");
                };
                if !lock(call).send_digits(&keys) {
                    anyhow::bail!("the SIP peer takes no DTMF events (RFC 4733)");
                }
                self.status.keys_sent.push_str(&keys);
            }
        }
        Ok(None)
    }

    fn take_call(&mut self, link: SipLink, state: String) -> PhoneTurn {
        let call = Arc::new(Mutex::new(link));
        self.call = Some(Arc::clone(&call));
        self.media = None;
        self.established = false;
        self.status.keys_sent.clear();
        PhoneTurn::Switch {
            link: Box::new(SharedCall {
                call,
                silence: None,
                ours_at: Instant::now(),
            }),
            codec: codecs(None)[0],
            state,
        }
    }

    fn stop_listener(&mut self) {
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

    /// Follows the SIP call and the listener; `busy`: the engine is in a call, so a caller
    /// is refused with 486.
    pub fn poll(&mut self, busy: bool, now: Instant) -> Vec<PhoneTurn> {
        let mut turns = Vec::new();
        self.follow_call(&mut turns);
        if self.call.is_none() {
            self.follow_listener(busy, now);
        }
        turns
    }

    fn follow_call(&mut self, turns: &mut Vec<PhoneTurn>) {
        let Some(call) = &self.call else { return };
        if Arc::strong_count(call) == 1 {
            // The engine let go of the call (the user hung up, or called elsewhere): its
            // hang-up was done by `Link::leave`.
            let peer = lock(call).peer().to_owned();
            self.status.note = Some(format!("the call with {peer} ended"));
            self.end_call();
            return;
        }
        // The engine hangs a call up on a thread of its own, holding the call while the peer
        // answers: this pass leaves it be.
        let mut link = match call.try_lock() {
            Ok(link) => link,
            Err(std::sync::TryLockError::Poisoned(e)) => e.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => return,
        };
        link.follow(Duration::ZERO);
        for notice in link.take_notices() {
            tracing::info!("SIP: {notice}");
            turns.push(PhoneTurn::Status {
                state: Some(notice),
                media: None,
            });
        }
        let media = link
            .negotiated()
            .map(|n| (n.codec, n.srtp.is_some()))
            .filter(|_| link.answered());
        let keypad = link.negotiated().is_some_and(|n| n.events.is_some());
        let over = match link.state() {
            CallState::Established if !self.established => {
                self.established = true;
                turns.push(PhoneTurn::Status {
                    state: Some(format!("in a SIP call with {}", link.peer())),
                    media: None,
                });
                None
            }
            CallState::Ended { by_peer: true } => Some(format!("{} hung up", link.peer())),
            CallState::Ended { by_peer: false } => {
                Some(format!("the call to {} ended", link.peer()))
            }
            CallState::Failed(e) => Some(format!("the SIP call failed: {e}")),
            CallState::Established | CallState::Setting => None,
        };
        drop(link);
        if media.is_some() && media != self.media {
            self.media = media;
            turns.push(PhoneTurn::Status { state: None, media });
        }
        self.status.keypad = keypad && self.established;
        if let Some(line) = over {
            self.end_call();
            turns.push(PhoneTurn::Over(line));
        }
    }

    fn end_call(&mut self) {
        self.call = None;
        self.media = None;
        self.established = false;
        self.status.keypad = false;
    }

    fn follow_listener(&mut self, busy: bool, now: Instant) {
        let Some(account) = &self.account else { return };
        let Some(listener) = &mut self.listener else {
            if self.retry_at.is_none_or(|t| now >= t) {
                self.retry_at = None;
                match listen(account) {
                    Ok(listener) => {
                        self.status.registration =
                            format!("registering with {}…", account.registrar());
                        self.listener = Some(listener);
                    }
                    Err(e) => self.listen_failed(&e.to_string(), now),
                }
            }
            return;
        };
        listener.follow(Duration::ZERO);
        for notice in listener.take_notices() {
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

/// The account's listener: registered, ringing the user with the first call.
fn listen(account: &Account) -> Result<SipLink, SipError> {
    let bind: SocketAddr = bind_towards(account.registrar())?;
    SipLink::open(
        bind,
        Some(account.clone()),
        Role::Ask,
        codecs(None),
        false,
        None,
    )
}

/// The SIP call as the engine's link, shared with the phone (which follows its state, sends
/// its keys and hears when the engine lets go of it). Where we have nothing to say (the
/// microphone's gate closed, or no microphone) it sends silence in the call's codec: phones
/// expect a steady stream, their jitter buffers hold back the last packets (a DTMF key's end
/// included) until more come, and the stream keeps a NAT's binding open.
struct SharedCall {
    call: Arc<Mutex<SipLink>>,
    /// The encoder of silence, for the codec the call agreed.
    silence: Option<FrameEncoder>,
    /// When the engine last sent (or skipped) a frame of ours.
    ours_at: Instant,
}

impl SharedCall {
    fn send_silence(&mut self, link: &mut SipLink, frames: u32) {
        let Some(codec) = link.codec().filter(|_| link.answered()) else {
            return;
        };
        if self.silence.as_ref().is_none_or(|e| e.codec() != codec) {
            self.silence = FrameEncoder::new(codec, &EncoderSettings::default()).ok();
        }
        let Some(encoder) = &mut self.silence else {
            return;
        };
        let quiet = vec![0i16; encoder.frame_samples()];
        let mut payload = [0u8; MAX_FRAME_PAYLOAD];
        for _ in 0..frames {
            if let Ok(Some((n, count))) = encoder.encode(&quiet, &mut payload) {
                link.send_frames(&payload[..n], count);
            }
        }
    }
}

impl Link for SharedCall {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        let call = Arc::clone(&self.call);
        let mut link = lock(&call);
        if self.ours_at.elapsed() >= QUIET_AFTER {
            self.send_silence(&mut link, 1);
        }
        link.pull(now, out);
    }

    fn peers(&self) -> Vec<PeerInfo> {
        lock(&self.call).peers()
    }

    fn all_left(&self) -> bool {
        lock(&self.call).all_left()
    }

    fn send_frames(&mut self, payload: &[u8], frames: u32) {
        self.ours_at = Instant::now();
        lock(&self.call).send_frames(payload, frames);
    }

    fn skip_frames(&mut self, frames: u32) {
        self.ours_at = Instant::now();
        let call = Arc::clone(&self.call);
        self.send_silence(&mut lock(&call), frames);
    }

    fn unknown_payload(&self) -> u64 {
        lock(&self.call).unknown_payload()
    }

    fn leave(&mut self) {
        lock(&self.call).leave();
    }

    /// The phone reports the call's progress and end ([`PhoneTurn`]); the engine's own
    /// handling of link events is for rooms.
    fn poll(&mut self) -> Vec<LinkEvent> {
        drop(lock(&self.call).poll());
        Vec::new()
    }

    fn over(&self) -> bool {
        lock(&self.call).over()
    }

    fn local_addr(&self) -> Option<SocketAddr> {
        lock(&self.call).local_addr()
    }
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
        for other in ["127.0.0.1:5000", "http://janus/janus", "", "+", "12a"] {
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

//! What a SIP peer can make the agent keep, bounded. ezk answers a request through a server
//! transaction that lives up to 32 s (64*T1, Timers H and J) on a task of its own, so a flood of
//! requests it answers piles them up by the thousand (40,000 INVITEs: over 1 GB). Here:
//! - a request outside any dialog that no call takes is answered statelessly (RFC 3261 8.2.7,
//!   [`answer_statelessly`]): nothing is kept, a retransmission is answered again;
//! - methods nothing here implements are answered at once: OPTIONS 200, the others 405;
//! - re-INVITEs are taken one at a time: one that comes while another is in progress gets 500
//!   with Retry-After (RFC 3261 14.2), statelessly;
//! - other in-dialog requests (BYE, NOTIFY, PRACK, CANCEL), which ezk answers statefully: at most
//!   [`IN_DIALOG_CAP`] per [`TRANSACTION_LIFETIME`], then 503 with Retry-After.
//!
//! [`Guard`] is the endpoint's first layer; the call's loops tell it when a re-INVITE is done.
//! Its refusals are warned about once per kind, and counted ([`Repeated`]).

use std::collections::VecDeque;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use bytesstr::BytesStr;
use ezk_sip_core::{Endpoint, IncomingRequest, Layer, MayTake};
use ezk_sip_types::header::typed::{FromTo, RetryAfter};
use ezk_sip_types::{Method, Name, StatusCode};

use super::quiet::Repeated;

/// How long ezk keeps a server transaction at most (64*T1): the window in-dialog requests are
/// counted over.
pub const TRANSACTION_LIFETIME: Duration = Duration::from_secs(32);
/// In-dialog requests other than INVITE and ACK taken per [`TRANSACTION_LIFETIME`]; a call has a
/// handful (a BYE, a NOTIFY or two).
pub const IN_DIALOG_CAP: usize = 32;
/// How long a refused caller has to acknowledge the refusal.
pub const REFUSAL_WAIT: Duration = Duration::from_secs(2);
/// Longest a re-INVITE may be in progress (ezk waits 8.5 s for the ACK of its 200) before the
/// next is taken, should the call's loop never see the first.
pub const REINVITE_HOLD: Duration = Duration::from_secs(10);

/// Answers `request` once and keeps nothing (RFC 3261 8.2.7, a stateless UAS): its To-tag is
/// made from the request, so a retransmission gets the same answer.
pub async fn answer_statelessly(
    endpoint: &Endpoint,
    request: &IncomingRequest,
    code: StatusCode,
    retry_after: Option<u32>,
) {
    if request.line.method == Method::ACK {
        return;
    }
    let mut response = endpoint.create_response(request, code, None);
    let headers = &mut response.msg.headers;
    if request.base_headers.to.tag.is_none() {
        let tag = stateless_tag(request);
        let _ = headers.edit(Name::TO, |to: &mut FromTo| to.tag = Some(tag));
    }
    if let Some(seconds) = retry_after {
        headers.insert_named(&RetryAfter::new(seconds));
    }
    if matches!(code, StatusCode::OK | StatusCode::METHOD_NOT_ALLOWED) {
        headers.insert_named(endpoint.allowed());
    }
    if let Err(e) = endpoint.send_outgoing_response(&mut response).await {
        tracing::debug!("answering a {} statelessly: {e}", request.line.method);
    }
}

fn stateless_tag(request: &IncomingRequest) -> BytesStr {
    let mut hasher = DefaultHasher::new();
    request.base_headers.call_id.0.hash(&mut hasher);
    request.base_headers.from.tag.hash(&mut hasher);
    request.tsx_key.branch().hash(&mut hasher);
    BytesStr::from(format!("{:016x}", hasher.finish()))
}

/// The endpoint's first layer: see the module's documentation.
pub struct Guard {
    state: Mutex<GuardState>,
}

struct GuardState {
    /// When the re-INVITE in progress was let through.
    reinvite: Option<Instant>,
    /// When each in-dialog request of the last [`TRANSACTION_LIFETIME`] was let through.
    in_dialog: VecDeque<Instant>,
    busy_refused: Repeated,
    over_cap: Repeated,
}

impl Default for Guard {
    fn default() -> Self {
        Self {
            state: Mutex::new(GuardState {
                reinvite: None,
                in_dialog: VecDeque::with_capacity(IN_DIALOG_CAP),
                busy_refused: Repeated::new(
                    "re-INVITEs refused (500) while another was in progress",
                ),
                over_cap: Repeated::new("in-dialog requests refused (503) past the cap"),
            }),
        }
    }
}

/// How the guard answers a request it does not let through.
type Refusal = (StatusCode, Option<u32>);

impl Guard {
    /// The re-INVITE let through is over (answered, refused or failed): the next may come.
    pub fn reinvite_done(&self) {
        if let Ok(mut state) = self.state.lock() {
            state.reinvite = None;
        }
    }

    /// A request let through as in-dialog matched no dialog of ours (it is answered statelessly):
    /// it does not count against the dialog's requests, so that made-up tags cannot use them up.
    pub fn matched_no_dialog(&self, method: &Method) {
        if *method == Method::INVITE {
            self.reinvite_done();
        } else if *method != Method::ACK
            && let Ok(mut state) = self.state.lock()
        {
            state.in_dialog.pop_back();
        }
    }

    fn check(&self, method: &Method, in_dialog: bool, now: Instant) -> Option<Refusal> {
        if *method == Method::OPTIONS {
            return Some((StatusCode::OK, None));
        }
        let taken = [
            Method::INVITE,
            Method::ACK,
            Method::BYE,
            Method::CANCEL,
            Method::NOTIFY,
            Method::PRACK,
        ];
        if !taken.contains(method) {
            return Some((StatusCode::METHOD_NOT_ALLOWED, None));
        }
        if !in_dialog || *method == Method::ACK {
            return None;
        }
        let mut state = self.state.lock().ok()?;
        if *method == Method::INVITE {
            if let Some(since) = state.reinvite
                && now.saturating_duration_since(since) < REINVITE_HOLD
            {
                state
                    .busy_refused
                    .warn("one came while the last was unanswered");
                return Some((StatusCode::SERVER_INTERNAL_ERROR, Some(retry_after())));
            }
            state.reinvite = Some(now);
            return None;
        }
        while state
            .in_dialog
            .front()
            .is_some_and(|&at| now.saturating_duration_since(at) >= TRANSACTION_LIFETIME)
        {
            state.in_dialog.pop_front();
        }
        if let Some(&oldest) = state.in_dialog.front()
            && state.in_dialog.len() >= IN_DIALOG_CAP
        {
            let free_in = TRANSACTION_LIFETIME.saturating_sub(now - oldest);
            state.over_cap.warn(format!(
                "more than {IN_DIALOG_CAP} in {} s",
                TRANSACTION_LIFETIME.as_secs()
            ));
            return Some((
                StatusCode::SERVICE_UNAVAILABLE,
                Some(free_in.as_secs() as u32 + 1),
            ));
        }
        state.in_dialog.push_back(now);
        None
    }
}

/// RFC 3261 14.2: a Retry-After of 0 to 10 s, chosen at random so that two peers do not retry
/// in step.
fn retry_after() -> u32 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    nanos % 11
}

#[async_trait::async_trait]
impl Layer for Guard {
    fn name(&self) -> &'static str {
        "lipcall-guard"
    }

    async fn receive(&self, endpoint: &Endpoint, request: MayTake<'_, IncomingRequest>) {
        let in_dialog = request.base_headers.to.tag.is_some();
        let Some((code, retry)) = self.check(&request.line.method, in_dialog, Instant::now())
        else {
            return;
        };
        let request = request.take();
        answer_statelessly(endpoint, &request, code, retry).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn re_invites_come_one_at_a_time_and_a_lost_one_expires() {
        let guard = Guard::default();
        let t0 = Instant::now();
        assert_eq!(guard.check(&Method::INVITE, true, t0), None);
        let refused = guard.check(&Method::INVITE, true, t0 + Duration::from_secs(1));
        assert!(matches!(
            refused,
            Some((StatusCode::SERVER_INTERNAL_ERROR, Some(0..=10)))
        ));
        // ACKs, BYEs and new calls are not held back by it.
        assert_eq!(guard.check(&Method::ACK, true, t0), None);
        assert_eq!(guard.check(&Method::BYE, true, t0), None);
        assert_eq!(guard.check(&Method::INVITE, false, t0), None);
        guard.reinvite_done();
        assert_eq!(
            guard.check(&Method::INVITE, true, t0 + Duration::from_secs(2)),
            None
        );
        // One the call never saw is given up after REINVITE_HOLD.
        assert_eq!(
            guard.check(&Method::INVITE, true, t0 + REINVITE_HOLD * 2),
            None
        );
    }

    #[test]
    fn in_dialog_requests_are_capped_per_transaction_lifetime() {
        let guard = Guard::default();
        let t0 = Instant::now();
        for _ in 0..IN_DIALOG_CAP {
            assert_eq!(guard.check(&Method::NOTIFY, true, t0), None);
        }
        let later = t0 + Duration::from_secs(2);
        assert_eq!(
            guard.check(&Method::BYE, true, later),
            Some((StatusCode::SERVICE_UNAVAILABLE, Some(31)))
        );
        // Out of dialog they go on to be answered statelessly; after the window, in again.
        assert_eq!(guard.check(&Method::BYE, false, later), None);
        // One with a tag that matched no dialog gives its place back.
        guard.matched_no_dialog(&Method::NOTIFY);
        assert_eq!(guard.check(&Method::BYE, true, later), None);
        assert!(guard.check(&Method::BYE, true, later).is_some());
        assert_eq!(
            guard.check(&Method::BYE, true, t0 + TRANSACTION_LIFETIME),
            None
        );
    }

    #[test]
    fn methods_nothing_implements_are_answered_at_once() {
        let guard = Guard::default();
        let now = Instant::now();
        assert_eq!(
            guard.check(&Method::OPTIONS, false, now),
            Some((StatusCode::OK, None))
        );
        for method in [
            Method::INFO,
            Method::UPDATE,
            Method::MESSAGE,
            Method::REGISTER,
        ] {
            assert_eq!(
                guard.check(&method, true, now),
                Some((StatusCode::METHOD_NOT_ALLOWED, None)),
                "{method}"
            );
        }
    }
}

//! An outgoing call on ezk's INVITE initiator: the offer, digest answers to 401 and 407, ringing
//! (early dialogs included), the answer, and until then a CANCEL that matches the INVITE. ezk's
//! own `OutboundCall` sends its CANCEL with a Via branch of its own, which RFC 3261 (9.1) does
//! not allow: kamailio drops it and the callee keeps ringing. Here the CANCEL copies the
//! INVITE's Via, From, To, Call-ID and CSeq number. Once answered, the session is followed here
//! too (re-INVITEs answered through the same SDP, BYE either way).

use std::future::poll_fn;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::task::Poll;
use std::time::Duration;

use bytesstr::BytesStr;
use ezk_sip_core::transaction::TsxResponse;
use ezk_sip_core::{Endpoint, Request};
use ezk_sip_types::header::typed::{CSeq, Contact, ContentType};
use ezk_sip_types::uri::{NameAddr, SipUri};
use ezk_sip_types::{Method, Name, StatusCode};
use ezk_sip_ua::invite::create_ack;
use ezk_sip_ua::invite::initiator::{Early, EarlyResponse, InviteInitiator, Response};
use ezk_sip_ua::invite::session::{InviteSession, InviteSessionEvent, ReInviteReceived};
use tokio::select;
use tokio::sync::mpsc::UnboundedReceiver;

use super::backend::{AgentEvent, SdpMedia, send};
use super::error::SipError;
use super::guard::{Guard, REFUSAL_WAIT};
use super::quiet::Repeated;
use super::register::{Limited, reason_of};
use super::sdp::SdpError;

/// How long a cancelled INVITE may take to end (the callee's 487).
const CANCEL_WAIT: Duration = Duration::from_secs(3);
/// Early dialogs one call may have (a forking proxy's branches ringing at once). ezk keeps a
/// dialog and a channel for each To-tag a callee invents until the INVITE ends, so a callee
/// that opens more is hung up on.
const MAX_EARLY_DIALOGS: usize = 16;

fn sdp_type() -> ContentType {
    ContentType(BytesStr::from_static("application/sdp"))
}

/// The SDP text of a message, if it carries one.
fn sdp_body(headers: &ezk_sip_types::Headers, body: &[u8]) -> Option<Result<String, SdpError>> {
    let is_sdp = headers
        .get_named::<ContentType>()
        .is_ok_and(|t| t.0.eq_ignore_ascii_case("application/sdp"));
    if !is_sdp || body.is_empty() {
        return None;
    }
    Some(
        std::str::from_utf8(body)
            .map(str::to_owned)
            .map_err(|_| SdpError::Malformed {
                line: String::new(),
                why: "the description is not UTF-8",
            }),
    )
}

fn refused(target: &str, response: &TsxResponse) -> SipError {
    let code = response.line.code;
    SipError::CallRefused {
        target: target.to_owned(),
        code: code.into_u16(),
        reason: reason_of(code, response.line.reason.as_ref()),
    }
}

fn core_error(target: &str, e: ezk_sip_core::Error) -> SipError {
    match e {
        ezk_sip_core::Error::RequestTimedOut => SipError::NoAnswer(target.to_owned()),
        e => SipError::Protocol(e.to_string()),
    }
}

/// Sends a CANCEL for the INVITE `initiator` sent (RFC 3261 9.1: its Request-URI, top Via,
/// From, To, Call-ID and CSeq number; to where the INVITE went).
async fn cancel(endpoint: &Endpoint, initiator: &InviteInitiator) -> Result<(), SipError> {
    let Some(transaction) = initiator.transaction() else {
        return Ok(());
    };
    let invite = transaction.request();
    let mut cancel = Request::new(Method::CANCEL, invite.msg.line.uri.clone());
    let headers = &invite.msg.headers;
    if let Some(via) = headers.get_raw(&Name::VIA).next() {
        cancel.headers.insert(Name::VIA, via.clone());
    }
    for name in [Name::FROM, Name::TO, Name::CALL_ID, Name::ROUTE] {
        // A header the INVITE lacks (Route) is simply not copied.
        let _ = headers.clone_into(&mut cancel.headers, name);
    }
    let cseq = headers
        .get_named::<CSeq>()
        .map_err(|e| SipError::Protocol(format!("our own INVITE: {e}")))?;
    cancel
        .headers
        .insert_named(&CSeq::new(cseq.cseq, Method::CANCEL));
    cancel.headers.insert(Name::MAX_FORWARDS, "70");
    let mut target = ezk_sip_core::transport::TargetTransportInfo {
        via_host_port: None,
        transport: Some((invite.parts.transport.clone(), invite.parts.destination)),
    };
    let mut outgoing = endpoint
        .create_outgoing(cancel, &mut target)
        .await
        .map_err(|e| SipError::Protocol(format!("CANCEL: {e}")))?;
    endpoint
        .send_outgoing_request(&mut outgoing)
        .await
        .map_err(|e| SipError::Protocol(format!("CANCEL: {e}")))
}

/// Early media: the first 183 whose description we can take starts the media before the
/// answer (announcements, ringback); one we cannot take is left to the final answer.
fn take_early(
    response: &TsxResponse,
    media: &mut SdpMedia,
    events: &mpsc::Sender<AgentEvent>,
    early_answer: &mut bool,
    unusable: &mut Repeated,
) {
    if *early_answer || response.line.code != StatusCode::SESSION_PROGRESS {
        return;
    }
    match sdp_body(&response.headers, &response.body) {
        Some(Ok(text)) => match media.take_answer_text(&text) {
            Ok(()) => {
                *early_answer = true;
                send(events, AgentEvent::EarlyMedia);
            }
            Err(e) => unusable.warn(e),
        },
        Some(Err(e)) => unusable.warn(e),
        None => {}
    }
}

/// Waits for the next response of any early dialog.
async fn next_early(earlies: &mut [Early]) -> (usize, Result<EarlyResponse, ezk_sip_core::Error>) {
    poll_fn(|cx| {
        for (i, early) in earlies.iter_mut().enumerate() {
            if let Poll::Ready(response) = early.poll_receive(cx) {
                return Poll::Ready((i, response));
            }
        }
        Poll::Pending
    })
    .await
}

/// Places the call; `Ok(None)` when we hung up before the answer (the INVITE cancelled).
#[allow(clippy::too_many_arguments)]
pub async fn dial(
    endpoint: &Endpoint,
    mut auth: Limited,
    (id, contact): (NameAddr, Contact),
    target: &str,
    (target_uri, next_hop): (SipUri, Option<SipUri>),
    media: &mut SdpMedia,
    events: &mpsc::Sender<AgentEvent>,
    commands: &mut UnboundedReceiver<()>,
) -> Result<Option<InviteSession>, SipError> {
    let offer = media.offer()?.to_string();
    let mut initiator = InviteInitiator::new(endpoint.clone(), id, contact, target_uri);
    // ezk's initiator sends no PRACK: a peer told we support 100rel would wait for one after a
    // reliable 183 and give up on the call.
    initiator.support_100rel = false;
    let mut earlies: Vec<Early> = Vec::new();
    let mut ringing = false;
    // When a CANCEL went out, the 487 is waited for until then.
    let mut cancelled: Option<tokio::time::Instant> = None;
    let mut early_answer = false;
    let mut unusable = Repeated::new("early media we cannot take");
    'invite: loop {
        let mut invite = initiator.create_invite();
        if let Some(hop) = &next_hop {
            // ezk sends where the Request-URI points; the To header keeps the callee.
            invite.line.uri = hop.clone();
        }
        invite.headers.insert_named(&sdp_type());
        invite.body = offer.clone().into();
        auth.authorize_request(&mut invite.headers);
        initiator
            .send_invite(invite)
            .await
            .map_err(|e| core_error(target, e))?;
        media.signalling_peer = initiator
            .transaction()
            .map(|t| t.request().parts.destination.ip());
        loop {
            let cancel_deadline = async {
                match cancelled {
                    Some(deadline) => tokio::time::sleep_until(deadline).await,
                    None => std::future::pending::<()>().await,
                }
            };
            let (session, response) = select! {
                response = initiator.receive() => match response.map_err(|e| core_error(target, e))? {
                    Response::Provisional(response) => {
                        take_early(&response, media, events, &mut early_answer, &mut unusable);
                        continue;
                    }
                    Response::EarlyEvent => continue,
                    // The INVITE ends here, not at the 487: while it lasts, every To-tag the
                    // callee invents costs memory.
                    Response::Early(..) if earlies.len() >= MAX_EARLY_DIALOGS => {
                        if cancelled.is_some() {
                            return Ok(None);
                        }
                        cancel(endpoint, &initiator).await?;
                        return Err(SipError::Protocol(format!(
                            "{target} opened more than {MAX_EARLY_DIALOGS} early dialogs for one call: hung up"
                        )));
                    }
                    Response::Early(early, response, _) => {
                        take_early(&response, media, events, &mut early_answer, &mut unusable);
                        earlies.push(early);
                        if !std::mem::replace(&mut ringing, true) {
                            send(events, AgentEvent::Ringing);
                        }
                        continue;
                    }
                    Response::Failure(response) => {
                        let code = response.line.code.into_u16();
                        if cancelled.is_some() {
                            return Ok(None);
                        }
                        if code != 401 && code != 407 {
                            return Err(refused(target, &response));
                        }
                        let Some(transaction) = initiator.transaction() else {
                            return Err(refused(target, &response));
                        };
                        // Only the account's own servers and realm get a digest.
                        auth.answer(transaction.request(), &response)
                            .map_err(|r| r.error(code, SipError::CallAuth(target.to_owned())))?;
                        continue 'invite;
                    }
                    Response::Session(session, response) => (session, response),
                    Response::Finished => {
                        if cancelled.is_some() {
                            return Ok(None);
                        }
                        return Err(SipError::NoAnswer(target.to_owned()));
                    }
                },
                (i, response) = next_early(&mut earlies), if !earlies.is_empty() => {
                    match response.map_err(|e| core_error(target, e))? {
                        EarlyResponse::Success(session, response) => {
                            earlies.remove(i);
                            (session, response)
                        }
                        EarlyResponse::Provisional(response, _) => {
                            take_early(&response, media, events, &mut early_answer, &mut unusable);
                            continue;
                        }
                        EarlyResponse::Terminated => {
                            earlies.remove(i);
                            continue;
                        }
                    }
                }
                _ = commands.recv(), if cancelled.is_none() => {
                    cancel(endpoint, &initiator).await?;
                    cancelled = Some(tokio::time::Instant::now() + CANCEL_WAIT);
                    continue;
                }
                () = cancel_deadline => {
                    tracing::warn!("{target} did not confirm the CANCEL");
                    return Ok(None);
                }
            };
            return established(
                endpoint,
                initiator,
                earlies,
                session,
                response,
                media,
                target,
                cancelled.is_some(),
                early_answer,
            )
            .await
            .map(Some);
        }
    }
}

/// A final 2xx: its answer taken, ACKed; the other early dialogs cancelled. A call answered
/// just as we cancelled it is hung up at once.
#[allow(clippy::too_many_arguments)]
async fn established(
    endpoint: &Endpoint,
    mut initiator: InviteInitiator,
    earlies: Vec<Early>,
    mut session: InviteSession,
    response: TsxResponse,
    media: &mut SdpMedia,
    target: &str,
    cancelled: bool,
    early_answer: bool,
) -> Result<InviteSession, SipError> {
    for early in earlies {
        tokio::spawn(early.cancel());
    }
    // ezk's `create_ack` draws a number from the dialog's CSeq although an ACK carries its
    // INVITE's: given back, or our next request (the BYE) skips one, and a peer that takes a
    // dialog's requests in CSeq order (ezk's dialog layer: lipcall answering) holds that BYE
    // for ever, waiting for the number never sent.
    let next_cseq = session.dialog.local_cseq.load(Ordering::Relaxed);
    let mut ack = create_ack(&session.dialog, response.base_headers.cseq.cseq)
        .await
        .map_err(|e| core_error(target, e))?;
    session
        .dialog
        .local_cseq
        .store(next_cseq, Ordering::Relaxed);
    endpoint
        .send_outgoing_request(&mut ack)
        .await
        .map_err(|e| SipError::Protocol(format!("ACK: {e}")))?;
    initiator.set_acknowledge(&session, ack);
    // Retransmitted 2xx are ACKed again while the transaction lasts.
    tokio::spawn(async move {
        while let Ok(
            Response::Provisional(_)
            | Response::EarlyEvent
            | Response::Early(..)
            | Response::Session(..),
        ) = initiator.receive().await
        {}
    });
    let taken = match sdp_body(&response.headers, &response.body) {
        Some(Ok(text)) => media.take_answer_text(&text),
        Some(Err(e)) => Err(e),
        // The 183's description was the answer (RFC 3264): the 200 need not repeat it.
        None if early_answer => Ok(()),
        None => Err(SdpError::Malformed {
            line: String::new(),
            why: "the answer has no session description",
        }),
    };
    if cancelled || taken.is_err() {
        let _ = session.terminate().await;
    }
    taken?;
    if cancelled {
        return Err(SipError::Protocol(format!(
            "{target} answered as we hung up"
        )));
    }
    Ok(session)
}

/// What a peer may make go wrong again and again in an answered call: each said once.
struct Faults {
    unusable: Repeated,
    unanswered: Repeated,
    unrefreshed: Repeated,
}

/// An answered call until either side hangs up; `true` when the peer did.
pub async fn follow(
    mut session: InviteSession,
    media: &mut SdpMedia,
    commands: &mut UnboundedReceiver<()>,
) -> Result<bool, SipError> {
    let endpoint = session.endpoint.clone();
    let guard = endpoint.layer::<Guard>();
    let mut faults = Faults {
        unusable: Repeated::new("a re-INVITE we cannot take"),
        unanswered: Repeated::new("answering a re-INVITE"),
        unrefreshed: Repeated::new("refreshing the session"),
    };
    loop {
        select! {
            event = session.run() => match event.map_err(|e| SipError::Protocol(e.to_string()))? {
                InviteSessionEvent::RefreshNeeded => {
                    if let Err(e) = session.refresh().await {
                        faults.unrefreshed.warn(e);
                    }
                }
                InviteSessionEvent::Notify(_) => {}
                InviteSessionEvent::ReInviteReceived(reinvite) => {
                    // Our 200 waits 8.5 s for its ACK: a hang-up does not.
                    let answered = select! {
                        answered = answer_reinvite(&mut session, reinvite, media, &mut faults) => Some(answered),
                        _ = commands.recv() => None,
                    };
                    guard.reinvite_done();
                    match answered {
                        Some(answered) => answered?,
                        None => return hang_up(&mut session).await,
                    }
                }
                InviteSessionEvent::Bye(bye) => {
                    if let Err(e) = session.handle_bye(bye).await {
                        tracing::debug!("answering BYE: {e}");
                    }
                    return Ok(true);
                }
                InviteSessionEvent::Terminated => return Ok(true),
            },
            _ = commands.recv() => return hang_up(&mut session).await,
        }
    }
}

async fn hang_up(session: &mut InviteSession) -> Result<bool, SipError> {
    session
        .terminate()
        .await
        .map_err(|e| SipError::Protocol(format!("BYE: {e}")))?;
    Ok(false)
}

/// Answers a re-INVITE through the same SDP: 200 with our answer (our offer to an offerless
/// one, a refresh), or 488 to an offer we cannot take.
async fn answer_reinvite(
    session: &mut InviteSession,
    reinvite: ReInviteReceived,
    media: &mut SdpMedia,
    faults: &mut Faults,
) -> Result<(), SipError> {
    let answer = match sdp_body(&reinvite.invite.headers, &reinvite.invite.body) {
        Some(Ok(text)) => media.answer_text(&text),
        Some(Err(e)) => Err(e),
        None => media.offer().map(|d| d.to_string()),
    };
    match answer {
        Ok(answer) => {
            let mut response = session
                .dialog
                .create_response(&reinvite.invite, StatusCode::OK, None)
                .map_err(|e| SipError::Protocol(e.to_string()))?;
            response.msg.headers.insert_named(&sdp_type());
            response.msg.body = answer.into();
            if let Err(e) = session.handle_reinvite_success(reinvite, response).await {
                faults.unanswered.warn(e);
            }
        }
        Err(e) => {
            faults.unusable.warn(e);
            let response = session
                .dialog
                .create_response(&reinvite.invite, StatusCode::NOT_ACCEPTABLE_HERE, None)
                .map_err(|e| SipError::Protocol(e.to_string()))?;
            // A peer that never acknowledges the refusal does not hold the call's loop.
            let refused = reinvite.transaction.respond_failure(response);
            let _ = tokio::time::timeout(REFUSAL_WAIT, refused).await;
        }
    }
    Ok(())
}

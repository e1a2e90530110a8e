//! What the SIP stack hands the owner (events) and what it asks of our media (ezk's
//! [`MediaBackend`]): offers, answers and what they agreed, through [`super::sdp`]. The RTP
//! itself is [`super::media`]'s, on the socket whose address the SDP gives.

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::sync::mpsc;

use ezk_sdp_types::SessionDescription;
use ezk_sip_ua::MediaBackend;

use super::error::SipError;
use super::sdp::{self, LocalAudio, Negotiated, SdpError};

/// What happened, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum AgentEvent {
    Listening(SocketAddr, super::transport::SipTransport),
    Registered(String),
    /// A call came in (from whom).
    Incoming(String),
    Ringing,
    /// The peer sends media before answering (a 183 with its description).
    EarlyMedia,
    /// The SDP exchange agreed this (again at a re-INVITE); boxed, the largest by far.
    Media(Box<Negotiated>),
    Established,
    /// The call is over: hung up by the peer or by us (a CANCEL before the answer included).
    Ended {
        by_peer: bool,
    },
    Failed(SipError),
}

pub fn send(events: &mpsc::Sender<AgentEvent>, event: AgentEvent) {
    let _ = events.send(event);
}

/// ezk's media backend: negotiates through [`super::sdp`] and tells the owner what was agreed.
pub struct SdpMedia {
    pub audio: LocalAudio,
    pub events: mpsc::Sender<AgentEvent>,
    pub version: u64,
    /// Where the call's SIP messages come from, once known ([`Negotiated::signalling_peer`]).
    pub signalling_peer: Option<IpAddr>,
}

impl SdpMedia {
    fn agreed(&mut self, mut negotiated: Negotiated) {
        negotiated.signalling_peer = self.signalling_peer;
        let _ = self.events.send(AgentEvent::Media(Box::new(negotiated)));
    }

    pub fn offer(&mut self) -> Result<SessionDescription, SdpError> {
        self.version += 1;
        Ok(sdp::offer(&self.audio, self.version))
    }

    /// Takes the peer's answer to our offer.
    pub fn take_answer(&mut self, answer: &SessionDescription) -> Result<(), SdpError> {
        let negotiated = sdp::take_description(answer, &self.audio)?;
        if self.audio.offer_srtp && negotiated.srtp.is_none() {
            return Err(SdpError::Unencrypted);
        }
        self.agreed(negotiated);
        Ok(())
    }

    /// [`Self::take_answer`] of an answer that came as text (a response's body).
    pub fn take_answer_text(&mut self, answer: &str) -> Result<(), SdpError> {
        self.take_answer(&sdp::parse(answer)?)
    }

    /// Our answer to the peer's offer.
    pub fn answer(&mut self, offer: &SessionDescription) -> Result<SessionDescription, SdpError> {
        // A first offer with an odd address was refused (488) before it got here.
        let negotiated = sdp::take_in_call(offer, &self.audio)?;
        self.version += 1;
        let answer = sdp::answer(&self.audio, &negotiated, self.version);
        self.agreed(negotiated);
        Ok(answer)
    }

    /// Our answer to an offer that came as text (a re-INVITE's body), as text.
    pub fn answer_text(&mut self, offer: &str) -> Result<String, SdpError> {
        Ok(self.answer(&sdp::parse(offer)?)?.to_string())
    }
}

impl MediaBackend for SdpMedia {
    type Error = SdpError;
    type Event = ();

    fn has_media(&self) -> bool {
        true
    }

    fn create_sdp_offer(
        &mut self,
    ) -> impl Future<Output = Result<SessionDescription, Self::Error>> + Send {
        std::future::ready(self.offer())
    }

    fn receive_sdp_answer(
        &mut self,
        sdp: SessionDescription,
    ) -> impl Future<Output = Result<(), Self::Error>> + Send {
        std::future::ready(self.take_answer(&sdp))
    }

    fn receive_sdp_offer(
        &mut self,
        sdp: SessionDescription,
    ) -> impl Future<Output = Result<SessionDescription, Self::Error>> + Send {
        std::future::ready(self.answer(&sdp))
    }

    fn run(&mut self) -> impl Future<Output = Result<Self::Event, Self::Error>> + Send {
        // The RTP runs on its own socket thread: nothing to drive here.
        std::future::pending()
    }
}

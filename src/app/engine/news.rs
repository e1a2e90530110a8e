//! The one route by which a call's news reaches the engine: whatever the transport, its link
//! says what happened through [`Link::poll`](crate::call::link::Link::poll), and the worker
//! shows it in the call bar (named by the call's label) or ends the call.

use std::time::Instant;

use super::{CallPhase, Encryption, Worker, lock};
use crate::app::mumble_call::app_words;
use crate::call::link::LinkEvent;
use crate::codec::any::{EncoderSettings, FrameEncoder};

impl Worker {
    /// What the call's link did since the last pass: joined, failed, lost and back, refusals,
    /// notes; a call over brings the worker back to idle.
    pub(super) fn follow_link(&mut self) {
        for news in self.link.poll() {
            let label = &self.call_label;
            let mut s = lock(&self.shared);
            match news {
                LinkEvent::Joined { place, id } => {
                    s.call.state = format!("in {place} as {id}, sending {}", self.encoder.codec());
                    if !matches!(s.call.phase, CallPhase::InCall { .. }) {
                        s.call.phase = CallPhase::InCall {
                            with: place,
                            since: Instant::now(),
                        };
                    }
                }
                LinkEvent::Failed(reason) => {
                    let error = format!("{label}: {}", app_words(&reason));
                    drop(s);
                    self.fail(error);
                    return;
                }
                LinkEvent::Over { reason } => {
                    drop(s);
                    self.fail(reason);
                    return;
                }
                LinkEvent::Ended { reason } => {
                    drop(s);
                    self.ended(reason);
                    return;
                }
                LinkEvent::Progress(line) => {
                    tracing::info!("{label}: {line}");
                    s.call.state = line;
                }
                LinkEvent::Ringing => {
                    if let CallPhase::Calling { to, deadline, .. } = &s.call.phase {
                        s.call.phase = CallPhase::Calling {
                            to: to.clone(),
                            deadline: *deadline,
                            ringing: true,
                        };
                    }
                }
                LinkEvent::Media { codec, srtp } => {
                    match FrameEncoder::new(codec, &EncoderSettings::default()) {
                        Ok(encoder) => self.encoder = encoder,
                        Err(e) => s.call.error = Some(format!("cannot send {codec}: {e}")),
                    }
                    s.call.codec = Some(codec);
                    // SDES keys travel in the signalling: every proxy on the way has them.
                    s.call.encryption = if srtp {
                        Encryption::HopByHop
                    } else {
                        Encryption::None
                    };
                }
                LinkEvent::Lost { reason } => {
                    s.call.error = Some(format!("lost the {label} ({reason}); reconnecting"));
                }
                LinkEvent::RejoinFailed { reason } => {
                    s.call.error = Some(format!("cannot reconnect to the {label} yet: {reason}"));
                }
                LinkEvent::Rejoined { id } => {
                    tracing::info!("back in the {label} as {id}");
                    s.call.error = None;
                }
                LinkEvent::Refusal(reason) => s.call.error = Some(format!("{label}: {reason}")),
                LinkEvent::Note(note) => tracing::info!("{label}: {note}"),
                LinkEvent::PeerJoined { id, name } => {
                    tracing::info!("{name:?} ({id}) is in the {label}");
                }
                LinkEvent::PeerLeft { id, name } => tracing::info!("{name:?} ({id}) left"),
                LinkEvent::PeerSkipped { name, reason, .. } => {
                    tracing::warn!("{name:?} cannot be heard, skipped: {reason}");
                }
            }
        }
    }

    /// A Mumble call's channels, state line and self-mute, once joined.
    pub(super) fn refresh_mumble(&mut self) {
        if let Some(mumble) = &mut self.mumble {
            let s = &mut *lock(&self.shared);
            mumble.refresh(&mut s.call, &mut s.mumble, s.mic.as_ref());
        }
    }
}

//! The call's phase ([`CallPhase`]), kept by the worker from every link's news, the direct
//! session's peers and the phone's ringing: what the call bar and the `--status` file show.

use std::time::Instant;

use super::consent::{Caller, in_call_with};
use super::{CallPhase, DIRECT_ANSWER_WAIT, Worker, lock};
use crate::app::counters::DEMO_NAME;
use crate::net::transport::PeerInfo;

impl Worker {
    pub(super) fn set_phase(&self, phase: CallPhase) {
        let mut s = lock(&self.shared);
        s.call.phase = phase;
    }

    /// A new call is being placed: the last call's messages go with its phase.
    pub(super) fn start_calling(&self, to: &str) {
        let mut s = lock(&self.shared);
        s.call.error = None;
        s.call.phase = CallPhase::Calling {
            to: to.trim().to_owned(),
            deadline: None,
        };
    }

    /// The call could not be placed or was lost: back to listening, saying why (the error
    /// is the phase's reason, and goes with it at the next call).
    pub(super) fn fail(&mut self, reason: String) {
        self.hang_up();
        let mut s = lock(&self.shared);
        s.call.error = Some(reason.clone());
        s.call.phase = CallPhase::Failed { reason };
    }

    /// The call ended: back to listening, saying who or what ended it.
    pub(super) fn ended(&mut self, by: String) {
        self.hang_up();
        self.set_phase(CallPhase::Ended { by });
    }

    fn hang_up(&mut self) {
        self.phone.call_over();
        if !self.in_call {
            self.set_idle_status();
        } else if let Err(e) = self.leave() {
            tracing::warn!("back to listening: {e:#}");
        }
    }

    /// A lipcall session's peers move the phase: a direct call's (heard means in a call; one
    /// nobody answers fails at its deadline; a peer who said goodbye or went away ends it), or
    /// the listening session's callers ([`Consent::phase`]).
    pub(super) fn follow_peers(&mut self, infos: &[PeerInfo], now: Instant) {
        if self.link.session().is_none() || self.call_label.starts_with(super::ROOM) {
            return;
        }
        let real = |i: &&PeerInfo| i.name.as_deref() != Some(DEMO_NAME);
        if !self.in_call {
            let heard: Vec<Caller> = infos
                .iter()
                .filter(real)
                .filter(|i| !i.ended && !i.said_bye)
                .map(|i| Caller {
                    addr: i.addr,
                    name: peer_name(i),
                })
                .collect();
            self.consent.keep_heard(&heard);
            let gone = infos.iter().filter(real).find(|i| i.ended).map(peer_name);
            let phase = lock(&self.shared).call.phase.clone();
            if let Some(next) = self.consent.phase(&phase, &heard, gone.as_deref(), now) {
                let mut s = lock(&self.shared);
                if next.is_active() || matches!(next, CallPhase::Ringing { .. }) {
                    s.call.error = None;
                }
                s.call.phase = next;
            }
            return;
        }
        let heard = infos.iter().filter(real).find(|i| !i.ended);
        let gone = infos.iter().filter(real).find(|i| i.ended);
        let phase = lock(&self.shared).call.phase.clone();
        match (phase, heard) {
            (CallPhase::Calling { .. }, Some(peer)) => self.set_phase(CallPhase::InCall {
                with: peer_name(peer),
                since: now,
            }),
            // A peer that only listens sends no media, but its reports name our stream.
            (CallPhase::Calling { to, .. }, None)
                if self
                    .link
                    .session()
                    .is_some_and(|s| s.stats().reports_about_us > 0) =>
            {
                self.set_phase(CallPhase::InCall {
                    with: to,
                    since: now,
                })
            }
            (CallPhase::Calling { to, deadline }, None) if deadline.is_some_and(|d| now >= d) => {
                self.fail(format!(
                    "nobody answered from {to} within {} s",
                    DIRECT_ANSWER_WAIT.as_secs()
                ));
            }
            (CallPhase::InCall { with, .. }, None) => {
                if let Some(peer) = gone {
                    self.ended(format!("{} hung up", peer_name(peer)));
                } else if self.link.session().is_some_and(|s| s.stats().rtp > 0) {
                    // Its media was heard and it was forgotten after its silence (gone
                    // without a BYE: its app or network died); a peer that only listens
                    // sends none and stays.
                    self.ended(format!("{with} went quiet and was dropped"));
                }
            }
            // The phase names whom the call is with now: a peer who left is not, a name heard
            // late replaces an address.
            (CallPhase::InCall { with, since }, Some(_)) => {
                let names: Vec<String> = infos
                    .iter()
                    .filter(real)
                    .filter(|i| !i.ended)
                    .map(peer_name)
                    .collect();
                if let Some(with) = in_call_with(&with, &names) {
                    lock(&self.shared).call.phase = CallPhase::InCall { with, since };
                }
            }
            _ => {}
        }
    }

    /// The phone's ringing, while no other call is placed or held.
    pub(super) fn follow_ringing(&self, ringing: Option<&str>) {
        let mut s = lock(&self.shared);
        match (ringing, &s.call.phase) {
            (
                Some(from),
                CallPhase::Ringing {
                    from: f,
                    caller: None,
                },
            ) if f == from => {}
            // The phone's call rings over a direct caller's (who rings again once it is over).
            (Some(from), phase) if !phase.is_active() => {
                s.call.phase = CallPhase::Ringing {
                    from: from.into(),
                    caller: None,
                };
            }
            (None, CallPhase::Ringing { caller: None, .. }) => s.call.phase = CallPhase::Idle,
            _ => {}
        }
    }
}

fn peer_name(peer: &PeerInfo) -> String {
    peer.name
        .clone()
        .filter(|n| !n.trim().is_empty())
        .unwrap_or_else(|| peer.addr.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|n| n.to_string()).collect()
    }

    #[test]
    fn the_phase_names_whom_the_call_is_with_after_a_peer_leaves() {
        assert_eq!(in_call_with("Bob", &names(&["Bob", "Carol"])), None);
        assert_eq!(
            in_call_with("Bob", &names(&["Carol"])).as_deref(),
            Some("Carol"),
            "Bob left, Carol stays"
        );
        assert_eq!(
            in_call_with("Bob", &names(&["Carol", "Dan"])).as_deref(),
            Some("Carol and Dan")
        );
        assert_eq!(
            in_call_with("Carol and Dan", &names(&["Carol", "Dan"])),
            None
        );
        assert_eq!(
            in_call_with("Bob", &names(&["Carol", "Dan", "Eve", "Fay"])).as_deref(),
            Some("Carol, Dan and 2 more")
        );
        assert_eq!(
            in_call_with("127.0.0.1:5004", &names(&["Bob"])).as_deref(),
            Some("Bob"),
            "a name heard late replaces the address"
        );
        assert_eq!(
            in_call_with("Bob", &[]),
            None,
            "nobody heard: the call's end says it"
        );
    }
}

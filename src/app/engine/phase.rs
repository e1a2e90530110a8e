//! The call's phase ([`CallPhase`]), kept by the worker from every link's news, the direct
//! session's peers and the phone's ringing: what the call bar and the `--status` file show.

use std::net::SocketAddr;
use std::time::Instant;

use super::consent::{Caller, in_call_with};
use super::{CallPhase, DIRECT_ANSWER_WAIT, RINGING_ANSWER_WAIT, Worker, lock};
use crate::app::counters::DEMO_NAME;
use crate::net::session::SessionStats;
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
            ringing: false,
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
            let mut heard: Vec<Caller> = infos
                .iter()
                .filter(real)
                .filter(|i| !i.ended && !i.said_bye)
                .map(|i| Caller {
                    addr: i.addr,
                    name: peer_name(i),
                })
                .collect();
            // In the order they called (as their tiles): the first rings, the bar names them so.
            {
                let s = lock(&self.shared);
                heard.sort_by_key(|c| {
                    let joined = s.peers.joined_at(c.addr);
                    (joined.is_none(), joined)
                });
            }
            self.consent.keep_heard(&heard);
            let ringing: Vec<SocketAddr> = heard
                .iter()
                .map(|c| c.addr)
                .filter(|a| !self.consent.is_answered(*a))
                .collect();
            lock(&self.shared).peers.ringing_at(&ringing, now);
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
            (
                CallPhase::Calling {
                    to,
                    deadline,
                    ringing,
                },
                None,
            ) => {
                let far = self
                    .link
                    .session()
                    .map_or(Far::Silent, |s| Far::of(&s.stats()));
                match calling_next(&to, deadline, ringing, far, now) {
                    Some(Next::Phase(next)) => self.set_phase(next),
                    Some(Next::Fail(reason)) => self.fail(reason),
                    None => {}
                }
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

/// What the called app's reports say of a direct call whose media is not heard yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Far {
    Silent,
    Ringing,
    /// Reports name our stream and say no more: a peer that listens (`lipcall receive`, or
    /// an app whose user answered and who is muted) sends no media.
    Answered,
    Declined,
}

impl Far {
    fn of(stats: &SessionStats) -> Self {
        if stats.declined > 0 {
            Self::Declined
        } else if stats.reports_about_us > stats.ringing_reports {
            Self::Answered
        } else if stats.ringing_reports > 0 {
            Self::Ringing
        } else {
            Self::Silent
        }
    }
}

#[derive(Debug, PartialEq, Eq)]
enum Next {
    Phase(CallPhase),
    Fail(String),
}

/// Where a direct call to `to`, placed and not yet heard, goes from what the far end says.
fn calling_next(
    to: &str,
    deadline: Option<Instant>,
    ringing: bool,
    far: Far,
    now: Instant,
) -> Option<Next> {
    match far {
        Far::Declined => Some(Next::Fail(format!("{to} declined the call"))),
        Far::Answered => Some(Next::Phase(CallPhase::InCall {
            with: to.into(),
            since: now,
        })),
        // Ringing there: the wait for an answer starts again, as long as a phone rings.
        Far::Ringing if !ringing => Some(Next::Phase(CallPhase::Calling {
            to: to.into(),
            deadline: Some(now + RINGING_ANSWER_WAIT),
            ringing: true,
        })),
        _ if deadline.is_some_and(|d| now >= d) => Some(Next::Fail(if ringing {
            format!(
                "{to} did not answer within {} s of ringing",
                RINGING_ANSWER_WAIT.as_secs()
            )
        } else {
            format!(
                "nobody answered from {to} within {} s",
                DIRECT_ANSWER_WAIT.as_secs()
            )
        })),
        _ => None,
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
    fn a_direct_call_rings_there_then_is_answered_declined_or_given_up() {
        let start = Instant::now();
        let placed = Some(start + DIRECT_ANSWER_WAIT);
        let at = |s: u64| start + std::time::Duration::from_secs(s);
        assert_eq!(calling_next("bob", placed, false, Far::Silent, at(1)), None);
        let Some(Next::Phase(rings)) = calling_next("bob", placed, false, Far::Ringing, at(2))
        else {
            panic!("ringing there moves the phase");
        };
        assert_eq!(rings.describe(at(2)), "ringing bob…");
        assert_eq!(rings.word(), "calling");
        let CallPhase::Calling { deadline, .. } = rings else {
            panic!("{rings:?}");
        };
        assert_eq!(deadline, Some(at(2) + RINGING_ANSWER_WAIT));
        // Past the first wait it still rings: no failure until the ringing's own wait ends.
        let past = at(2 + DIRECT_ANSWER_WAIT.as_secs());
        assert_eq!(
            calling_next("bob", deadline, true, Far::Ringing, past),
            None
        );
        assert_eq!(
            calling_next("bob", deadline, true, Far::Ringing, at(32)),
            Some(Next::Fail(
                "bob did not answer within 30 s of ringing".into()
            ))
        );
        assert_eq!(
            calling_next("bob", deadline, true, Far::Answered, at(10)),
            Some(Next::Phase(CallPhase::InCall {
                with: "bob".into(),
                since: at(10)
            }))
        );
        assert_eq!(
            calling_next("bob", deadline, true, Far::Declined, at(10)),
            Some(Next::Fail("bob declined the call".into()))
        );
        assert_eq!(
            calling_next("bob", placed, false, Far::Silent, at(15)),
            Some(Next::Fail("nobody answered from bob within 15 s".into()))
        );
    }

    #[test]
    fn reports_tell_how_the_call_stands_there() {
        let stats = |about_us, ringing, declined| SessionStats {
            reports_about_us: about_us,
            ringing_reports: ringing,
            declined,
            ..SessionStats::default()
        };
        assert_eq!(Far::of(&stats(0, 0, 0)), Far::Silent);
        assert_eq!(Far::of(&stats(2, 2, 0)), Far::Ringing);
        assert_eq!(
            Far::of(&stats(3, 2, 0)),
            Far::Answered,
            "rang, then answered"
        );
        assert_eq!(
            Far::of(&stats(1, 0, 0)),
            Far::Answered,
            "a receiver that never rings"
        );
        assert_eq!(Far::of(&stats(2, 2, 1)), Far::Declined);
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

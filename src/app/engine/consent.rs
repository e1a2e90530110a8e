//! The user's consent to a direct caller (issue 46): the listening session hears anyone who
//! sends to its port, but our microphone goes only to the callers the user answered. A caller
//! heard and not answered rings (the phase is [`CallPhase::Ringing`] with its address); one
//! that stops before it is answered is a missed call.
//!
//! A ringing caller is played, as an intercom is: the user hears who it is and what it wants
//! before answering, and what the user says stays in the room until then.

use std::net::SocketAddr;
use std::time::Instant;

use super::CallPhase;
use crate::net::session::MAX_ANSWERED;

/// The direct callers the user answered, at most [`MAX_ANSWERED`]; forgotten when the caller
/// is gone, on Leave and Decline, and when a call is placed.
#[derive(Debug, Default)]
pub(super) struct Consent {
    answered: Vec<SocketAddr>,
    /// When the call with the answered callers began: a caller ringing over the call and
    /// answered too does not start its clock again.
    since: Option<Instant>,
}

/// A direct caller heard now, by address and the name the call bar gives it.
#[derive(Debug, Clone)]
pub(super) struct Caller {
    pub addr: SocketAddr,
    pub name: String,
}

impl Consent {
    /// The user answered `addr`; false (and not answered) when [`MAX_ANSWERED`] already are.
    pub fn answer(&mut self, addr: SocketAddr) -> bool {
        if self.answered.contains(&addr) {
            return true;
        }
        if self.answered.len() >= MAX_ANSWERED {
            return false;
        }
        self.answered.push(addr);
        true
    }

    pub fn forget(&mut self, addr: SocketAddr) {
        self.answered.retain(|a| *a != addr);
        self.over_when_empty();
    }

    pub fn clear(&mut self) {
        self.answered.clear();
        self.since = None;
    }

    fn over_when_empty(&mut self) {
        if self.answered.is_empty() {
            self.since = None;
        }
    }

    pub fn is_answered(&self, addr: SocketAddr) -> bool {
        self.answered.contains(&addr)
    }

    /// Forgets the callers no longer heard: one that comes back rings again.
    pub fn keep_heard(&mut self, heard: &[Caller]) {
        self.answered.retain(|a| heard.iter().any(|c| c.addr == *a));
        self.over_when_empty();
    }

    /// The phase the listening session's callers give, where it changes: the first caller not
    /// answered rings; else the answered ones are in the call; a ringing caller gone is a
    /// missed call, an answered one gone ends the call (`gone` names who said goodbye). A call
    /// being placed and the phone's ringing are left as they are.
    pub fn phase(
        &mut self,
        phase: &CallPhase,
        heard: &[Caller],
        gone: Option<&str>,
        now: Instant,
    ) -> Option<CallPhase> {
        if matches!(
            phase,
            CallPhase::Calling { .. } | CallPhase::Ringing { caller: None, .. }
        ) {
            return None;
        }
        if let Some(ringing) = heard.iter().find(|c| !self.is_answered(c.addr)) {
            let next = CallPhase::Ringing {
                from: ringing.name.clone(),
                caller: Some(ringing.addr),
            };
            return (*phase != next).then_some(next);
        }
        let names: Vec<String> = heard.iter().map(|c| c.name.clone()).collect();
        if !names.is_empty() {
            return match phase {
                CallPhase::InCall { with, since } => {
                    in_call_with(with, &names).map(|with| CallPhase::InCall {
                        with,
                        since: *since,
                    })
                }
                _ => {
                    let since = *self.since.get_or_insert(now);
                    in_call_with("", &names).map(|with| CallPhase::InCall { with, since })
                }
            };
        }
        match phase {
            CallPhase::Ringing { from, .. } => Some(CallPhase::Missed { from: from.clone() }),
            CallPhase::InCall { with, .. } => Some(CallPhase::Ended {
                by: match gone {
                    Some(name) => format!("{name} hung up"),
                    None => format!("{with} went quiet and was dropped"),
                },
            }),
            _ => None,
        }
    }
}

/// Whom a call that is with `with` is with now that `heard` are heard (by name, in join
/// order): `None` while `with` is still among them or nobody is heard.
pub(super) fn in_call_with(with: &str, heard: &[String]) -> Option<String> {
    if heard.iter().any(|h| h == with) {
        return None;
    }
    let now = match heard {
        [one] => one.clone(),
        [one, two] => format!("{one} and {two}"),
        [one, two, three] => format!("{one}, {two} and {three}"),
        [one, two, rest @ ..] => format!("{one}, {two} and {} more", rest.len()),
        [] => return None,
    };
    (now != with).then_some(now)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn caller(port: u16, name: &str) -> Caller {
        Caller {
            addr: SocketAddr::from(([127, 0, 0, 1], port)),
            name: name.into(),
        }
    }

    #[test]
    fn the_answered_set_is_capped_and_forgets_callers_gone() {
        let mut consent = Consent::default();
        let callers: Vec<Caller> = (0..MAX_ANSWERED as u16 + 2)
            .map(|i| caller(4000 + i, "x"))
            .collect();
        for c in &callers[..MAX_ANSWERED] {
            assert!(consent.answer(c.addr));
        }
        assert!(
            consent.answer(callers[0].addr),
            "answered again: no room taken"
        );
        assert!(!consent.answer(callers[MAX_ANSWERED].addr), "capped");
        assert!(!consent.is_answered(callers[MAX_ANSWERED].addr));
        consent.keep_heard(&callers[1..3]);
        assert!(!consent.is_answered(callers[0].addr), "gone: forgotten");
        assert!(consent.is_answered(callers[1].addr) && consent.is_answered(callers[2].addr));
        consent.forget(callers[1].addr);
        assert!(!consent.is_answered(callers[1].addr), "declined");
        consent.clear();
        assert!(!consent.is_answered(callers[2].addr), "left");
    }

    #[test]
    fn a_caller_rings_until_answered_and_is_missed_if_it_stops_first() {
        let now = Instant::now();
        let mut consent = Consent::default();
        let ann = caller(5000, "Ann");
        let ringing = consent
            .phase(&CallPhase::Idle, std::slice::from_ref(&ann), None, now)
            .unwrap();
        assert_eq!(
            ringing,
            CallPhase::Ringing {
                from: "Ann".into(),
                caller: Some(ann.addr)
            }
        );
        assert_eq!(ringing.word(), "ringing");
        assert_eq!(
            consent.phase(&ringing, std::slice::from_ref(&ann), None, now),
            None,
            "keeps ringing while she sends"
        );
        assert_eq!(
            consent.phase(&ringing, &[], None, now),
            Some(CallPhase::Missed { from: "Ann".into() })
        );
        consent.answer(ann.addr);
        let in_call = consent
            .phase(&ringing, std::slice::from_ref(&ann), None, now)
            .unwrap();
        assert!(matches!(&in_call, CallPhase::InCall { with, .. } if with == "Ann"));
        // Another caller rings over the call; the one answered ends it by leaving.
        let bob = caller(5001, "Bob");
        assert!(matches!(
            consent.phase(&in_call, &[ann.clone(), bob.clone()], None, now),
            Some(CallPhase::Ringing { from, .. }) if from == "Bob"
        ));
        // Bob answered too: the call's clock runs on from Ann's answer.
        consent.answer(bob.addr);
        let later = now + std::time::Duration::from_secs(9);
        let bob_ringing = CallPhase::Ringing {
            from: "Bob".into(),
            caller: Some(bob.addr),
        };
        assert_eq!(
            consent.phase(&bob_ringing, &[ann.clone(), bob.clone()], None, later),
            Some(CallPhase::InCall {
                with: "Ann and Bob".into(),
                since: now
            })
        );
        assert_eq!(
            consent.phase(&in_call, &[], Some("Ann"), now),
            Some(CallPhase::Ended {
                by: "Ann hung up".into()
            })
        );
    }

    #[test]
    fn a_call_being_placed_and_the_phone_ringing_are_left_alone() {
        let mut consent = Consent::default();
        let heard = [caller(5000, "Ann")];
        let now = Instant::now();
        let calling = CallPhase::Calling {
            to: "bob.example".into(),
            deadline: None,
            ringing: false,
        };
        assert_eq!(consent.phase(&calling, &heard, None, now), None);
        let sip = CallPhase::Ringing {
            from: "Bob".into(),
            caller: None,
        };
        assert_eq!(consent.phase(&sip, &heard, None, now), None);
        assert_eq!(consent.phase(&CallPhase::Idle, &[], None, now), None);
    }
}

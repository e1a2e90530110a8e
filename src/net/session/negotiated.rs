//! A negotiated call's state beside the session's: when we last sent, the DTMF digits
//! waiting and the one being sent. Its rules are in `super::call` and `super::dtmf`.

use std::collections::VecDeque;
use std::time::Instant;

use super::NegotiatedCall;

/// A digit being sent (`super::dtmf`).
pub(super) struct Digit {
    pub(super) event: u8,
    pub(super) timestamp: u32,
    pub(super) step: u32,
}

/// A negotiated call's state beside the session's.
pub(super) struct CallMedia {
    pub(super) config: NegotiatedCall,
    /// When we last sent media (or a keepalive).
    pub(super) last_sent: Instant,
    pub(super) digits: VecDeque<u8>,
    pub(super) digit: Option<Digit>,
}

impl CallMedia {
    pub(super) fn new(config: NegotiatedCall, now: Instant) -> Self {
        Self {
            config,
            last_sent: now,
            digits: VecDeque::new(),
            digit: None,
        }
    }
}

//! A call that rings, noticed: the ringtone in the mix and the desktop notification while the
//! phase is ringing, both stopped the pass it is not; the notification's Answer and Decline
//! go where the window's buttons go: the phone's for a SIP call, the consent's
//! (`engine/consent.rs`) for a direct caller.

use std::time::Instant;

use super::{CallPhase, Worker, lock};
use crate::app::ring_notice::{NoticeAction, RingNotice};
use crate::app::sip_call::PhoneCommand;

impl Worker {
    /// Each pass: the ringtone and the notification follow the phase.
    pub(super) fn follow_ring(&mut self) {
        let about = {
            let s = lock(&self.shared);
            let about = match &s.call.phase {
                CallPhase::Ringing { from, caller } => Some((from.clone(), *caller)),
                _ => None,
            };
            let testing = self
                .speaker_test_until
                .is_some_and(|until| Instant::now() < until);
            if !testing {
                self.speaker_test_until = None;
            }
            let ringing = testing || about.is_some();
            if s.playback.is_ringing() != ringing {
                s.playback.set_ringing(ringing);
            }
            about
        };
        match (&about, &self.posted) {
            (Some((from, _)), Some(p)) if p.is_about(from) => {}
            (Some((from, _)), _) => self.posted = Some(RingNotice::post(from)),
            (None, Some(_)) => self.posted = None,
            (None, None) => {}
        }
        let Some(action) = self.posted.as_ref().and_then(RingNotice::action) else {
            return;
        };
        tracing::info!("the call's notification: {action:?}");
        if matches!(action, NoticeAction::Answer | NoticeAction::Show) {
            lock(&self.shared).show_window = true;
        }
        let direct = about.and_then(|(_, caller)| caller);
        let result = match (action, direct) {
            (NoticeAction::Show, _) => Ok(()),
            (NoticeAction::Answer, Some(addr)) => self.answer_caller(addr),
            (NoticeAction::Decline, Some(addr)) => {
                self.decline_caller(addr);
                Ok(())
            }
            (NoticeAction::Answer, None) => self.phone_command(PhoneCommand::Answer),
            (NoticeAction::Decline, None) => self.phone_command(PhoneCommand::Decline),
        };
        if let Err(e) = result {
            lock(&self.shared).call.error = Some(format!("{e:#}"));
        }
    }
}

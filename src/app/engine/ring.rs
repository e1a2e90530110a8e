//! A call that rings, noticed: the ringtone in the mix and the desktop notification while the
//! phase is ringing, both stopped the pass it is not; the notification's Answer and Decline
//! go where the window's buttons go. An incoming direct call, connected as soon as it is
//! heard, gets a notification too, whose only action shows the window.

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
                CallPhase::Ringing { from } => Some((from.clone(), true)),
                CallPhase::InCall { with, .. } if s.call.just_arrived() => {
                    Some((with.clone(), false))
                }
                _ => None,
            };
            let testing = self
                .speaker_test_until
                .is_some_and(|until| Instant::now() < until);
            if !testing {
                self.speaker_test_until = None;
            }
            let ringing = testing || about.as_ref().is_some_and(|(_, sip)| *sip);
            if s.playback.is_ringing() != ringing {
                s.playback.set_ringing(ringing);
            }
            about
        };
        match (about, &self.posted) {
            (Some((caller, sip)), Some(p)) if p.is_about(&caller, sip) => {}
            (Some((caller, sip)), _) => self.posted = Some(RingNotice::post(&caller, sip)),
            (None, Some(_)) => self.posted = None,
            (None, None) => {}
        }
        let Some(action) = self.posted.as_ref().and_then(RingNotice::action) else {
            return;
        };
        tracing::info!("the call's notification: {action:?}");
        let command = match action {
            NoticeAction::Answer => PhoneCommand::Answer,
            NoticeAction::Decline => PhoneCommand::Decline,
            NoticeAction::Show => {
                lock(&self.shared).show_window = true;
                return;
            }
        };
        if command == PhoneCommand::Answer {
            lock(&self.shared).show_window = true;
        }
        if let Err(e) = self.phone_command(command) {
            lock(&self.shared).call.error = Some(format!("{e:#}"));
        }
    }
}

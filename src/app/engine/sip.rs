//! The engine's side of the phone ([`crate::app::sip_call`]): a SIP call dialled or answered
//! becomes the worker's link, its encoder follows the codec SDP agreed, its progress is the
//! call's state line, and its end (either side) brings the worker back to idle.

use std::time::Instant;

use super::{CallSpec, CallStatus, Encryption, Worker, lock};
use crate::app::sip_call::{PhoneCommand, PhoneTurn};
use crate::app::timing::RelayWatch;
use crate::codec::any::{EncoderSettings, FrameEncoder};

impl Worker {
    pub(super) fn dial_sip(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        let turn = self.phone.dial(&spec.address);
        self.show_phone();
        self.apply(turn?)
    }

    pub(super) fn phone_command(&mut self, command: PhoneCommand) -> anyhow::Result<()> {
        let turn = self.phone.command(command);
        self.show_phone();
        match turn? {
            Some(turn) => self.apply(turn),
            None => Ok(()),
        }
    }

    /// The SIP call's progress and the listener's callers, each pass of the worker's loop.
    pub(super) fn follow_phone(&mut self) {
        for turn in self.phone.poll(self.in_call, Instant::now()) {
            if let Err(e) = self.apply(turn) {
                lock(&self.shared).call.error = Some(format!("{e:#}"));
            }
        }
        self.show_phone();
    }

    fn show_phone(&self) {
        let status = self.phone.status();
        let mut s = lock(&self.shared);
        if s.phone != *status {
            s.phone = status.clone();
        }
    }

    fn apply(&mut self, turn: PhoneTurn) -> anyhow::Result<()> {
        match turn {
            PhoneTurn::Switch { link, codec, state } => {
                let encoder = FrameEncoder::new(codec, &EncoderSettings::default())?;
                self.switch_link(link, encoder);
                self.relay = RelayWatch::default();
                lock(&self.shared).call = CallStatus {
                    state,
                    in_call: true,
                    codec: Some(codec),
                    ..CallStatus::default()
                };
            }
            PhoneTurn::Status { state, media } => {
                if let Some((codec, srtp)) = media {
                    self.encoder = FrameEncoder::new(codec, &EncoderSettings::default())?;
                    let mut s = lock(&self.shared);
                    s.call.codec = Some(codec);
                    // SDES keys travel in the SIP messages: every proxy on the way has them.
                    s.call.encryption = if srtp {
                        Encryption::HopByHop
                    } else {
                        Encryption::None
                    };
                }
                if let Some(state) = state {
                    lock(&self.shared).call.state = state;
                }
            }
            PhoneTurn::Over(line) => {
                self.leave()?;
                let mut s = lock(&self.shared);
                s.call.state = format!("{line}; {}", s.call.state);
            }
        }
        Ok(())
    }
}

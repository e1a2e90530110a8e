//! The engine's side of the phone ([`crate::app::sip_call`]): a SIP call dialled or answered
//! becomes the worker's link; like every link's, its progress, media and end come through the
//! engine's one route (`engine/news.rs`).

use std::time::Instant;

use super::{CallSpec, CallStatus, Worker, lock};
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

    /// The listener's callers and the keypad, each pass of the worker's loop (the SIP call's
    /// own news comes by the engine's one route, [`Worker::follow_link`]).
    pub(super) fn follow_phone(&mut self) {
        self.phone.poll(self.in_call, Instant::now());
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
        let PhoneTurn {
            link,
            handle,
            peer,
            codec,
            state,
        } = turn;
        let encoder = FrameEncoder::new(codec, &EncoderSettings::default())?;
        self.switch_link(link, encoder);
        self.phone.in_call(handle, peer);
        self.relay = RelayWatch::default();
        self.call_label = "SIP call".into();
        lock(&self.shared).call = CallStatus {
            state,
            in_call: true,
            codec: Some(codec),
            ..CallStatus::default()
        };
        Ok(())
    }
}

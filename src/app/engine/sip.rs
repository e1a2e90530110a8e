//! The engine's side of the phone ([`crate::app::sip_call`]): a SIP call dialled or answered
//! becomes the worker's link; like every link's, its progress, media and end come through the
//! engine's one route (`engine/news.rs`).

use std::net::SocketAddr;
use std::time::Instant;

use super::{CallPhase, CallSpec, CallStatus, Then, Worker, lock};
use crate::app::sip_call::{PhoneCommand, PhoneTurn};
use crate::app::timing::RelayWatch;
use crate::codec::any::{EncoderSettings, FrameEncoder};
use crate::net::host_port::HostPort;
use crate::net::sip::address::bind_towards;

impl Worker {
    /// A SIP call: its host is looked up off the worker, then [`Worker::dial_from`].
    pub(super) fn dial_sip(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        let (target, towards) = self.phone.dial_plan(&spec.address)?;
        if HostPort::parse(&towards).is_ok_and(|h| h.ip().is_some()) {
            let bind = bind_towards(&towards)?;
            return self.dial_from(target, bind);
        }
        let host = towards.clone();
        self.look_up(&host, Then::Sip { target }, move || {
            bind_towards(&towards).map_err(|e| e.to_string())
        })
    }

    /// A SIP call to `target` from `bind`, the local address towards its host.
    pub(super) fn dial_from(&mut self, target: String, bind: SocketAddr) -> anyhow::Result<()> {
        let turn = self.phone.dial_from(target, bind);
        self.show_phone();
        self.apply(turn?)
    }

    pub(super) fn phone_command(&mut self, command: PhoneCommand) -> anyhow::Result<()> {
        // A call answered becomes the link while its ringing is still the phase.
        let applied = match self.phone.command(command) {
            Ok(Some(turn)) => self.apply(turn),
            Ok(None) => Ok(()),
            Err(e) => Err(e),
        };
        self.show_phone();
        applied
    }

    /// The listener's callers and the keypad, each pass of the worker's loop (the SIP call's
    /// own news comes by the engine's one route, [`Worker::follow_link`]).
    pub(super) fn follow_phone(&mut self) {
        self.phone.poll(self.in_call, Instant::now());
        self.show_phone();
    }

    fn show_phone(&self) {
        let status = self.phone.status();
        self.follow_ringing(status.ringing.as_deref());
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
        // A call that rang here was answered; any other was dialled.
        let phase = match lock(&self.shared).call.phase {
            CallPhase::Ringing { .. } => CallPhase::InCall {
                with: peer.clone(),
                since: Instant::now(),
            },
            _ => CallPhase::Calling {
                to: peer.clone(),
                deadline: None,
            },
        };
        self.switch_link(link, encoder);
        self.phone.in_call(handle, peer);
        self.relay = RelayWatch::default();
        self.call_label = "SIP call".into();
        lock(&self.shared).call = CallStatus {
            state,
            in_call: true,
            codec: Some(codec),
            phase,
            ..CallStatus::default()
        };
        Ok(())
    }
}

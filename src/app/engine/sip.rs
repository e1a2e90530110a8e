//! The engine's side of the phone ([`crate::app::sip_call`]): a SIP call dialled or answered
//! becomes the worker's link; like every link's, its progress, media and end come through the
//! engine's one route (`engine/news.rs`).

use std::net::SocketAddr;
use std::sync::{Arc, PoisonError};
use std::time::Instant;

use super::{CallPhase, CallSpec, CallStatus, MediaSlot, Then, Worker, lock};
use crate::app::sip_call::{PhoneCommand, PhoneTurn};
use crate::app::timing::RelayWatch;
use crate::call::sip_sockets::{MediaSockets, bind_media};
use crate::codec::any::{EncoderSettings, FrameEncoder};
use crate::net::host_port::HostPort;
use crate::net::sip::address::bind_towards;

impl Worker {
    /// A SIP call: its host is looked up off the worker, then [`Worker::dial_from`].
    pub(super) fn dial_sip(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        let (target, towards) = self.phone.dial_plan(&spec.address)?;
        let stun = self.phone.stun();
        let literal = HostPort::parse(&towards).is_ok_and(|h| h.ip().is_some());
        if literal && stun.is_none() {
            // Binding towards an address is a socket's connect: nothing is asked or waited on.
            let bind = bind_towards(&towards)?;
            let media = bind_media(bind, None)?;
            return self.dial_from(target, bind, media);
        }
        let host = towards.clone();
        let media = MediaSlot::default();
        let then = Then::Sip {
            target,
            media: Arc::clone(&media),
        };
        self.look_up(&host, then, move || {
            let bind = bind_towards(&towards).map_err(|e| e.to_string())?;
            let bound = bind_media(bind, stun.as_deref()).map_err(|e| e.to_string())?;
            *media.lock().unwrap_or_else(PoisonError::into_inner) = Some(bound);
            Ok(bind)
        })?;
        if literal {
            lock(&self.shared).call.state = "asking the STUN server for our media address…".into();
        }
        Ok(())
    }

    /// A SIP call to `target` from `bind`, the local address towards its host, with its media
    /// on `media`.
    pub(super) fn dial_from(
        &mut self,
        target: String,
        bind: SocketAddr,
        media: MediaSockets,
    ) -> anyhow::Result<()> {
        let turn = self.phone.dial_from(target, bind, media);
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
                ringing: false,
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

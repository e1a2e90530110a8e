//! Placing a lipcall call (direct, or a relay's room) and joining a Janus room: each becomes
//! the worker's link.

use std::net::SocketAddr;
use std::time::Instant;

use super::{CallPhase, CallSpec, CallStatus, DIRECT_ANSWER_WAIT, Encryption, ROOM, Worker, lock};
use crate::app::timing::RelayWatch;
use crate::call::janus::JanusLink;
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::net::janus::room::RoomConfig;
use crate::net::jitter::JitterConfig;
use crate::net::session::{Session, SessionConfig};
use crate::net::srtp::MasterKey;

impl Worker {
    /// A call (or a relay's room) at `to`, an address found.
    pub(super) fn call_direct(&mut self, spec: &CallSpec, to: SocketAddr) -> anyhow::Result<()> {
        let room = spec.room.clone().filter(|r| !r.trim().is_empty());
        let key = spec
            .passphrase
            .as_deref()
            .filter(|p| !p.is_empty())
            .map(|p| MasterKey::from_passphrase(p, room.as_deref().unwrap_or("")));
        // A fresh port: the listening session still holds its own until replaced.
        let bind = if to.ip().is_loopback() {
            SocketAddr::new(to.ip(), 0)
        } else if to.is_ipv4() {
            SocketAddr::from(([0, 0, 0, 0], 0))
        } else {
            SocketAddr::from((std::net::Ipv6Addr::UNSPECIFIED, 0))
        };
        let settings = spec.encoder_settings();
        let encoder = FrameEncoder::new(spec.codec, &settings)?;
        let mut sc = SessionConfig::new(bind);
        sc.destinations = vec![to];
        sc.room = room.clone();
        sc.key = key;
        sc.codec = spec.codec;
        sc.name = Some(self.call_name(spec));
        let session = Session::start(sc)?;
        let encryption = if session.encrypted() {
            Encryption::EndToEnd
        } else {
            Encryption::None
        };
        let local_addr = session.local_addr().ok();
        self.switch_link(Box::new(session), encoder);
        self.relay = match room {
            Some(_) => RelayWatch::joining(Instant::now()),
            None => RelayWatch::default(),
        };
        let now = Instant::now();
        let phase = match &room {
            Some(r) => {
                self.call_label = format!("{ROOM} {r:?}");
                CallPhase::InCall {
                    with: format!("room {r:?}"),
                    since: now,
                }
            }
            None => CallPhase::Calling {
                to: to.to_string(),
                deadline: Some(now + DIRECT_ANSWER_WAIT),
            },
        };
        let mut s = lock(&self.shared);
        s.call = CallStatus {
            phase,
            state: match &room {
                Some(r) => format!("in room {r:?} on relay {to}, sending {}", spec.codec),
                None => format!("calling {to}, sending {}", spec.codec),
            },
            in_call: true,
            encryption,
            codec: Some(spec.codec),
            local_addr,
            error: None,
            unknown_payload: 0,
            arrived: None,
        };
        Ok(())
    }

    /// A room on a Janus server: WebRTC speaks Opus, whatever the settings' codec.
    pub(super) fn join_janus(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        let room = spec
            .room
            .clone()
            .filter(|r| !r.trim().is_empty())
            .ok_or_else(|| anyhow::anyhow!("a Janus server needs a room name"))?;
        let config = RoomConfig {
            url: spec.address.trim().to_owned(),
            auth: spec.janus_auth.clone(),
            room,
            name: self.call_name(spec),
            pin: spec.passphrase.clone().filter(|p| !p.is_empty()),
            subscribe: true,
            jitter: JitterConfig::default(),
            ice: spec.ice.clone(),
        };
        let janus = JanusLink::join(config)?;
        let state = format!("joining {}…", janus.place());
        let settings = spec.encoder_settings();
        let encoder = FrameEncoder::new(Codec::Opus, &settings)?;
        self.switch_link(Box::new(janus), encoder);
        self.relay = RelayWatch::default();
        self.call_label = "Janus room".into();
        let mut s = lock(&self.shared);
        s.call = CallStatus {
            state,
            in_call: true,
            encryption: Encryption::HopByHop,
            codec: Some(Codec::Opus),
            local_addr: None,
            error: None,
            unknown_payload: 0,
            arrived: None,
            phase: s.call.phase.clone(),
        };
        Ok(())
    }
}

impl CallSpec {
    /// Our encoder's settings in this call: Opus's band and frame length (any length but 10
    /// is 20).
    pub fn encoder_settings(&self) -> EncoderSettings {
        let mut settings = EncoderSettings::wideband(self.bandwidth);
        settings.opus.frame_ms = if self.frame_ms == 10 { 10 } else { 20 };
        settings
    }
}

//! Placing a lipcall call (direct, or a relay's room) and joining a Janus room: each becomes
//! the worker's link.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant;

use super::{
    CallPhase, CallSpec, CallStatus, DIRECT_ANSWER_WAIT, Encryption, KeySlot, ROOM, Then, Worker,
    lock,
};
use crate::app::timing::RelayWatch;
use crate::call::janus::JanusLink;
use crate::codec::any::{Codec, EncoderSettings, FrameEncoder};
use crate::net::host_port::{HostPort, resolve_with_port};
use crate::net::janus::room::{RoomConfig, server_addr};
use crate::net::janus::url::JanusUrl;
use crate::net::jitter::JitterConfig;
use crate::net::session::{Session, SessionConfig};
use crate::net::srtp::MasterKey;

impl Worker {
    /// A direct call (or a relay's room) to `spec.address`. Its host is looked up, and a
    /// passphrase's room key derived (100,000 PBKDF2 rounds: half a second on a slow machine),
    /// off the worker; an address without either is called at once.
    pub(super) fn place_direct(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        let host = HostPort::parse(spec.address.trim())?;
        if host.port.is_none() {
            anyhow::bail!(crate::app::listen::give_the_port(&host));
        }
        let passphrase = spec.passphrase.clone().filter(|p| !p.is_empty());
        if host.ip().is_some() && passphrase.is_none() {
            let to = resolve_with_port(&spec.address)?;
            return self.call_direct(spec, to, None);
        }
        let address = spec.address.clone();
        let room = spec.room.clone().filter(|r| !r.trim().is_empty());
        let key = KeySlot::default();
        let then = Then::Direct(Box::new(spec.clone()), Arc::clone(&key));
        let named = host.ip().is_none();
        self.look_up(&host.host, then, move || {
            let at = resolve_with_port(&address).map_err(|e| e.to_string())?;
            if let Some(p) = passphrase {
                key.get_or_init(|| MasterKey::from_passphrase(&p, room.as_deref().unwrap_or("")));
            }
            Ok(at)
        })?;
        if !named {
            lock(&self.shared).call.state = "deriving the room key…".into();
        }
        Ok(())
    }

    /// A call (or a relay's room) at `to`, an address found.
    pub(super) fn call_direct(
        &mut self,
        spec: &CallSpec,
        to: SocketAddr,
        key: Option<MasterKey>,
    ) -> anyhow::Result<()> {
        let room = spec.room.clone().filter(|r| !r.trim().is_empty());
        if key.is_none() && spec.passphrase.as_deref().is_some_and(|p| !p.is_empty()) {
            anyhow::bail!("the room key was not derived");
        }
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
        self.blocked.lift(to);
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
                ringing: false,
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
        };
        Ok(())
    }

    /// A room on a Janus server, once its host is found (off the worker where it has a name).
    pub(super) fn join_janus(&mut self, spec: &CallSpec) -> anyhow::Result<()> {
        janus_room(spec)?;
        let url = spec.address.trim().to_owned();
        let parsed = JanusUrl::parse(&url)?;
        let host = HostPort {
            host: parsed.host,
            port: Some(parsed.port),
        };
        if host.ip().is_none() {
            let then = Then::Janus(Box::new(spec.clone()));
            return self.look_up(&host.host, then, move || {
                server_addr(&url).map_err(|e| e.to_string())
            });
        }
        self.join_janus_at(spec, server_addr(&url)?)
    }

    /// A room on the Janus server at `server`: WebRTC speaks Opus, whatever the settings' codec.
    pub(super) fn join_janus_at(
        &mut self,
        spec: &CallSpec,
        server: SocketAddr,
    ) -> anyhow::Result<()> {
        let room = janus_room(spec)?;
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
        let janus = JanusLink::start_at(config, true, server)?;
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
            phase: s.call.phase.clone(),
        };
        Ok(())
    }
}

fn janus_room(spec: &CallSpec) -> anyhow::Result<String> {
    spec.room
        .clone()
        .filter(|r| !r.trim().is_empty())
        .ok_or_else(|| anyhow::anyhow!("a Janus server needs a room name"))
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

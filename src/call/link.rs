//! A call's transport as the receive side sees it: decoded frames of every remote peer pulled
//! on the output clock, the peers described, our own frames sent. lipcall's session (a direct
//! call or a relay room), a Janus room, a Mumble channel and a SIP call implement it; the app's
//! worker and `receive` drive any of them alike, and learn what happened from [`Link::poll`]
//! alone. What only one transport can do is asked of a handle the link gives out.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::codec::any::Codec;
use crate::net::session::Session;
use crate::net::transport::{PeerFrame, PeerInfo};

/// What a link did since the last poll, for the caller to show.
#[derive(Debug, Clone, PartialEq)]
pub enum LinkEvent {
    /// In the call (`place`: where, as the status shows it) as `id`.
    Joined {
        place: String,
        id: String,
    },
    /// The first join failed: the call is over.
    Failed(String),
    /// A peer started sending (`id`: the transport's name for it).
    PeerJoined {
        id: String,
        name: String,
    },
    PeerLeft {
        id: String,
        name: String,
    },
    /// A peer that cannot be heard (it sends no codec we have); the call goes on without it.
    PeerSkipped {
        id: String,
        name: String,
        reason: String,
    },
    /// The call was lost (the server restarted or is unreachable); getting it back.
    Lost {
        reason: String,
    },
    /// An attempt to get it back failed (said once per distinct reason).
    RejoinFailed {
        reason: String,
    },
    /// Back in the call, as `id`.
    Rejoined {
        id: String,
    },
    /// Said by the other side, changing nothing (a text message, how voice travels).
    Note(String),
    /// A request of ours refused (a channel move, a rejoin); the call goes on.
    Refusal(String),
    /// The call, once in, is over for good (removed, the server no longer the one trusted):
    /// why, as a whole sentence.
    Over {
        reason: String,
    },
    /// How the call is getting on while it is set up (dialling, ringing, media agreed): for
    /// the call's state line.
    Progress(String),
    /// The called party's phone rings (a SIP 180): the call is not answered yet.
    Ringing,
    /// What our audio must now be sent in, and whether the media is encrypted (hop by hop:
    /// SDES keys travel in the signalling).
    Media {
        codec: Codec,
        srtp: bool,
    },
    /// The call ended as calls do (a hang-up): said, not an error.
    Ended {
        reason: String,
    },
}

impl LinkEvent {
    /// The call is over: nothing more will come.
    pub fn ends_call(&self) -> bool {
        matches!(
            self,
            LinkEvent::Failed(_) | LinkEvent::Over { .. } | LinkEvent::Ended { .. }
        )
    }
}

/// How waiting for a link's join (on its own thread) ended.
#[derive(Debug)]
pub enum JoinWait<T, E> {
    /// Joined: what the join has to tell.
    Joined(T),
    Failed(E),
    /// The stop flag was set first.
    Stopped,
    /// The deadline passed first.
    TimedOut,
}

/// How often a join's end, the stop flag and the deadline are looked at.
const JOIN_LOOK: Duration = Duration::from_millis(10);

/// Asks `finished` until it has the join's outcome, `stop` is set or `until` passes, whichever
/// comes first: a server that never answers holds neither a signal nor a deadline.
pub fn wait_for_join<T, E>(
    stop: &AtomicBool,
    until: Option<Instant>,
    mut finished: impl FnMut() -> Option<Result<T, E>>,
) -> JoinWait<T, E> {
    loop {
        match finished() {
            Some(Ok(joined)) => return JoinWait::Joined(joined),
            Some(Err(e)) => return JoinWait::Failed(e),
            None => {}
        }
        if stop.load(Ordering::Relaxed) {
            return JoinWait::Stopped;
        }
        let now = Instant::now();
        match until {
            Some(until) if now >= until => return JoinWait::TimedOut,
            Some(until) => std::thread::sleep(JOIN_LOOK.min(until - now)),
            None => std::thread::sleep(JOIN_LOOK),
        }
    }
}

/// One call's transport.
pub trait Link: Send {
    /// The next 20 ms (starting at `now` on the output clock) of every peer that is playing.
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>);

    /// Every remote peer, described (name, address, codec, reception statistics).
    fn peers(&self) -> Vec<PeerInfo>;

    /// Those who are in the call but have sent nothing yet, where the link knows them (the
    /// users of our Mumble channel): the app shows them too, with a still head.
    fn silent_members(&self) -> Vec<PeerInfo> {
        Vec::new()
    }

    /// Every peer that came has left (asked once someone played): a receive ends there.
    fn all_left(&self) -> bool;

    /// Sends one encoded payload of our own audio lasting `ticks` of its codec's RTP clock
    /// (what [`crate::codec::any::FrameEncoder::encode`] says).
    fn send_audio(&mut self, payload: &[u8], ticks: u32);

    /// Frames not sent (the microphone gate was closed): our stream's clock moves on.
    fn skip_frames(&mut self, frames: u32);

    /// RTP packets of payload types nobody mapped, dropped.
    fn unknown_payload(&self) -> u64;

    /// Hangs up (a second call does nothing).
    fn leave(&mut self);

    /// What happened since the last call (joins, losses, peers coming and going).
    fn poll(&mut self) -> Vec<LinkEvent> {
        Vec::new()
    }

    /// The call is over for good (hung up, refused): nothing more will come, whether or not
    /// anyone was heard. Links that wait for peers to come say no.
    fn over(&self) -> bool {
        false
    }

    /// Where peers can reach us directly, if they can.
    fn local_addr(&self) -> Option<SocketAddr> {
        None
    }

    /// lipcall's own RTP session underneath, where the link runs on one (its relay handshake,
    /// its statistics).
    fn session(&self) -> Option<&Session> {
        None
    }
}

impl Link for Session {
    fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        Session::pull(self, now, out);
    }

    fn peers(&self) -> Vec<PeerInfo> {
        Session::peers(self)
    }

    /// Peers that said BYE are left, and so are peers the session forgot (silent for its peer
    /// timeout).
    fn all_left(&self) -> bool {
        Session::peers(self).iter().all(|p| p.said_bye)
    }

    fn send_audio(&mut self, payload: &[u8], ticks: u32) {
        if let Err(e) = Session::send_packet(self, payload, ticks) {
            tracing::debug!("send: {e}");
        }
    }

    fn skip_frames(&mut self, frames: u32) {
        Session::skip_frames(self, frames);
    }

    fn unknown_payload(&self) -> u64 {
        self.stats().unknown_payload
    }

    fn leave(&mut self) {
        Session::leave(self);
    }

    fn local_addr(&self) -> Option<SocketAddr> {
        Session::local_addr(self).ok()
    }

    fn session(&self) -> Option<&Session> {
        Some(self)
    }
}

//! Where a negotiated call's plain RTP or RTCP may come from (issue 43): anyone can send
//! datagrams to our port and plain RTP proves nothing about its sender, so before the peer's
//! first believed packet only the address its description named is taken (and what the caller
//! vouches for besides, such as the IP its signalling comes from); that packet fixes the
//! source, ours go there, and no later packet moves it. Only the peer naming a new address (a
//! re-INVITE) opens it again. The SIP call's RTP and its RTCP each keep one.

use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

/// RTP from other sources than a fixed call's is said at most once a second, and from the
/// same source again only after this long.
const STRAY_WARNING_EVERY: Duration = Duration::from_secs(10);
const STRAY_WARNING_NEW_SOURCE: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SourceLatch {
    /// Where the peer said its stream comes from, and where ours goes until it is latched.
    named: SocketAddr,
    /// Where its first believed packet came from.
    latched: Option<SocketAddr>,
}

impl SourceLatch {
    pub fn new(named: SocketAddr) -> Self {
        Self {
            named,
            latched: None,
        }
    }

    /// Where ours go: the latched source, else the address named.
    pub fn target(&self) -> SocketAddr {
        self.latched.unwrap_or(self.named)
    }

    pub fn latched(&self) -> Option<SocketAddr> {
        self.latched
    }

    /// Whether a packet from `from` may be the peer's: once latched, from the source only;
    /// before, from the address named or where `vouched` says.
    pub fn admits(&self, from: SocketAddr, vouched: impl FnOnce(SocketAddr) -> bool) -> bool {
        match self.latched {
            Some(source) => from == source,
            None => from == self.named || vouched(from),
        }
    }

    /// A believed packet came from `from` (one [`Self::admits`], or an authenticated one).
    pub fn latch(&mut self, from: SocketAddr) {
        self.latched = Some(from);
    }

    /// The peer named another address: the source is open to it again.
    pub fn rename(&mut self, named: SocketAddr) {
        self.named = named;
        self.latched = None;
    }
}

/// Where a session's peers may send from, and whether they may move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Latch {
    /// lipcall's own calls: any source may become a peer, each peer is pinned to the address
    /// its media came from, and it moves after a few packets continuing its sequence from a
    /// new address while the old one is quiet (a NAT rebinding, a roaming device).
    #[default]
    Rebinding,
    /// A negotiated two-party call (SIP): before the first packet only the addresses its
    /// description named; then the first source is kept for the call and nothing moves it
    /// (only the peer naming new addresses). Everything else is counted and dropped.
    Fixed(Named),
}

/// What a negotiated call's description named: where its RTP and RTCP come from and ours go,
/// and the IP its signalling comes from, whose every port is vouched for until the first
/// packet (a symmetric-RTP peer behind a NAT whose description gives its private address).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Named {
    pub rtp: SocketAddr,
    pub rtcp: SocketAddr,
    pub signalling: Option<IpAddr>,
}

/// The [`Latch::Fixed`] rule of one call: a [`SourceLatch`] for its RTP and one for its RTCP.
#[derive(Debug, Clone)]
pub(crate) struct FixedSources {
    pub(crate) rtp: SourceLatch,
    pub(crate) rtcp: SourceLatch,
    signalling: Option<IpAddr>,
    /// When stray RTP was last said and whose, and how many packets came since.
    stray_said: Option<(Instant, SocketAddr)>,
    stray_unsaid: u64,
}

impl FixedSources {
    pub(crate) fn new(named: Named) -> Self {
        Self {
            rtp: SourceLatch::new(named.rtp),
            rtcp: SourceLatch::new(named.rtcp),
            signalling: named.signalling,
            stray_said: None,
            stray_unsaid: 0,
        }
    }

    /// Whether RTP from `from` may be the peer's. An `authenticated` call (SRTP) takes its
    /// first packet from anywhere: only the keyed peer can make one.
    pub(crate) fn admits_rtp(&self, from: SocketAddr, authenticated: bool) -> bool {
        let signalling = self.signalling;
        self.rtp
            .admits(from, |from| authenticated || Some(from.ip()) == signalling)
    }

    /// Whether RTCP from `from` may be the peer's: as RTP, and before its first report also
    /// from the IP its RTP is latched to.
    pub(crate) fn admits_rtcp(&self, from: SocketAddr, authenticated: bool) -> bool {
        let (signalling, rtp) = (self.signalling, self.rtp.latched());
        self.rtcp.admits(from, |from| {
            authenticated
                || Some(from.ip()) == signalling
                || rtp.is_some_and(|s| s.ip() == from.ip())
        })
    }

    /// The peer named new addresses (a re-INVITE): each one changed is open again.
    pub(crate) fn rename(&mut self, named: Named) {
        if named.rtp != self.rtp.named {
            self.rtp.rename(named.rtp);
        }
        if named.rtcp != self.rtcp.named {
            self.rtcp.rename(named.rtcp);
        }
        self.signalling = named.signalling;
    }

    /// RTP from another source than the call's, dropped: said in a warning naming the source,
    /// a new source at most once a second, the same again after [`STRAY_WARNING_EVERY`].
    pub(crate) fn stray(&mut self, what: &str, from: SocketAddr, now: Instant) {
        self.stray_unsaid += 1;
        if let Some((said, whose)) = self.stray_said {
            let quiet = if whose == from {
                STRAY_WARNING_EVERY
            } else {
                STRAY_WARNING_NEW_SOURCE
            };
            if now.saturating_duration_since(said) < quiet {
                return;
            }
        }
        let expected = if let Some(source) = self.rtp.latched() {
            format!("the call's media comes from {source}")
        } else {
            let signalling = self
                .signalling
                .map(|ip| format!(" or from its signalling's IP {ip}"))
                .unwrap_or_default();
            format!(
                "the call's media is taken only from the address its description named, {}{signalling}",
                self.rtp.target()
            )
        };
        let count = match self.stray_unsaid {
            1 => String::new(),
            n => format!(" ({n} packets from other sources since the last warning)"),
        };
        tracing::warn!("{what} from {from} dropped{count}: {expected}");
        self.stray_said = Some((now, from));
        self.stray_unsaid = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_believed_packet_fixes_the_source_until_the_peer_names_another() {
        let named: SocketAddr = "192.0.2.1:4000".parse().unwrap();
        let nat: SocketAddr = "198.51.100.1:5000".parse().unwrap();
        let stranger: SocketAddr = "203.0.113.9:4000".parse().unwrap();
        let mut latch = SourceLatch::new(named);
        let from_nat = |from: SocketAddr| from.ip() == nat.ip();
        assert!(latch.admits(named, |_| false) && latch.admits(nat, from_nat));
        assert!(!latch.admits(stranger, from_nat));
        assert_eq!(latch.target(), named);
        latch.latch(nat);
        assert_eq!((latch.target(), latch.latched()), (nat, Some(nat)));
        assert!(
            !latch.admits(named, |_| true),
            "no longer the named address"
        );
        latch.rename(stranger);
        assert!(latch.admits(stranger, |_| false) && !latch.admits(nat, |_| false));
        assert_eq!(latch.target(), stranger);
    }
}

//! Where a negotiated call's plain RTP or RTCP may come from (issue 43): anyone can send
//! datagrams to our port and plain RTP proves nothing about its sender, so before the peer's
//! first believed packet only the address its description named is taken (and what the caller
//! vouches for besides, such as the IP its signalling comes from); that packet fixes the
//! source, ours go there, and no later packet moves it. Only the peer naming a new address (a
//! re-INVITE) opens it again. The SIP call's RTP and its RTCP each keep one.

use std::net::SocketAddr;

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

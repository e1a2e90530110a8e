//! Callers the user hung up on: a direct caller cannot be refused first, and a sender that
//! keeps sending would be a peer again at its next packet. Each address is kept out until it
//! has been quiet for [`BLOCK_QUIET`], or [`BLOCK_LONGEST`] at most; the table holds
//! [`BLOCKS_KEPT`] addresses, the oldest making room.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// A blocked caller quiet this long may call again.
pub const BLOCK_QUIET: Duration = Duration::from_secs(10);
/// No block lasts longer: a caller the user left a minute ago is heard again.
pub const BLOCK_LONGEST: Duration = Duration::from_secs(60);
/// Addresses blocked at once at most.
pub const BLOCKS_KEPT: usize = 16;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Block {
    addr: SocketAddr,
    since: Instant,
    last_heard: Instant,
}

impl Block {
    fn over(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.last_heard) >= BLOCK_QUIET
            || now.saturating_duration_since(self.since) >= BLOCK_LONGEST
    }
}

/// The addresses kept out of a session.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Blocked {
    blocks: Vec<Block>,
}

impl Blocked {
    /// Keeps `addr` out from `now` (again, if it was).
    pub fn block(&mut self, addr: SocketAddr, now: Instant) {
        self.expire(now);
        self.blocks.retain(|b| b.addr != addr);
        if self.blocks.len() >= BLOCKS_KEPT
            && let Some(oldest) = (0..self.blocks.len()).min_by_key(|&i| self.blocks[i].since)
        {
            self.blocks.swap_remove(oldest);
        }
        self.blocks.push(Block {
            addr,
            since: now,
            last_heard: now,
        });
    }

    /// Whether a datagram from `from` at `now` is let in; one kept out keeps its block alive.
    pub fn admits(&mut self, from: SocketAddr, now: Instant) -> bool {
        let Some(i) = self.blocks.iter().position(|b| b.addr == from) else {
            return true;
        };
        if self.blocks[i].over(now) {
            self.blocks.swap_remove(i);
            return true;
        }
        self.blocks[i].last_heard = now;
        false
    }

    /// The user called `addr`: it is let in again.
    pub fn lift(&mut self, addr: SocketAddr) {
        self.blocks.retain(|b| b.addr != addr);
    }

    /// Forgets the blocks that are over at `now`.
    pub fn expire(&mut self, now: Instant) {
        self.blocks.retain(|b| !b.over(now));
    }

    pub fn len(&self) -> usize {
        self.blocks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([192, 0, 2, 1], port))
    }

    #[test]
    fn a_sender_that_keeps_sending_stays_out_until_a_minute_has_passed() {
        let t0 = Instant::now();
        let mut blocked = Blocked::default();
        blocked.block(addr(1), t0);
        assert!(blocked.admits(addr(2), t0), "another address");
        let mut t = t0;
        while t < t0 + BLOCK_LONGEST - Duration::from_secs(1) {
            assert!(!blocked.admits(addr(1), t), "kept out at {:?}", t - t0);
            t += Duration::from_secs(1);
        }
        assert!(blocked.admits(addr(1), t0 + BLOCK_LONGEST));
        assert!(blocked.is_empty());
    }

    #[test]
    fn a_quiet_caller_may_call_again_and_a_call_to_it_lifts_its_block() {
        let t0 = Instant::now();
        let mut blocked = Blocked::default();
        blocked.block(addr(1), t0);
        assert!(!blocked.admits(addr(1), t0 + Duration::from_secs(5)));
        assert!(!blocked.admits(addr(1), t0 + Duration::from_secs(14)));
        assert!(blocked.admits(addr(1), t0 + Duration::from_secs(24)));
        blocked.block(addr(1), t0);
        blocked.lift(addr(1));
        assert!(blocked.admits(addr(1), t0));
    }

    #[test]
    fn the_table_is_capped_and_the_oldest_make_room() {
        let t0 = Instant::now();
        let mut blocked = Blocked::default();
        for port in 0..BLOCKS_KEPT as u16 * 4 {
            blocked.block(addr(port), t0 + Duration::from_millis(u64::from(port)));
        }
        assert_eq!(blocked.len(), BLOCKS_KEPT);
        let now = t0 + Duration::from_secs(1);
        assert!(blocked.admits(addr(0), now), "the oldest made room");
        assert!(!blocked.admits(addr(BLOCKS_KEPT as u16 * 4 - 1), now));
        blocked.expire(t0 + BLOCK_LONGEST + Duration::from_secs(1));
        assert!(blocked.is_empty());
    }
}

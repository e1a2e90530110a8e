//! What comes in: media that makes and feeds peers, and RTCP about them, each pinned to the
//! address its media came from.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Instant;

use super::protocol::SessionCore;
use super::remote::{IDLE_EVICT, PENDING_NAMES, PENDING_STARTS, Peer, UNCONFIRMED_TIMEOUT};
use crate::net::peer::PeerReceiver;
use crate::net::rtcp::{self, HeardReports, RtcpItem};
use crate::net::rtp::{self, Rtp};
use crate::net::srtp::{Srtp, SrtpError};

impl SessionCore {
    /// Decrypts `data` in place with `f`, if the session has a key; false (and counted) if it
    /// is not to be read.
    fn unprotect(
        &mut self,
        data: &mut Vec<u8>,
        f: fn(&mut Srtp, &mut Vec<u8>) -> Result<(), SrtpError>,
    ) -> bool {
        let Some(srtp) = self.rx_srtp.as_mut() else {
            return true;
        };
        match f(srtp, data) {
            Ok(()) => true,
            Err(SrtpError::Replay) => {
                self.stats.replayed += 1;
                false
            }
            Err(SrtpError::Stale) => {
                self.stats.stale += 1;
                false
            }
            Err(SrtpError::AuthFailed) => {
                self.stats.auth_failed += 1;
                false
            }
            Err(_) => {
                self.stats.malformed += 1;
                false
            }
        }
    }

    /// Makes room for a new peer: an unconfirmed one goes, else one that has sent no media for
    /// `IDLE_EVICT`; a talking peer never does. Of the unconfirmed, the oldest of the address
    /// holding the most goes: one socket churning new SSRCs only ever evicts its own, so a
    /// caller from elsewhere lives to confirm. False if there is no room.
    fn make_room(&mut self, now: Instant) -> bool {
        if self.peers.len() < self.config.max_peers {
            return true;
        }
        let mut unconfirmed_at: HashMap<SocketAddr, usize> = HashMap::new();
        for p in self.peers.values().filter(|p| !p.confirmed()) {
            *unconfirmed_at.entry(p.addr).or_default() += 1;
        }
        let victim = self
            .peers
            .iter()
            .filter(|(_, p)| {
                !p.confirmed() || now.saturating_duration_since(p.last_media) >= IDLE_EVICT
            })
            .min_by_key(|(_, p)| {
                let crowd = if p.confirmed() {
                    0
                } else {
                    unconfirmed_at.get(&p.addr).copied().unwrap_or(0)
                };
                (p.confirmed(), std::cmp::Reverse(crowd), p.last_media)
            })
            .map(|(&ssrc, _)| ssrc);
        let Some(ssrc) = victim else {
            self.stats.too_many_peers += 1;
            return false;
        };
        self.peers.remove(&ssrc);
        self.stats.evicted += 1;
        true
    }

    /// A new peer from its first media packet, if it is media a mapped codec can read.
    fn new_peer(&mut self, packet: &Rtp<'_>, from: SocketAddr, arrival: Instant) -> bool {
        let readable = self
            .config
            .payloads
            .codec(packet.header.payload_type)
            .is_some_and(|c| c.payload_duration(packet.payload).is_some());
        if !readable {
            self.stats.unknown_payload += 1;
            return false;
        }
        if !self.make_room(arrival) {
            return false;
        }
        let ssrc = packet.header.ssrc;
        // A fixed call's reports come from a port of their own, admitted as the call's.
        let fixed = self.fixed.is_some();
        let mut receiver = PeerReceiver::with_payloads(
            self.config.jitter,
            self.epoch,
            self.config.enhancer,
            self.config.payloads.clone(),
        );
        if let Some(i) = self
            .pending_starts
            .iter()
            .position(|&(s, _, addr, _)| s == ssrc && (addr == from || fixed))
        {
            let (_, ts, _, _) = self.pending_starts.swap_remove(i);
            receiver.jitter().hint_start(ts);
        }
        let (cname, name) = match self
            .pending_names
            .iter()
            .position(|(s, addr, ..)| *s == ssrc && (*addr == from || fixed))
        {
            Some(i) => {
                let (_, _, cname, name, _) = self.pending_names.swap_remove(i);
                (cname, name)
            }
            None => (None, None),
        };
        self.peers.insert(
            ssrc,
            Peer {
                receiver,
                addr: from,
                cname,
                name,
                last_heard: arrival,
                last_media: arrival,
                media: 0,
                candidate: None,
                reports: HeardReports::default(),
                said_bye: false,
            },
        );
        true
    }

    /// Whether a [`super::latch::Latch::Fixed`] call takes RTP (or RTCP) from `from`; what it
    /// does not take is counted and said once.
    fn fixed_admits(&mut self, from: SocketAddr, rtcp: bool, now: Instant) -> bool {
        let authenticated = self.rx_srtp.is_some();
        let Some(fixed) = self.fixed.as_mut() else {
            return true;
        };
        let admitted = if rtcp {
            fixed.admits_rtcp(from, authenticated)
        } else {
            fixed.admits_rtp(from, authenticated)
        };
        if !admitted {
            self.stats.foreign += 1;
            if rtcp {
                self.stats.foreign_rtcp += 1;
                tracing::debug!("RTCP from {from} not believed: not the call's peer");
            } else {
                let what = if authenticated { "SRTP" } else { "plain RTP" };
                fixed.stray(what, from, now);
            }
        }
        admitted
    }

    pub(super) fn handle_rtp(&mut self, data: &mut Vec<u8>, from: SocketAddr, arrival: Instant) {
        if !self.fixed_admits(from, false, arrival) || !self.unprotect(data, Srtp::unprotect_rtp) {
            return;
        }
        let packet = match rtp::parse(data, None) {
            Ok(p) => p,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        let ssrc = packet.header.ssrc;
        // A negotiated call's one peer may echo our own stream back (SIPp's echo does).
        if ssrc == self.ssrc && self.call.is_none() {
            self.stats.own += 1;
            return;
        }
        if !self.call_takes(&packet, arrival) {
            return;
        }
        self.stats.rtp += 1;
        if !self.peers.contains_key(&ssrc) && !self.new_peer(&packet, from, arrival) {
            return;
        }
        let Some(peer) = self.peers.get_mut(&ssrc) else {
            return;
        };
        if let Some(fixed) = self.fixed.as_mut() {
            // Admitted above: the call's source, or its first packet, which fixes it.
            fixed.rtp.latch(from);
            peer.addr = from;
        } else if peer.addr == from {
            peer.candidate = None;
        } else if peer.said_bye {
            // A redial may come from anywhere; a straggler of the old stream changes nothing.
            peer.addr = from;
            peer.candidate = None;
        } else if peer.moved_to(from, packet.header.sequence) {
            peer.addr = from;
            peer.candidate = None;
            self.stats.moved += 1;
        } else {
            self.stats.foreign += 1;
            return;
        }
        peer.last_heard = arrival;
        peer.last_media = arrival;
        peer.media += 1;
        let restarts = peer.receiver.restarts();
        if !peer.receiver.insert(&packet, arrival) {
            self.stats.unknown_payload += 1;
        }
        if peer.receiver.restarts() != restarts {
            peer.said_bye = false;
        }
    }

    pub(super) fn handle_rtcp(&mut self, data: &mut Vec<u8>, from: SocketAddr, arrival: Instant) {
        if !self.fixed_admits(from, true, arrival) {
            return;
        }
        let failed = self.stats.auth_failed;
        if !self.unprotect(data, Srtp::unprotect_rtcp) {
            self.stats.rtcp_auth_failed += self.stats.auth_failed - failed;
            return;
        }
        let items = match rtcp::parse(data) {
            Ok(items) => items,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        let arrival_ntp = self.ntp_at(arrival);
        // A fixed call's RTCP comes from a port of its own, admitted above.
        let fixed = self.fixed.is_some();
        // Where we call says how our call stands there: ringing, or declined.
        let callee = self.config.destinations.contains(&from);
        let rings: Vec<u32> = items
            .iter()
            .filter_map(|item| match item {
                RtcpItem::Names {
                    ssrc,
                    note: Some(note),
                    ..
                } if callee && note == rtcp::RINGING_NOTE => Some(*ssrc),
                _ => None,
            })
            .collect();
        let mut believed = false;
        let mut end_ts: HashMap<u32, u32> = HashMap::new();
        for item in items {
            match item {
                RtcpItem::Report {
                    reporter,
                    sender,
                    blocks,
                } => {
                    if reporter == self.ssrc {
                        self.stats.own += 1;
                        continue;
                    }
                    if blocks.iter().any(|b| b.ssrc == self.ssrc) {
                        self.stats.reports_about_us += 1;
                        if rings.contains(&reporter) {
                            self.stats.ringing_reports += 1;
                        }
                    }
                    let Some(peer) = self.peers.get_mut(&reporter) else {
                        // Not a peer (until its media comes): only where its stream will start
                        // is worth keeping, a few at most.
                        if let Some(info) = sender.filter(|i| i.packets == 0) {
                            if self.pending_starts.len() == PENDING_STARTS {
                                self.pending_starts.remove(0);
                            }
                            self.pending_starts
                                .push((reporter, info.rtp_timestamp, from, arrival));
                        }
                        continue;
                    };
                    if !fixed && peer.addr != from {
                        self.stats.foreign += 1;
                        continue;
                    }
                    believed = true;
                    peer.last_heard = arrival;
                    if let Some(info) = sender {
                        end_ts.insert(reporter, info.rtp_timestamp);
                        if info.packets == 0 {
                            peer.receiver.jitter().hint_start(info.rtp_timestamp);
                        }
                    }
                    peer.reports
                        .take(sender.as_ref(), &blocks, self.ssrc, arrival, arrival_ntp);
                }
                RtcpItem::Names {
                    ssrc, cname, name, ..
                } => {
                    if ssrc == self.ssrc {
                        continue;
                    }
                    match self.peers.get_mut(&ssrc) {
                        Some(peer) if fixed || peer.addr == from => {
                            believed = true;
                            if cname.is_some() {
                                peer.cname = cname;
                            }
                            if name.is_some() {
                                peer.name = name;
                            }
                        }
                        Some(_) => {}
                        None => {
                            // Kept until its media comes, a few at most; junk only displaces
                            // other pending names.
                            self.pending_names
                                .retain(|(s, addr, ..)| (*s, *addr) != (ssrc, from));
                            if self.pending_names.len() == PENDING_NAMES {
                                self.pending_names.remove(0);
                            }
                            self.pending_names.push((ssrc, from, cname, name, arrival));
                        }
                    }
                }
                RtcpItem::Bye { ssrcs, reason } => {
                    if callee && reason.as_deref() == Some(rtcp::DECLINED_REASON) {
                        self.stats.declined += 1;
                    }
                    for ssrc in ssrcs {
                        let Some(peer) = self.peers.get_mut(&ssrc) else {
                            continue;
                        };
                        if !fixed && peer.addr != from {
                            self.stats.foreign += 1;
                            continue;
                        }
                        peer.said_bye = true;
                        match end_ts.get(&ssrc) {
                            Some(&ts) => peer.receiver.jitter().hint_end(ts),
                            None => peer.receiver.jitter().bye(),
                        }
                    }
                }
            }
        }
        if let Some(fixed) = self.fixed.as_mut().filter(|_| believed) {
            // Our reports go where the peer's believed ones come from (RFC 4961).
            fixed.rtcp.latch(from);
        }
    }

    /// Forgets silent peers and stale hints.
    pub(super) fn expire(&mut self, now: Instant) {
        let timeout = self.config.peer_timeout;
        self.blocked.expire(now);
        self.pending_starts
            .retain(|&(_, _, _, at)| now.saturating_duration_since(at) < UNCONFIRMED_TIMEOUT);
        self.pending_names
            .retain(|(.., at)| now.saturating_duration_since(*at) < UNCONFIRMED_TIMEOUT);
        // A forgotten peer's SRTP replay state stays: replayed, its packets are still refused.
        self.peers.retain(|_, p| {
            if p.confirmed() {
                now.saturating_duration_since(p.last_heard) < timeout
            } else {
                now.saturating_duration_since(p.last_media) < UNCONFIRMED_TIMEOUT
            }
        });
    }
}

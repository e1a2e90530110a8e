//! The relay: a room server for peers behind NAT and for rooms too large for a mesh.
//!
//! Peers join a room by its hashed id (see [`super::control`]) and repeat the join as a
//! keepalive; the relay forwards every RTP/RTCP datagram from a member to the other members of
//! its room, as it is: with SRTP it cannot read or forge them. Everything is bounded: rooms,
//! members per room, packets per second per source (token bucket), and idle members expire.
//! Anything else is dropped and counted.

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::control::{Control, ControlKind, RoomId};
use super::{DatagramKind, MAX_DATAGRAM, NetError, classify};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelayConfig {
    pub max_rooms: usize,
    pub max_members: usize,
    /// Sustained packets per second a member may send (RTP + RTCP + keepalives).
    pub rate_per_second: f64,
    pub burst: f64,
    /// Joins per second accepted from everyone together.
    pub joins_per_second: f64,
    pub idle_timeout: Duration,
}

impl Default for RelayConfig {
    fn default() -> Self {
        Self {
            max_rooms: 1024,
            max_members: 16,
            // 50 packets/s of media plus RTCP and keepalives, with room for a burst.
            rate_per_second: 120.0,
            burst: 60.0,
            joins_per_second: 200.0,
            idle_timeout: Duration::from_secs(30),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RelayStats {
    pub datagrams: u64,
    /// Member datagrams forwarded (each counted once, however many copies went out).
    pub forwarded: u64,
    pub copies: u64,
    pub joins: u64,
    pub refused: u64,
    pub leaves: u64,
    pub expired: u64,
    /// Media from addresses that are no member.
    pub unknown_source: u64,
    pub malformed: u64,
    pub rate_limited: u64,
    pub send_errors: u64,
    pub rooms: usize,
    pub members: usize,
}

#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    at: Instant,
}

impl Bucket {
    fn take(&mut self, now: Instant, rate: f64, burst: f64) -> bool {
        let elapsed = now.saturating_duration_since(self.at).as_secs_f64();
        self.tokens = (self.tokens + elapsed * rate).min(burst);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

#[derive(Debug)]
struct Member {
    room: RoomId,
    last_seen: Instant,
    bucket: Bucket,
}

/// The relay's state and rules without a socket: datagrams in, datagrams out.
#[derive(Debug)]
pub struct RelayCore {
    config: RelayConfig,
    members: HashMap<SocketAddr, Member>,
    rooms: HashMap<RoomId, Vec<SocketAddr>>,
    joins: Bucket,
    stats: RelayStats,
}

impl RelayCore {
    pub fn new(config: RelayConfig, now: Instant) -> Self {
        Self {
            config,
            members: HashMap::new(),
            rooms: HashMap::new(),
            joins: Bucket {
                tokens: config.joins_per_second,
                at: now,
            },
            stats: RelayStats::default(),
        }
    }

    pub fn stats(&self) -> RelayStats {
        RelayStats {
            rooms: self.rooms.len(),
            members: self.members.len(),
            ..self.stats
        }
    }

    /// Handles one datagram; `send` is called for every copy to go out.
    pub fn handle(
        &mut self,
        data: &[u8],
        from: SocketAddr,
        now: Instant,
        mut send: impl FnMut(&[u8], SocketAddr) -> bool,
    ) {
        self.stats.datagrams += 1;
        let kind = classify(data);
        if let Some(member) = self.members.get_mut(&from) {
            if !member
                .bucket
                .take(now, self.config.rate_per_second, self.config.burst)
            {
                self.stats.rate_limited += 1;
                return;
            }
            member.last_seen = now;
            if matches!(kind, DatagramKind::Rtp | DatagramKind::Rtcp) {
                let room = member.room;
                self.stats.forwarded += 1;
                for &to in self.rooms.get(&room).into_iter().flatten() {
                    if to != from {
                        if send(data, to) {
                            self.stats.copies += 1;
                        } else {
                            self.stats.send_errors += 1;
                        }
                    }
                }
                return;
            }
        } else if kind != DatagramKind::Control {
            self.stats.unknown_source += 1;
            return;
        }
        let Ok(control) = Control::decode(data) else {
            self.stats.malformed += 1;
            return;
        };
        match control.kind {
            ControlKind::Join => {
                let answer = if self.join(control.room, from, now) {
                    ControlKind::Joined
                } else {
                    ControlKind::Refused
                };
                let reply = Control {
                    kind: answer,
                    room: control.room,
                }
                .encode();
                if !send(&reply, from) {
                    self.stats.send_errors += 1;
                }
            }
            ControlKind::Leave => {
                if self
                    .members
                    .get(&from)
                    .is_some_and(|m| m.room == control.room)
                {
                    self.remove(from);
                    self.stats.leaves += 1;
                }
            }
            ControlKind::Joined | ControlKind::Refused => self.stats.malformed += 1,
        }
    }

    fn join(&mut self, room: RoomId, from: SocketAddr, now: Instant) -> bool {
        if let Some(member) = self.members.get_mut(&from) {
            if member.room == room {
                return true;
            }
        } else if !self.joins.take(
            now,
            self.config.joins_per_second,
            self.config.joins_per_second,
        ) {
            self.stats.rate_limited += 1;
            self.stats.refused += 1;
            return false;
        }
        let members = self.rooms.get(&room).map_or(0, Vec::len);
        let room_ok = if members == 0 {
            self.rooms.len() < self.config.max_rooms
        } else {
            members < self.config.max_members
        };
        if !room_ok {
            self.stats.refused += 1;
            return false;
        }
        // A member moving rooms keeps its rate budget.
        let bucket = self.members.get(&from).map_or(
            Bucket {
                tokens: self.config.burst,
                at: now,
            },
            |m| m.bucket,
        );
        self.remove(from);
        self.rooms.entry(room).or_default().push(from);
        self.members.insert(
            from,
            Member {
                room,
                last_seen: now,
                bucket,
            },
        );
        self.stats.joins += 1;
        true
    }

    fn remove(&mut self, addr: SocketAddr) {
        let Some(member) = self.members.remove(&addr) else {
            return;
        };
        if let Some(list) = self.rooms.get_mut(&member.room) {
            list.retain(|&a| a != addr);
            if list.is_empty() {
                self.rooms.remove(&member.room);
            }
        }
    }

    /// Forgets members silent for longer than the idle timeout.
    pub fn expire(&mut self, now: Instant) {
        let timeout = self.config.idle_timeout;
        let stale: Vec<SocketAddr> = self
            .members
            .iter()
            .filter(|(_, m)| now.saturating_duration_since(m.last_seen) > timeout)
            .map(|(&a, _)| a)
            .collect();
        for addr in stale {
            self.remove(addr);
            self.stats.expired += 1;
        }
    }
}

/// A relay serving on its own thread until stopped or dropped.
pub struct Relay {
    addr: SocketAddr,
    stats: Arc<Mutex<RelayStats>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl std::fmt::Debug for Relay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Relay").field("addr", &self.addr).finish()
    }
}

impl Relay {
    pub fn start(bind: SocketAddr, config: RelayConfig) -> Result<Self, NetError> {
        let socket = UdpSocket::bind(bind)
            .map_err(|e| NetError::io(format!("cannot listen on {bind}"), e))?;
        socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .map_err(|e| NetError::io("socket timeout", e))?;
        let addr = socket
            .local_addr()
            .map_err(|e| NetError::io("local address", e))?;
        let stats = Arc::new(Mutex::new(RelayStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stats = Arc::clone(&stats);
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("lipcall-relay".into())
                .spawn(move || relay_loop(&socket, config, &stats, &stop))
                .map_err(|e| NetError::io("cannot start the relay thread", e))?
        };
        Ok(Self {
            addr,
            stats,
            stop,
            thread: Some(thread),
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn stats(&self) -> RelayStats {
        *self.stats.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn relay_loop(
    socket: &UdpSocket,
    config: RelayConfig,
    stats: &Mutex<RelayStats>,
    stop: &AtomicBool,
) {
    let mut core = RelayCore::new(config, Instant::now());
    // One byte over the largest datagram forwarded: one that fills the buffer was cut short
    // by the socket and is dropped, not forwarded or parsed truncated.
    let mut buf = vec![0u8; MAX_DATAGRAM + 1];
    let mut next_expiry = Instant::now() + Duration::from_secs(1);
    let mut next_publish = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) if n > MAX_DATAGRAM => {
                core.stats.datagrams += 1;
                core.stats.malformed += 1;
            }
            Ok((n, from)) => core.handle(&buf[..n], from, Instant::now(), |data, to| {
                socket.send_to(data, to).is_ok()
            }),
            Err(_) => {}
        }
        let now = Instant::now();
        if now >= next_expiry {
            core.expire(now);
            next_expiry = now + Duration::from_secs(1);
        }
        if now >= next_publish {
            *stats.lock().unwrap_or_else(|p| p.into_inner()) = core.stats();
            next_publish = now + Duration::from_millis(20);
        }
    }
    *stats.lock().unwrap_or_else(|p| p.into_inner()) = core.stats();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    fn join(room: &str) -> [u8; super::super::control::LEN] {
        Control {
            kind: ControlKind::Join,
            room: RoomId::from_name(room),
        }
        .encode()
    }

    #[test]
    fn forwards_within_a_room_only() {
        let now = Instant::now();
        let mut core = RelayCore::new(RelayConfig::default(), now);
        let mut out = Vec::new();
        for (port, room) in [(1, "a"), (2, "a"), (3, "a"), (4, "b")] {
            core.handle(&join(room), addr(port), now, |d, to| {
                out.push((d.to_vec(), to));
                true
            });
        }
        assert!(
            out.iter()
                .all(|(d, _)| Control::decode(d).unwrap().kind == ControlKind::Joined)
        );
        out.clear();
        let rtp = [0x80u8, 110, 0, 1, 0, 0, 0, 0, 0, 0, 0, 9, 1, 2];
        core.handle(&rtp, addr(1), now, |d, to| {
            out.push((d.to_vec(), to));
            true
        });
        let mut to: Vec<u16> = out.iter().map(|(_, a)| a.port()).collect();
        to.sort();
        assert_eq!(to, vec![2, 3]);
        out.clear();
        core.handle(&rtp, addr(9), now, |_, _| panic!("stranger forwarded"));
        assert_eq!(core.stats().unknown_source, 1);
        core.handle(&[0xff; 30], addr(1), now, |_, _| {
            panic!("garbage forwarded")
        });
        assert_eq!(core.stats().malformed, 1);
    }

    #[test]
    fn rooms_are_bounded_rates_limited_and_idle_members_expire() {
        let now = Instant::now();
        let config = RelayConfig {
            max_rooms: 2,
            max_members: 2,
            ..Default::default()
        };
        let mut core = RelayCore::new(config, now);
        let mut answers = Vec::new();
        for (port, room) in [(1, "a"), (2, "a"), (3, "a"), (4, "b"), (5, "c")] {
            core.handle(&join(room), addr(port), now, |d, _| {
                answers.push(Control::decode(d).unwrap().kind);
                true
            });
        }
        use ControlKind::*;
        assert_eq!(answers, vec![Joined, Joined, Refused, Joined, Refused]);
        let rtp = [0x80u8, 110, 0, 1, 0, 0, 0, 0, 0, 0, 0, 9, 1, 2];
        let mut forwarded = 0;
        for _ in 0..1000 {
            core.handle(&rtp, addr(1), now, |_, _| {
                forwarded += 1;
                true
            });
        }
        assert_eq!(forwarded as f64, config.burst);
        assert_eq!(core.stats().rate_limited, 1000 - config.burst as u64);
        core.expire(now + config.idle_timeout + Duration::from_secs(1));
        assert_eq!(core.stats().members, 0);
        assert_eq!(core.stats().rooms, 0);
    }
}

//! The relay: a room server for peers behind NAT and for rooms too large for a mesh.
//!
//! Peers join a room by its hashed id (see [`super::control`]) and repeat the join as a
//! keepalive; the relay forwards every RTP/RTCP datagram from a member to the other members of
//! its room, as it is: with SRTP it cannot read or forge them. Everything is bounded: rooms,
//! members per room, packets per second per source (token bucket), and idle members expire.
//! Anything else is dropped and counted.

//! The RTP of one SIP call: the payload types and address SDP agreed, symmetric RTP (we send to
//! where the peer's media comes from, which is what gets through a NAT), one remote stream
//! into the same [`PeerReceiver`] (jitter buffer, decoder, features) as every other call, our
//! own stream out, RFC 4733 DTMF events, and RTCP reports both ways (`super::reports`).
//!
//! As the session's and the Janus media's, the rules are a core without I/O ([`SipRtpCore`])
//! under the shared socket thread ([`Driver`]).
//!
//! Where RTP and RTCP may come from is the session's [`Latch::Fixed`] rule
//! ([`FixedSources`], `net::session::latch`): anyone can send datagrams to our port, and plain
//! RTP proves nothing about its sender, so before the peer's first packet only those from the
//! address its SDP named are taken, or from any port of the IP its SIP messages come from
//! ([`Negotiated::signalling_peer`]: a symmetric-RTP peer behind a NAT whose SDP gives its
//! private address sends from the NAT's address, the same as its SIP, and whoever holds that IP
//! could move the media with a re-INVITE anyway); under SRTP any authenticated one. The first
//! packet taken fixes the source for the rest of the call (a re-INVITE naming a new address
//! opens it again); everything else is dropped, counted (`stray`) and said in a warning naming
//! the source, rate-limited. A peer behind a NAT reached through a proxy, whose SDP address
//! neither sends nor is the NAT's, is not heard: that takes a media relay (the PBX's,
//! rtpengine). RTCP has a latch of its own in the same rule (`super::reports`).
//!
//! [`Latch::Fixed`]: crate::net::session::latch::Latch::Fixed

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use super::reports::{CallRtcp, Taken};
use super::sdp::{Negotiated, SdesKey};
use crate::net::jitter::JitterConfig;
use crate::net::peer::{PeerReceiver, ReceiverStats};
use crate::net::rtcp::{HeardReports, ReportBlock, RtcpError};
use crate::net::rtp::{self, RtpStream};
use crate::net::session::LARGEST_DATAGRAM;
use crate::net::session::latch::{FixedSources, Named};
use crate::net::srtp::{MasterKey, Srtp, SrtpError};
use crate::net::transport::{Driver, PeerFrame, PeerId, SansIo, Transmit, TransmitKind};

/// How long the socket thread waits at most for a datagram, and how often the keepalive and
/// the reports are looked at.
const POLL: Duration = Duration::from_millis(10);
/// A call that sent nothing for this long (on hold, muted, our file played out) sends an empty
/// datagram, so that a NAT on the way keeps the media's mapping (RFC 6263: 15 s by default).
pub const KEEPALIVE: Duration = Duration::from_secs(15);
/// One DTMF digit: this many 20 ms packets of the tone, then three end packets, then a pause.
const DIGIT_PACKETS: u32 = 5;
const END_PACKETS: u32 = 3;
const PAUSE_PACKETS: u32 = 5;
/// A new stream replaces the peer's current one only after the current one has been silent
/// this long: a stray or echoed second stream on the port never cuts into the call.
const STREAM_HANDOVER: Duration = Duration::from_millis(200);
/// The RFC 4733 volume field (-10 dBm0).
const EVENT_VOLUME: u8 = 10;

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SipRtpStats {
    pub datagrams: u64,
    pub rtp: u64,
    pub malformed: u64,
    /// RTCP from the call's peer.
    pub rtcp: u64,
    /// RTCP not believed: from another source than the call's, in another SSRC's name, or
    /// failing SRTCP's authentication.
    pub rtcp_stray: u64,
    pub sent_rtcp: u64,
    /// The peer's last report about our stream: the loss and jitter it sees.
    pub their_report: Option<ReportBlock>,
    /// Packets of a payload type SDP did not agree.
    pub unknown_payload: u64,
    /// RFC 4733 event packets received.
    pub events_in: u64,
    pub sent_rtp: u64,
    pub sent_events: u64,
    pub send_errors: u64,
    /// Empty datagrams sent to keep a NAT's mapping open ([`KEEPALIVE`]).
    pub keepalives: u64,
    /// SRTP packets that failed authentication (or replays), dropped.
    pub auth_failed: u64,
    /// Packets of a second stream while the current one is still sending (dropped).
    pub other_stream: u64,
    /// The peer's media came from another address than its SDP named (we followed it).
    pub latched: Option<SocketAddr>,
    /// Plain RTP from another source than the call's (dropped, nothing sent there).
    pub stray: u64,
}

/// A digit being sent.
struct Digit {
    event: u8,
    timestamp: u32,
    step: u32,
}

/// The sans-I/O RTP of one SIP call.
pub struct SipRtpCore {
    stream: RtpStream,
    negotiated: Negotiated,
    frame_ticks: u32,
    /// Where the peer's RTP and RTCP may come from and ours go: fixed by the first packet of
    /// each taken (the session's [`crate::net::session::latch::Latch::Fixed`] rule).
    sources: FixedSources,
    receiver: PeerReceiver,
    ssrc: Option<u32>,
    /// When the current stream last sent.
    last_heard: Instant,
    jitter: JitterConfig,
    epoch: Instant,
    digits: VecDeque<u8>,
    digit: Option<Digit>,
    outbox: VecDeque<Transmit>,
    /// When we last sent, as the socket thread's clock saw it, and whether anything was
    /// queued since.
    last_sent: Instant,
    sent_since: bool,
    stats: SipRtpStats,
    /// SRTP (SDES): ours protects what we send, the peer's key what it sends.
    tx_srtp: Option<Srtp>,
    rx_srtp: Option<Srtp>,
    rtcp: CallRtcp,
    /// When the keepalive and the reports are next looked at.
    next_timeout: Instant,
}

/// Both ends of SDES-keyed SRTP: our key for what we send, the peer's for what we receive.
fn sdes_contexts(
    negotiated: &Negotiated,
    ours: &SdesKey,
) -> std::io::Result<(Option<Srtp>, Option<Srtp>)> {
    let Some(theirs) = &negotiated.srtp else {
        return Ok((None, None));
    };
    let context = |key: &SdesKey| -> std::io::Result<Srtp> {
        let master = MasterKey::from_bytes(&key.0).map_err(std::io::Error::other)?;
        Srtp::new(&master).map_err(std::io::Error::other)
    };
    Ok((Some(context(ours)?), Some(context(&theirs.key)?)))
}

/// The addresses a call's description named.
fn named(negotiated: &Negotiated) -> Named {
    Named {
        rtp: negotiated.remote,
        rtcp: negotiated.rtcp,
        signalling: negotiated.signalling_peer,
    }
}

/// The RFC 4733 event code of a DTMF key.
pub fn event_code(key: char) -> Option<u8> {
    match key.to_ascii_uppercase() {
        d @ '0'..='9' => Some(d as u8 - b'0'),
        '*' => Some(10),
        '#' => Some(11),
        l @ 'A'..='D' => Some(l as u8 - b'A' + 12),
        _ => None,
    }
}

impl SipRtpCore {
    /// The call's RTP as `negotiated`, our SRTP key `ours` where SRTP was agreed, sent from
    /// `local`.
    pub fn new(
        negotiated: Negotiated,
        ours: &SdesKey,
        local: SocketAddr,
        now: Instant,
    ) -> std::io::Result<Self> {
        let (tx_srtp, rx_srtp) = sdes_contexts(&negotiated, ours)?;
        let mut stream = RtpStream::new_random().map_err(std::io::Error::other)?;
        let frame_ticks = negotiated.codec.frame_ticks();
        stream.set_payload(negotiated.payload_type, frame_ticks);
        let stream_ssrc = stream.ssrc;
        let jitter = JitterConfig::default();
        Ok(Self {
            stream,
            frame_ticks,
            sources: FixedSources::new(named(&negotiated)),
            receiver: PeerReceiver::with_payloads(jitter, now, true, negotiated.payloads.clone()),
            ssrc: None,
            last_heard: now,
            jitter,
            epoch: now,
            digits: VecDeque::new(),
            digit: None,
            outbox: VecDeque::new(),
            last_sent: now,
            sent_since: false,
            stats: SipRtpStats::default(),
            tx_srtp,
            rx_srtp,
            rtcp: CallRtcp::new(stream_ssrc, local, now),
            next_timeout: now + POLL,
            negotiated,
        })
    }

    pub fn stats(&self) -> SipRtpStats {
        self.stats
    }

    pub fn receiver_stats(&self) -> ReceiverStats {
        self.receiver.stats()
    }

    /// The remote stream's SSRC, once it sent.
    pub fn ssrc(&self) -> Option<u32> {
        self.ssrc
    }

    pub fn remote(&self) -> SocketAddr {
        self.sources.rtp.target()
    }

    /// Where our RTCP goes.
    pub fn rtcp_remote(&self) -> SocketAddr {
        self.sources.rtcp.target()
    }

    /// What the peer's reports said: the loss it sees of our stream, the round trip.
    pub fn heard(&self) -> HeardReports {
        self.rtcp.heard()
    }

    /// The CNAME the peer's SDES gave.
    pub fn peer_cname(&self) -> Option<&str> {
        self.rtcp.peer_cname()
    }

    /// A new offer or answer in the same call (a re-INVITE: hold, resume, another address).
    pub fn renegotiate(&mut self, mut negotiated: Negotiated) {
        // An old-style hold (c=0.0.0.0): nothing goes there, and the source stays as it was.
        if negotiated.remote.ip().is_unspecified() {
            negotiated.remote = self.negotiated.remote;
            negotiated.rtcp = self.negotiated.rtcp;
        }
        self.sources.rename(named(&negotiated));
        if negotiated.payload_type != self.negotiated.payload_type {
            self.frame_ticks = negotiated.codec.frame_ticks();
            self.stream
                .set_payload(negotiated.payload_type, self.frame_ticks);
        }
        self.negotiated = negotiated;
    }

    fn queue(&mut self, mut data: Vec<u8>) {
        if let Some(srtp) = self.tx_srtp.as_mut()
            && srtp.protect_rtp(&mut data).is_err()
        {
            self.stats.send_errors += 1;
            return;
        }
        self.sent_since = true;
        self.outbox.push_back(Transmit {
            to: self.sources.rtp.target(),
            data,
            kind: TransmitKind::Rtp,
        });
    }

    /// An empty datagram (RFC 6263 4.1) where nothing went out for [`KEEPALIVE`]: RTP stacks
    /// drop it as too short to be RTP, and under SRTP it carries no key stream.
    fn keep_alive(&mut self, now: Instant) {
        if std::mem::take(&mut self.sent_since) {
            self.last_sent = now;
        } else if now.saturating_duration_since(self.last_sent) >= KEEPALIVE {
            self.last_sent = now;
            self.stats.keepalives += 1;
            self.outbox.push_back(Transmit {
                to: self.sources.rtp.target(),
                data: Vec::new(),
                kind: TransmitKind::Rtp,
            });
        }
    }

    /// Sends one payload of the agreed codec lasting `ticks` (nothing while the peer holds the
    /// call: it said it receives nothing).
    pub fn send_packet(&mut self, payload: &[u8], ticks: u32) -> Result<(), rtp::RtpError> {
        if !self.negotiated.direction.reversed().sends() {
            self.stream.skip(ticks / self.frame_ticks.max(1));
            return Ok(());
        }
        let mut buf = Vec::with_capacity(payload.len() + 12);
        self.stream.packetize_ticks(payload, ticks, &mut buf)?;
        self.queue(buf);
        self.stats.sent_rtp += 1;
        Ok(())
    }

    pub fn skip_frames(&mut self, frames: u32) {
        self.stream.skip(frames);
    }

    /// Queues DTMF keys (0-9 * # A-D) to send as RFC 4733 events; `false` when the peer
    /// agreed no events or a key is not one.
    pub fn queue_digits(&mut self, keys: &str) -> bool {
        let codes: Option<Vec<u8>> = keys.chars().map(event_code).collect();
        match (codes, self.negotiated.events) {
            (Some(codes), Some(_)) => {
                self.digits.extend(codes);
                true
            }
            _ => false,
        }
    }

    /// Whether every queued digit went out.
    pub fn digits_sent(&self) -> bool {
        self.digits.is_empty() && self.digit.is_none()
    }

    /// One 20 ms step of the digit being sent: a packet of its event (RFC 4733 2.5), its
    /// duration growing, then the end packets, then a pause before the next digit.
    pub fn step_digits(&mut self) -> Result<(), rtp::RtpError> {
        let Some(events_pt) = self.negotiated.events else {
            self.digits.clear();
            return Ok(());
        };
        if self.digit.is_none() {
            let Some(event) = self.digits.pop_front() else {
                return Ok(());
            };
            self.digit = Some(Digit {
                event,
                timestamp: self.stream.next_timestamp(),
                step: 0,
            });
        }
        let Some(digit) = self.digit.as_mut() else {
            return Ok(());
        };
        let step = digit.step;
        digit.step += 1;
        let (event, timestamp) = (digit.event, digit.timestamp);
        if step >= DIGIT_PACKETS + END_PACKETS + PAUSE_PACKETS {
            self.digit = None;
            // Where no audio went out meanwhile (no microphone), the stream's clock stood
            // still: the next event must not start at this one's timestamp, or the peer
            // takes it for a repeat of this one (RFC 4733 2.5.1.3).
            if self.stream.next_timestamp() == timestamp {
                self.stream.skip(step);
            }
            return self.step_digits();
        }
        if step >= DIGIT_PACKETS + END_PACKETS {
            return Ok(());
        }
        let end = step >= DIGIT_PACKETS;
        let duration = self.frame_ticks * (step.min(DIGIT_PACKETS - 1) + 1);
        let [d1, d2] = u16::try_from(duration).unwrap_or(u16::MAX).to_be_bytes();
        let payload = [event, (u8::from(end) << 7) | EVENT_VOLUME, d1, d2];
        let mut buf = Vec::with_capacity(16);
        self.stream
            .packetize_other(events_pt, step == 0, timestamp, &payload, &mut buf)?;
        self.queue(buf);
        self.stats.sent_events += 1;
        Ok(())
    }

    /// The next 20 ms of the peer, if it is playing.
    pub fn pull(&mut self, now: Instant, out: &mut Vec<PeerFrame>) {
        if let (Some(ssrc), Some(frame)) = (self.ssrc, self.receiver.pull(now)) {
            out.push(PeerFrame {
                peer: PeerId::Ssrc(ssrc),
                frame,
            });
        }
    }

    /// `data` in the clear: decrypted into `clear` by `unprotect` where SRTP was agreed;
    /// `None` where it fails authentication.
    fn in_clear<'a>(
        &mut self,
        data: &'a [u8],
        clear: &'a mut Vec<u8>,
        unprotect: fn(&mut Srtp, &mut Vec<u8>) -> Result<(), SrtpError>,
    ) -> Option<&'a [u8]> {
        let Some(srtp) = self.rx_srtp.as_mut() else {
            return Some(data);
        };
        clear.extend_from_slice(data);
        unprotect(srtp, clear).ok()?;
        Some(clear.as_slice())
    }

    fn handle_rtcp(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        if !self.sources.admits_rtcp(from, self.rx_srtp.is_some()) {
            tracing::debug!("RTCP from {from} not believed: not the call's peer");
            self.stats.rtcp_stray += 1;
            return;
        }
        let mut clear = Vec::new();
        let Some(data) = self.in_clear(data, &mut clear, Srtp::unprotect_rtcp) else {
            // baresip sends its first APP packet and its BYE in the clear, even under SRTP.
            tracing::debug!("RTCP from {from} not believed: it fails SRTCP's authentication");
            self.stats.rtcp_stray += 1;
            return;
        };
        match self.rtcp.take(data, self.stream.ssrc, self.ssrc, now) {
            Ok(Taken::Peer) => {
                self.stats.rtcp += 1;
                self.stats.their_report = self.rtcp.heard().about_us;
                self.sources.rtcp.latch(from);
            }
            Ok(Taken::Nothing) => self.stats.rtcp += 1,
            Ok(Taken::Stranger) => {
                tracing::debug!("RTCP from {from} in another source's name (not the call's)");
                self.stats.rtcp_stray += 1;
            }
            Err(_) => self.stats.malformed += 1,
        }
    }

    /// The block about the peer's stream, once it sent (a new interval of its loss count:
    /// only for a report going out).
    fn reception(&mut self) -> Option<(u32, (u8, u32, u32, u32))> {
        let ssrc = self.ssrc?;
        Some((ssrc, self.receiver.jitter().report()?))
    }

    /// Queues a compound RTCP packet (protected where SRTP was agreed).
    fn queue_rtcp(&mut self, built: Result<Vec<u8>, RtcpError>) {
        let Ok(mut data) = built else {
            self.stats.send_errors += 1;
            return;
        };
        if let Some(srtp) = self.tx_srtp.as_mut()
            && srtp.protect_rtcp(&mut data).is_err()
        {
            self.stats.send_errors += 1;
            return;
        }
        self.outbox.push_back(Transmit {
            to: self.sources.rtcp.target(),
            data,
            kind: TransmitKind::Rtcp,
        });
    }

    fn report_if_due(&mut self, now: Instant) {
        if self.rtcp.due(now) {
            let received = self.reception();
            let built = self.rtcp.report(&self.stream, received, false, now);
            self.queue_rtcp(built);
        }
    }

    /// Our last report with BYE (once), as the call ends.
    pub fn say_bye(&mut self, now: Instant) {
        if self.rtcp.bye() {
            let received = self.reception();
            let built = self.rtcp.report(&self.stream, received, true, now);
            self.queue_rtcp(built);
        }
    }

    fn handle(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        self.stats.datagrams += 1;
        // RTCP comes on its own socket, or shares the RTP port (RFC 5761 4: types 64-95).
        if data.len() >= 2 && (200..=206).contains(&data[1]) {
            self.handle_rtcp(data, from, now);
            return;
        }
        let authenticated = self.rx_srtp.is_some();
        if !self.sources.admits_rtp(from, authenticated) {
            self.stats.stray += 1;
            let what = if authenticated { "SRTP" } else { "plain RTP" };
            self.sources.stray(what, from, now);
            return;
        }
        let mut clear = Vec::new();
        let Some(data) = self.in_clear(data, &mut clear, Srtp::unprotect_rtp) else {
            self.stats.auth_failed += 1;
            return;
        };
        let packet = match rtp::parse(data, None) {
            Ok(p) => p,
            Err(_) => {
                self.stats.malformed += 1;
                return;
            }
        };
        let pt = packet.header.payload_type;
        if Some(pt) == self.negotiated.events {
            self.stats.events_in += 1;
            return;
        }
        if !self.negotiated.audio_types.contains(&pt) {
            self.stats.unknown_payload += 1;
            return;
        }
        let ssrc = packet.header.ssrc;
        if self.ssrc.is_some_and(|current| current != ssrc)
            && now.saturating_duration_since(self.last_heard) < STREAM_HANDOVER
        {
            self.stats.other_stream += 1;
            return;
        }
        self.stats.rtp += 1;
        self.last_heard = now;
        if self.sources.rtp.latched() != Some(from) {
            if from != self.negotiated.remote {
                self.stats.latched = Some(from);
            }
            self.sources.rtp.latch(from);
        }
        if self.ssrc != Some(packet.header.ssrc) {
            if self.ssrc.is_some() {
                // A new stream (the peer restarted its sender): a fresh timeline.
                self.receiver = PeerReceiver::with_payloads(
                    self.jitter,
                    self.epoch,
                    true,
                    self.negotiated.payloads.clone(),
                );
            }
            self.ssrc = Some(packet.header.ssrc);
        }
        self.receiver.insert(&packet, now);
    }
}

impl SansIo for SipRtpCore {
    const BUFFER: usize = LARGEST_DATAGRAM + 1;

    fn handle_datagram(&mut self, data: &[u8], from: SocketAddr, now: Instant) {
        if data.len() > LARGEST_DATAGRAM {
            self.stats.malformed += 1;
            return;
        }
        self.handle(data, from, now);
    }

    fn poll_timeout(&self) -> Instant {
        self.next_timeout
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.next_timeout = now + POLL;
        self.keep_alive(now);
        self.report_if_due(now);
    }

    fn poll_transmit(&mut self) -> Option<Transmit> {
        self.outbox.pop_front()
    }

    fn transmitted(&mut self, transmit: Transmit, sent: bool) {
        match (sent, transmit.kind) {
            (false, _) => self.stats.send_errors += 1,
            (true, TransmitKind::Rtcp) => self.stats.sent_rtcp += 1,
            (true, _) => {}
        }
    }
}

/// A call's RTP running on its socket thread.
pub struct SipRtp {
    driver: Driver<SipRtpCore>,
}

impl std::fmt::Debug for SipRtp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SipRtp").finish_non_exhaustive()
    }
}

impl SipRtp {
    /// Starts the media on `socket` (the one whose address our SDP gave), and its RTCP on
    /// `rtcp` (where the SDP gave one and RTCP is not multiplexed; on `socket` else).
    pub fn start(
        socket: UdpSocket,
        rtcp: Option<UdpSocket>,
        negotiated: Negotiated,
        ours: &SdesKey,
    ) -> std::io::Result<Self> {
        let local = socket.local_addr()?;
        let rtcp = rtcp.filter(|_| !negotiated.rtcp_mux);
        let core = SipRtpCore::new(negotiated, ours, local, Instant::now())?;
        let driver = Driver::start_with_rtcp(socket, rtcp, core, "lipcall-sip-rtp", POLL)?;
        Ok(Self { driver })
    }

    /// Says BYE in RTCP, before the call's SIP BYE.
    pub fn say_bye(&self) {
        self.driver.with(|core| core.say_bye(Instant::now()));
    }

    pub fn with<T>(&self, f: impl FnOnce(&mut SipRtpCore) -> T) -> T {
        self.driver.with(f)
    }

    pub fn stop(&mut self) {
        self.driver.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::any::{Codec, PayloadMap};
    use crate::net::sip::sdp::Direction;

    pub(super) const LOCAL: SocketAddr = SocketAddr::V4(std::net::SocketAddrV4::new(
        std::net::Ipv4Addr::LOCALHOST,
        4000,
    ));

    pub(super) fn negotiated() -> Negotiated {
        Negotiated {
            remote: "127.0.0.1:9000".parse().unwrap(),
            rtcp: "127.0.0.1:9001".parse().unwrap(),
            rtcp_mux: false,
            codec: Codec::Pcmu,
            payload_type: 0,
            events: Some(101),
            direction: Direction::SendRecv,
            payloads: PayloadMap::default(),
            audio_types: vec![0],
            srtp: None,
            signalling_peer: Some([10, 0, 0, 1].into()),
            frame_ms: 20,
        }
    }

    #[test]
    fn a_digit_is_five_growing_packets_then_three_ends_on_one_timestamp() {
        let now = Instant::now();
        let mut core = SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, now).unwrap();
        assert!(core.queue_digits("1#"));
        assert!(!core.queue_digits("x"));
        let mut packets = Vec::new();
        for _ in 0..13 {
            core.step_digits().unwrap();
            while let Some(t) = core.poll_transmit() {
                packets.push(t.data);
            }
        }
        assert_eq!(packets.len(), 8);
        let parsed: Vec<_> = packets
            .iter()
            .map(|p| rtp::parse(p, None).unwrap())
            .collect();
        assert!(parsed[0].header.marker && !parsed[1].header.marker);
        assert!(
            parsed
                .iter()
                .all(|p| p.header.timestamp == parsed[0].header.timestamp)
        );
        assert_eq!(parsed[0].payload, &[1, 10, 0, 160]);
        assert_eq!(parsed[7].payload, &[1, 128 | 10, 3, 32]);
        let seqs: Vec<u16> = parsed.iter().map(|p| p.header.sequence).collect();
        assert!(
            seqs.windows(2).all(|w| w[1] == w[0].wrapping_add(1)),
            "{seqs:?}"
        );
        core.step_digits().unwrap();
        let data = core.poll_transmit().unwrap().data;
        let next = rtp::parse(&data, None).unwrap();
        assert_eq!(next.payload[0], 11, "then #");
        // No audio went out between them: # still starts at a timestamp of its own, one
        // digit's span (13 steps of 160) later.
        assert_eq!(
            next.header.timestamp,
            parsed[0].header.timestamp.wrapping_add(13 * 160)
        );
    }

    #[test]
    fn a_call_that_sends_nothing_for_15_s_sends_an_empty_datagram() {
        let t0 = Instant::now();
        let mut core = SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, t0).unwrap();
        // RTP only: the call's reports go out meanwhile.
        let sent = |core: &mut SipRtpCore, at: Duration| {
            core.handle_timeout(t0 + at);
            std::iter::from_fn(|| core.poll_transmit())
                .filter(|t| t.kind == TransmitKind::Rtp)
                .collect::<Vec<_>>()
        };
        assert!(sent(&mut core, Duration::from_secs(14)).is_empty());
        let keepalive = sent(&mut core, KEEPALIVE);
        assert_eq!(keepalive.len(), 1);
        assert!(keepalive[0].data.is_empty());
        assert_eq!(keepalive[0].to, "127.0.0.1:9000".parse().unwrap());
        assert!(sent(&mut core, Duration::from_secs(29)).is_empty());
        // Audio sent at 29 s: the next keepalive is due 15 s after it, not after the last.
        core.send_packet(&[0xff; 160], 160).unwrap();
        assert_eq!(sent(&mut core, Duration::from_secs(29)).len(), 1);
        assert!(sent(&mut core, Duration::from_secs(43)).is_empty());
        assert_eq!(sent(&mut core, Duration::from_secs(44)).len(), 1);
        assert_eq!(core.stats().keepalives, 2);
    }

    #[test]
    fn plain_rtp_is_taken_from_one_source_only_and_never_sent_elsewhere() {
        let t0 = Instant::now();
        let mut core = SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, t0).unwrap();
        let packet = |ssrc: u32, seq: u16| {
            let mut stream = RtpStream::new(ssrc, seq, 0);
            stream.set_payload(0, 160);
            let mut buf = Vec::new();
            stream.packetize(&[0xff; 160], 1, &mut buf).unwrap();
            buf
        };
        let sent_to = |core: &mut SipRtpCore| {
            core.send_packet(&[0xff; 160], 160).unwrap();
            core.poll_transmit().unwrap().to
        };
        let sdp: SocketAddr = "127.0.0.1:9000".parse().unwrap();
        let stranger: SocketAddr = "127.0.0.2:9000".parse().unwrap();
        // Before the peer's first packet: a stranger is dropped, and our media goes on to the
        // SDP's address.
        core.handle_datagram(&packet(7, 1), stranger, t0);
        assert_eq!(
            (core.stats().rtp, core.stats().stray, core.ssrc()),
            (0, 1, None)
        );
        assert_eq!(sent_to(&mut core), sdp);
        // The peer from its SDP address; then the stranger again after 1 s of its silence, on
        // the SDP's IP with another port too: never taken.
        core.handle_datagram(&packet(42, 1), sdp, t0);
        assert_eq!((core.stats().rtp, core.ssrc()), (1, Some(42)));
        let later = t0 + Duration::from_secs(1);
        core.handle_datagram(&packet(7, 2), stranger, later);
        core.handle_datagram(&packet(8, 2), "127.0.0.1:9002".parse().unwrap(), later);
        assert_eq!(
            (core.stats().rtp, core.stats().stray, core.ssrc()),
            (1, 3, Some(42))
        );
        assert_eq!(sent_to(&mut core), sdp);
        assert_eq!(core.stats().latched, None);
        // A re-INVITE naming another address opens the call to it (and only it).
        let mut moved = negotiated();
        moved.remote = "127.0.0.3:7000".parse().unwrap();
        core.renegotiate(moved.clone());
        core.handle_datagram(&packet(42, 3), sdp, later);
        assert_eq!(core.stats().stray, 4);
        core.handle_datagram(&packet(42, 3), moved.remote, later);
        assert_eq!(core.stats().rtp, 2);
        assert_eq!(sent_to(&mut core), moved.remote);
    }

    #[test]
    fn an_old_style_hold_sends_nothing_and_keeps_the_source() {
        let t0 = Instant::now();
        let mut core = SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, t0).unwrap();
        let mut held = negotiated();
        held.remote = "0.0.0.0:9000".parse().unwrap();
        held.direction = Direction::SendOnly;
        core.renegotiate(held);
        core.send_packet(&[0xff; 160], 160).unwrap();
        assert!(core.poll_transmit().is_none());
        assert_eq!(core.remote(), "127.0.0.1:9000".parse().unwrap());
        core.renegotiate(negotiated());
        core.send_packet(&[0xff; 160], 160).unwrap();
        assert_eq!(
            core.poll_transmit().unwrap().to,
            "127.0.0.1:9000".parse().unwrap()
        );
    }

    #[test]
    fn media_from_the_signalling_peers_nat_is_received_and_answered_there() {
        let now = Instant::now();
        let mut core = SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, now).unwrap();
        let mut sender = RtpStream::new(42, 1, 0);
        sender.set_payload(0, 160);
        let mut buf = Vec::new();
        sender.packetize(&[0xff; 160], 1, &mut buf).unwrap();
        let nat: SocketAddr = "10.0.0.1:40000".parse().unwrap();
        core.handle_datagram(&buf, nat, now);
        assert_eq!(core.stats().rtp, 1);
        assert_eq!(core.stats().latched, Some(nat));
        core.send_packet(&[0xff; 160], 160).unwrap();
        assert_eq!(core.poll_transmit().unwrap().to, nat);
        // Unagreed types, events and garbage are counted, never decoded.
        sender.set_payload(8, 160);
        sender.packetize(&[0xd5; 160], 1, &mut buf).unwrap();
        core.handle_datagram(&buf, nat, now);
        core.handle_datagram(&[0x80, 0, 1], nat, now);
        assert_eq!(core.stats().unknown_payload, 1);
        assert_eq!(core.stats().malformed, 1);
        assert_eq!(core.ssrc(), Some(42));
        // A second stream while the first one talks is dropped; after a pause it takes over.
        let mut other = RtpStream::new(43, 1, 0);
        other.set_payload(0, 160);
        other.packetize(&[0xff; 160], 1, &mut buf).unwrap();
        core.handle_datagram(&buf, nat, now + Duration::from_millis(20));
        assert_eq!((core.ssrc(), core.stats().other_stream), (Some(42), 1));
        other.packetize(&[0xff; 160], 1, &mut buf).unwrap();
        core.handle_datagram(&buf, nat, now + Duration::from_millis(500));
        assert_eq!(core.ssrc(), Some(43));
    }
}

#[cfg(test)]
mod srtp_tests {
    use super::tests::LOCAL;
    use super::*;
    use crate::codec::any::{Codec, PayloadMap};
    use crate::net::sip::sdp::{Direction, Sdes};

    #[test]
    fn sdes_keyed_ends_hear_each_other_and_drop_the_unkeyed() {
        let now = Instant::now();
        let (a_key, b_key) = (SdesKey([1; 30]), SdesKey([2; 30]));
        let towards = |key: &SdesKey| Negotiated {
            remote: "127.0.0.1:9000".parse().unwrap(),
            rtcp: "127.0.0.1:9001".parse().unwrap(),
            rtcp_mux: false,
            codec: Codec::Pcmu,
            payload_type: 0,
            events: None,
            direction: Direction::SendRecv,
            payloads: PayloadMap::default(),
            audio_types: vec![0],
            srtp: Some(Sdes {
                tag: 1,
                key: key.clone(),
            }),
            signalling_peer: None,
            frame_ms: 20,
        };
        let mut a = SipRtpCore::new(towards(&b_key), &a_key, LOCAL, now).unwrap();
        let mut b = SipRtpCore::new(towards(&a_key), &b_key, LOCAL, now).unwrap();
        let from: SocketAddr = "127.0.0.1:9001".parse().unwrap();
        a.send_packet(&[0xff; 160], 160).unwrap();
        let sent = a.poll_transmit().unwrap().data;
        assert_eq!(sent.len(), 12 + 160 + 10, "authenticated");
        b.handle_datagram(&sent, from, now);
        assert_eq!((b.stats().rtp, b.stats().auth_failed), (1, 0));
        // The first authenticated packet fixed the source: A's next one from elsewhere (a
        // replay or a rebinding alike) is dropped before decryption, and ours stay there.
        a.send_packet(&[0xff; 160], 160).unwrap();
        let next = a.poll_transmit().unwrap().data;
        b.handle_datagram(&next, "127.0.0.5:9001".parse().unwrap(), now);
        assert_eq!((b.stats().rtp, b.stats().stray), (1, 1));
        assert_eq!(b.remote(), from);
        // Plain RTP (or a wrong key) into a keyed call is dropped.
        let mut plain = RtpStream::new(5, 1, 0);
        plain.set_payload(0, 160);
        let mut buf = Vec::new();
        plain.packetize(&[0xff; 160], 1, &mut buf).unwrap();
        b.handle_datagram(&buf, from, now);
        assert_eq!((b.stats().rtp, b.stats().auth_failed), (1, 1));
        // Reports are SRTCP: A's BYE reaches B; one in the clear is not believed.
        a.say_bye(now);
        let bye = a.poll_transmit().unwrap();
        assert_eq!(bye.kind, TransmitKind::Rtcp);
        b.handle_datagram(&bye.data, from, now);
        assert_eq!((b.stats().rtcp, b.stats().rtcp_stray), (1, 0));
        let mut clear = Vec::new();
        let outgoing = crate::net::rtcp::Outgoing {
            ssrc: a.stream.ssrc,
            cname: "x",
            ..Default::default()
        };
        crate::net::rtcp::build(&outgoing, &mut clear).unwrap();
        b.handle_datagram(&clear, from, now);
        assert_eq!((b.stats().rtcp, b.stats().rtcp_stray), (1, 1));
    }
}

#[cfg(test)]
mod rtcp_tests {
    use super::tests::{LOCAL, negotiated};
    use super::*;
    use crate::net::rtcp::{self, Outgoing, RtcpItem};

    /// Two calls' cores wired back to back, each datagram arriving one 20 ms step after it left
    /// (RTP from the cores' RTP ports, RTCP from the ports above), `lose` deciding which of A's
    /// RTP packets (by count) never arrive.
    struct Wire {
        a: SipRtpCore,
        b: SipRtpCore,
        now: Instant,
        in_flight: Vec<(bool, Transmit)>,
        a_rtp_sent: u32,
    }

    const A_RTP: &str = "127.0.0.1:4000";
    const B_RTP: &str = "127.0.0.1:9000";

    impl Wire {
        fn new() -> Self {
            let now = Instant::now();
            let mut towards_a = negotiated();
            towards_a.remote = A_RTP.parse().unwrap();
            towards_a.rtcp = "127.0.0.1:4001".parse().unwrap();
            let b_local: SocketAddr = B_RTP.parse().unwrap();
            Self {
                a: SipRtpCore::new(negotiated(), &SdesKey([1; 30]), LOCAL, now).unwrap(),
                b: SipRtpCore::new(towards_a, &SdesKey([1; 30]), b_local, now).unwrap(),
                now,
                in_flight: Vec::new(),
                a_rtp_sent: 0,
            }
        }

        fn step(&mut self, lose: impl Fn(u32) -> bool) {
            self.now += Duration::from_millis(20);
            for (to_b, t) in std::mem::take(&mut self.in_flight) {
                let (core, rtp_port) = if to_b {
                    (&mut self.b, 4000)
                } else {
                    (&mut self.a, 9000)
                };
                let port = rtp_port + u16::from(t.kind == TransmitKind::Rtcp);
                core.handle_datagram(&t.data, ([127, 0, 0, 1], port).into(), self.now);
            }
            self.a.send_packet(&[0xff; 160], 160).unwrap();
            self.b.send_packet(&[0xff; 160], 160).unwrap();
            self.a.handle_timeout(self.now);
            self.b.handle_timeout(self.now);
            let mut played = Vec::new();
            self.a.pull(self.now, &mut played);
            self.b.pull(self.now, &mut played);
            while let Some(t) = self.a.poll_transmit() {
                if t.kind == TransmitKind::Rtp {
                    self.a_rtp_sent += 1;
                    if lose(self.a_rtp_sent) {
                        continue;
                    }
                }
                self.in_flight.push((true, t));
            }
            while let Some(t) = self.b.poll_transmit() {
                self.in_flight.push((false, t));
            }
        }
    }

    #[test]
    fn each_side_reports_what_it_lost_of_the_other_and_learns_what_the_other_lost() {
        let mut wire = Wire::new();
        let mut reports_to = Vec::new();
        for _ in 0..1000 {
            wire.step(|n| n % 10 == 0);
            reports_to.extend(
                wire.in_flight
                    .iter()
                    .filter(|(to_b, t)| *to_b && t.kind == TransmitKind::Rtcp)
                    .map(|(_, t)| t.to),
            );
        }
        // 20 s at 5 s spread 0.5-1.5x: two to eight reports, to B's RTCP port.
        assert!((2..=8).contains(&reports_to.len()), "{reports_to:?}");
        assert!(
            reports_to
                .iter()
                .all(|&to| to == "127.0.0.1:9001".parse().unwrap())
        );
        // B lost every tenth of A's packets, and said so; A lost nothing of B's.
        let said_to_a = wire.a.stats().their_report.expect("B reported");
        assert_eq!(said_to_a.ssrc, wire.a.stream.ssrc);
        let fraction = f64::from(said_to_a.fraction_lost) / 256.0;
        assert!((0.08..=0.12).contains(&fraction), "{said_to_a:?}");
        assert!(said_to_a.cumulative_lost >= 20, "{said_to_a:?}");
        let said_to_b = wire.b.stats().their_report.expect("A reported");
        assert_eq!(said_to_b.cumulative_lost, 0, "{said_to_b:?}");
        // Both sides sent SRs and heard the other's: the round trip is the two steps' 40 ms.
        let rtt = wire.a.heard().rtt_ms.expect("a round trip");
        assert!((35.0..=45.0).contains(&rtt), "{rtt} ms");
        assert!(
            wire.a
                .peer_cname()
                .is_some_and(|c| c.starts_with("lipcall-"))
        );
        assert_eq!(
            (wire.a.stats().rtcp_stray, wire.b.stats().rtcp_stray),
            (0, 0)
        );
        assert_eq!(wire.a.stats().sent_rtcp, 0, "no socket counted them");
    }

    #[test]
    fn reports_from_strangers_are_not_believed_and_bye_is_said_once() {
        let mut wire = Wire::new();
        for _ in 0..400 {
            wire.step(|_| false);
        }
        let believed = wire.a.stats().their_report.expect("B reported");
        let (ours, bs) = (wire.a.stream.ssrc, wire.b.stream.ssrc);
        let forged = |reporter: u32| {
            let block = ReportBlock {
                ssrc: ours,
                fraction_lost: 255,
                cumulative_lost: 99_999,
                ..ReportBlock::default()
            };
            let mut out = Vec::new();
            let outgoing = Outgoing {
                ssrc: reporter,
                blocks: &[block],
                cname: "forger",
                ..Outgoing::default()
            };
            rtcp::build(&outgoing, &mut out).unwrap();
            out
        };
        // In B's name from another host, from B's own IP on another port (its RTCP is latched
        // now), from the right place in another SSRC's name; then garbage.
        let now = wire.now;
        wire.a
            .handle_datagram(&forged(bs), "127.0.0.2:9001".parse().unwrap(), now);
        wire.a
            .handle_datagram(&forged(bs), "127.0.0.1:9555".parse().unwrap(), now);
        wire.a
            .handle_datagram(&forged(77), "127.0.0.1:9001".parse().unwrap(), now);
        assert_eq!(wire.a.stats().rtcp_stray, 3);
        wire.a
            .handle_datagram(&[0x80, 201, 0, 9], "127.0.0.1:9001".parse().unwrap(), now);
        assert_eq!(wire.a.stats().malformed, 1);
        assert_eq!(wire.a.stats().their_report, Some(believed));
        // BYE, once: with an SR (A sent since its last report) and its block about B.
        wire.a.say_bye(now);
        wire.a.say_bye(now);
        let sent: Vec<Transmit> = std::iter::from_fn(|| wire.a.poll_transmit()).collect();
        assert_eq!(sent.len(), 1);
        let items = rtcp::parse(&sent[0].data).unwrap();
        assert!(matches!(
            &items[0],
            RtcpItem::Report { sender: Some(_), blocks, .. } if blocks[0].ssrc == bs
        ));
        assert_eq!(
            items.last(),
            Some(&RtcpItem::Bye {
                ssrcs: vec![ours],
                reason: None
            })
        );
        // No periodic report after it.
        wire.a.handle_timeout(now + Duration::from_secs(60));
        let after: Vec<Transmit> = std::iter::from_fn(|| wire.a.poll_transmit()).collect();
        assert!(after.iter().all(|t| t.kind != TransmitKind::Rtcp));
    }
}

//! RTCP (RFC 3550 section 6) through `rtcp-types`: sender and receiver reports with their
//! report blocks, SDES CNAME, NAME (the peer's display name) and NOTE (a state such as
//! [`RINGING_NOTE`]), and BYE with its reason; and what every
//! sender of reports shares: when the next one is due, the NTP clock they are stamped on, the
//! block about a stream received, and what a peer's reports said about ours.

use std::net::SocketAddr;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::net::rtp::RtpStream;

use rtcp_types::{
    Bye, Compound, Packet, ReceiverReport, ReportBlock as RawBlock, RtcpPacketWriter,
    RtcpPacketWriterExt, Sdes, SdesItem, SenderReport,
};

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RtcpError {
    #[error("malformed RTCP packet: {0}")]
    Malformed(String),
    #[error("cannot build RTCP packet: {0}")]
    Write(String),
}

/// The sender-information part of an SR.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SenderInfo {
    pub ntp: u64,
    pub rtp_timestamp: u32,
    pub packets: u32,
    pub octets: u32,
}

/// One reception report block: what `reporter` heard from `ssrc`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReportBlock {
    pub ssrc: u32,
    /// Fraction lost since the previous report, out of 256.
    pub fraction_lost: u8,
    /// Cumulative packets lost (24 bits; duplicates can make the true value negative, sent as 0).
    pub cumulative_lost: u32,
    pub highest_sequence: u32,
    /// Interarrival jitter in timestamp units.
    pub jitter: u32,
    /// Middle 32 bits of the NTP time of the last SR heard from `ssrc`.
    pub last_sr: u32,
    /// Delay since that SR, in 1/65536 s.
    pub delay_since_last_sr: u32,
}

/// What a compound RTCP packet said, one item per piece of information.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RtcpItem {
    Report {
        reporter: u32,
        sender: Option<SenderInfo>,
        blocks: Vec<ReportBlock>,
    },
    Names {
        ssrc: u32,
        cname: Option<String>,
        name: Option<String>,
        note: Option<String>,
    },
    Bye {
        ssrcs: Vec<u32>,
        reason: Option<String>,
    },
}

/// The SDES NOTE (RFC 3550 6.5.7) of an app that rings for the caller it reports to: the
/// caller's reports are heard, its call is not answered yet.
pub const RINGING_NOTE: &str = "ringing";
/// The BYE reason (RFC 3550 6.6) of an app whose user declined the caller it says it to.
pub const DECLINED_REASON: &str = "declined";

/// Parses a compound packet; unknown packet types inside it are skipped.
pub fn parse(data: &[u8]) -> Result<Vec<RtcpItem>, RtcpError> {
    let malformed = |e: rtcp_types::RtcpParseError| RtcpError::Malformed(e.to_string());
    let mut items = Vec::new();
    for packet in Compound::parse(data).map_err(malformed)? {
        match packet.map_err(malformed)? {
            Packet::Sr(sr) => items.push(sender_report(&sr)),
            Packet::Rr(rr) => items.push(RtcpItem::Report {
                reporter: rr.ssrc(),
                sender: None,
                blocks: rr.report_blocks().map(|b| block(&b)).collect(),
            }),
            Packet::Sdes(sdes) => names(&sdes, &mut items),
            Packet::Bye(bye) => items.push(bye_item(&bye)),
            _ => {}
        }
    }
    Ok(items)
}

fn sender_report(sr: &SenderReport<'_>) -> RtcpItem {
    RtcpItem::Report {
        reporter: sr.ssrc(),
        sender: Some(SenderInfo {
            ntp: sr.ntp_timestamp(),
            rtp_timestamp: sr.rtp_timestamp(),
            packets: sr.packet_count(),
            octets: sr.octet_count(),
        }),
        blocks: sr.report_blocks().map(|b| block(&b)).collect(),
    }
}

fn block(b: &RawBlock<'_>) -> ReportBlock {
    ReportBlock {
        ssrc: b.ssrc(),
        fraction_lost: b.fraction_lost(),
        cumulative_lost: b.cumulative_lost(),
        highest_sequence: b.extended_sequence_number(),
        jitter: b.interarrival_jitter(),
        last_sr: b.last_sender_report_timestamp(),
        delay_since_last_sr: b.delay_since_last_sender_report_timestamp(),
    }
}

/// Longest display name kept from SDES; longer ones are cut at a character boundary.
pub const MAX_NAME_BYTES: usize = 64;

fn names<'a>(sdes: &'a Sdes<'a>, items: &mut Vec<RtcpItem>) {
    for chunk in sdes.chunks() {
        let mut cname = None;
        let mut name = None;
        let mut note = None;
        for item in chunk.items() {
            let text = || Some(clean_name(&String::from_utf8_lossy(item.value())));
            match item.type_() {
                SdesItem::CNAME => cname = text(),
                SdesItem::NAME => name = text(),
                SdesItem::NOTE => note = text(),
                _ => {}
            }
        }
        items.push(RtcpItem::Names {
            ssrc: chunk.ssrc(),
            cname,
            name,
            note,
        });
    }
}

/// Keeps a display name printable and short.
pub fn clean_name(raw: &str) -> String {
    let mut out = String::new();
    for c in raw.chars().filter(|c| !c.is_control()) {
        if out.len() + c.len_utf8() > MAX_NAME_BYTES {
            break;
        }
        out.push(c);
    }
    out
}

fn bye_item(bye: &Bye<'_>) -> RtcpItem {
    RtcpItem::Bye {
        ssrcs: bye.ssrcs().collect(),
        reason: bye
            .reason()
            .map(|r| clean_name(&String::from_utf8_lossy(r))),
    }
}

/// What to put into one outgoing compound packet.
#[derive(Debug, Clone, Default)]
pub struct Outgoing<'a> {
    pub ssrc: u32,
    /// `Some` makes it an SR (we sent media since the last report), `None` an RR.
    pub sender: Option<SenderInfo>,
    /// At most 31 blocks are sent; extra ones are left out.
    pub blocks: &'a [ReportBlock],
    pub cname: &'a str,
    pub name: Option<&'a str>,
    /// An SDES NOTE: where the sender is (ringing, say), for the one it reports to.
    pub note: Option<&'a str>,
    pub bye: bool,
    /// Why the sender says BYE, where `bye` is set.
    pub bye_reason: Option<&'a str>,
}

/// Builds the compound packet (SR or RR, then SDES, then an optional BYE) into `out`.
pub fn build(outgoing: &Outgoing<'_>, out: &mut Vec<u8>) -> Result<(), RtcpError> {
    let cname = clean_name(outgoing.cname);
    let name = outgoing.name.map(clean_name);
    let note = outgoing.note.map(clean_name);
    let blocks = outgoing.blocks.iter().take(31).map(|b| {
        RawBlock::builder(b.ssrc)
            .fraction_lost(b.fraction_lost)
            .cumulative_lost(b.cumulative_lost.min(0x7f_ffff))
            .extended_sequence_number(b.highest_sequence)
            .interarrival_jitter(b.jitter)
            .last_sender_report_timestamp(b.last_sr)
            .delay_since_last_sender_report_timestamp(b.delay_since_last_sr)
    });
    let mut compound = Compound::builder();
    compound = match outgoing.sender {
        Some(info) => {
            let mut sr = SenderReport::builder(outgoing.ssrc)
                .ntp_timestamp(info.ntp)
                .rtp_timestamp(info.rtp_timestamp)
                .packet_count(info.packets)
                .octet_count(info.octets);
            for b in blocks {
                sr = sr.add_report_block(b);
            }
            compound.add_packet(sr)
        }
        None => {
            let mut rr = ReceiverReport::builder(outgoing.ssrc);
            for b in blocks {
                rr = rr.add_report_block(b);
            }
            compound.add_packet(rr)
        }
    };
    let mut chunk = rtcp_types::SdesChunk::builder(outgoing.ssrc)
        .add_item(SdesItem::builder(SdesItem::CNAME, &cname));
    if let Some(name) = &name {
        chunk = chunk.add_item(SdesItem::builder(SdesItem::NAME, name));
    }
    if let Some(note) = &note {
        chunk = chunk.add_item(SdesItem::builder(SdesItem::NOTE, note));
    }
    compound = compound.add_packet(Sdes::builder().add_chunk(chunk));
    if outgoing.bye {
        let mut bye = Bye::builder().add_source(outgoing.ssrc);
        if let Some(reason) = outgoing.bye_reason {
            bye = bye.reason_owned(clean_name(reason));
        }
        compound = compound.add_packet(bye);
    }
    let size = compound
        .calculate_size()
        .map_err(|e| RtcpError::Write(e.to_string()))?;
    out.clear();
    out.resize(size, 0);
    compound
        .write_into(out)
        .map_err(|e| RtcpError::Write(e.to_string()))?;
    Ok(())
}

/// The current wall-clock time as a 64-bit NTP timestamp.
pub fn ntp_now() -> u64 {
    let since = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    const NTP_UNIX_OFFSET: u64 = 2_208_988_800;
    let seconds = since.as_secs().wrapping_add(NTP_UNIX_OFFSET);
    let fraction = (u64::from(since.subsec_nanos()) << 32) / 1_000_000_000;
    (seconds << 32) | fraction
}

/// The middle 32 bits of an NTP timestamp, as LSR and round-trip arithmetic use them.
pub fn ntp_middle(ntp: u64) -> u32 {
    (ntp >> 16) as u32
}

/// `interval` times 0.5 to 1.5 (RFC 3550 6.3.1), by where `draw` falls in `u32`'s range: reports
/// of many members do not fall into step.
pub fn spread(interval: Duration, draw: u32) -> Duration {
    interval.mul_f64(0.5 + f64::from(draw) / f64::from(u32::MAX))
}

/// The system's randomness (the middle of the range if it fails).
pub fn system_draw() -> u32 {
    getrandom::u32().unwrap_or(0x8000_0000)
}

/// When the next periodic report is due: every `interval`, spread by [`spread`].
#[derive(Debug, Clone)]
pub struct ReportTimer {
    interval: Duration,
    /// A uniform random draw over `u32`.
    draw: fn() -> u32,
    next: Instant,
}

impl ReportTimer {
    pub fn new(interval: Duration, now: Instant, draw: fn() -> u32) -> Self {
        Self {
            interval,
            draw,
            next: now + spread(interval, draw()),
        }
    }

    pub fn next(&self) -> Instant {
        self.next
    }

    /// Whether a report is due at `now`; if so the next one is scheduled from `now`.
    pub fn due(&mut self, now: Instant) -> bool {
        if now < self.next {
            return false;
        }
        self.next = now + spread(self.interval, (self.draw)());
        true
    }
}

/// The wall clock as NTP for a sender's reports, counted from the moment it started: its
/// stamps never step back when the system's clock is set.
#[derive(Debug, Clone, Copy)]
pub struct NtpClock {
    epoch: Instant,
    ntp_epoch: u64,
}

impl NtpClock {
    pub fn new(now: Instant) -> Self {
        Self {
            epoch: now,
            ntp_epoch: ntp_now(),
        }
    }

    /// `at` as NTP.
    pub fn at(&self, at: Instant) -> u64 {
        let since = at.saturating_duration_since(self.epoch);
        let fraction = (u64::from(since.subsec_nanos()) << 32) / 1_000_000_000;
        self.ntp_epoch
            .wrapping_add((since.as_secs() << 32) | fraction)
    }
}

/// A sender's CNAME: its SSRC and the address it sends from.
pub fn cname(ssrc: u32, local: SocketAddr) -> String {
    format!("lipcall-{ssrc:08x}@{local}")
}

impl SenderInfo {
    /// What `stream` sent until now, stamped `ntp`.
    pub fn of(stream: &RtpStream, ntp: u64) -> Self {
        Self {
            ntp,
            rtp_timestamp: stream.next_timestamp(),
            packets: stream.packets_sent,
            octets: stream.octets_sent,
        }
    }
}

impl ReportBlock {
    /// The block about the stream `ssrc` from what its receiver counted (`reception`: fraction
    /// lost, cumulative lost, highest sequence and jitter, as the jitter buffer reports them)
    /// and the last SR its sender sent (the SR's middle NTP bits, and when it came).
    pub fn about(
        ssrc: u32,
        reception: (u8, u32, u32, u32),
        last_sr: Option<(u32, Instant)>,
        now: Instant,
    ) -> Self {
        let (fraction_lost, cumulative_lost, highest_sequence, jitter) = reception;
        let (last_sr, delay_since_last_sr) = match last_sr {
            Some((middle, at)) => (
                middle,
                (now.saturating_duration_since(at).as_secs_f64() * 65536.0) as u32,
            ),
            None => (0, 0),
        };
        Self {
            ssrc,
            fraction_lost,
            cumulative_lost,
            highest_sequence,
            jitter,
            last_sr,
            delay_since_last_sr,
        }
    }
}

/// What one remote sender's reports told us: its last SR (for our blocks' LSR and DLSR), and
/// its last block about our stream with the round trip it gives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HeardReports {
    pub last_sr: Option<(u32, Instant)>,
    pub about_us: Option<ReportBlock>,
    pub rtt_ms: Option<f64>,
}

impl HeardReports {
    /// Takes a report from the sender: its sender info if an SR, and its blocks, of which the
    /// one about `ours` (our SSRC) counts; it came at `arrival` (`arrival_ntp` on our clock).
    pub fn take(
        &mut self,
        sender: Option<&SenderInfo>,
        blocks: &[ReportBlock],
        ours: u32,
        arrival: Instant,
        arrival_ntp: u64,
    ) {
        if let Some(info) = sender {
            self.last_sr = Some((ntp_middle(info.ntp), arrival));
        }
        if let Some(about_us) = blocks.iter().find(|b| b.ssrc == ours) {
            // A block without our last SR (sent before it reached the peer) measures nothing:
            // the last round trip measured stands.
            if let Some(rtt) = round_trip(about_us, arrival_ntp) {
                self.rtt_ms = Some(rtt * 1000.0);
            }
            self.about_us = Some(*about_us);
        }
    }

    /// Share of our packets the sender last reported lost (0..1).
    pub fn their_loss(&self) -> Option<f64> {
        self.about_us.map(|b| f64::from(b.fraction_lost) / 256.0)
    }
}

/// How far below zero a round trip may come out and still be read as none at all (in 1/65536
/// s): a peer that counts its DLSR on a millisecond timer (baresip's libre) overstates it by up
/// to a millisecond, more than a round trip on one host takes, so A - LSR - DLSR comes out
/// slightly negative about half the time there.
const DLSR_ROUNDING: u32 = 65536 / 100;

/// Round trip from a report block about us (RFC 3550 6.4.1), in seconds, if it has one; one
/// under zero by less than [`DLSR_ROUNDING`] is zero.
pub fn round_trip(block: &ReportBlock, arrival_ntp: u64) -> Option<f64> {
    if block.last_sr == 0 {
        return None;
    }
    let rtt = ntp_middle(arrival_ntp)
        .wrapping_sub(block.last_sr)
        .wrapping_sub(block.delay_since_last_sr);
    // A negative round trip shows up as a huge value: a rounded DLSR when it is small, clock
    // steps or a bogus report when larger.
    if rtt.wrapping_neg() <= DLSR_ROUNDING {
        return Some(0.0);
    }
    (rtt < 0x8000_0000).then(|| f64::from(rtt) / 65536.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sender_report_with_names_and_bye_round_trips() {
        let blocks = [ReportBlock {
            ssrc: 7,
            fraction_lost: 25,
            cumulative_lost: 12,
            highest_sequence: 70000,
            jitter: 80,
            last_sr: 0x1234_5678,
            delay_since_last_sr: 65536,
        }];
        let sender = SenderInfo {
            ntp: 0x0102_0304_0506_0708,
            rtp_timestamp: 99,
            packets: 10,
            octets: 380,
        };
        let mut out = Vec::new();
        build(
            &Outgoing {
                ssrc: 42,
                sender: Some(sender),
                blocks: &blocks,
                cname: "lipcall@host",
                name: Some("Ann\u{7}e"),
                note: Some(RINGING_NOTE),
                bye: true,
                bye_reason: Some(DECLINED_REASON),
            },
            &mut out,
        )
        .unwrap();
        assert_eq!(crate::net::classify(&out), crate::net::DatagramKind::Rtcp);
        let items = parse(&out).unwrap();
        assert_eq!(
            items,
            vec![
                RtcpItem::Report {
                    reporter: 42,
                    sender: Some(sender),
                    blocks: blocks.to_vec()
                },
                RtcpItem::Names {
                    ssrc: 42,
                    cname: Some("lipcall@host".into()),
                    name: Some("Anne".into()),
                    note: Some(RINGING_NOTE.into()),
                },
                RtcpItem::Bye {
                    ssrcs: vec![42],
                    reason: Some(DECLINED_REASON.into()),
                },
            ]
        );
    }

    #[test]
    fn receiver_report_without_name() {
        let mut out = Vec::new();
        build(
            &Outgoing {
                ssrc: 1,
                cname: "x",
                ..Default::default()
            },
            &mut out,
        )
        .unwrap();
        let items = parse(&out).unwrap();
        assert!(matches!(items[0], RtcpItem::Report { sender: None, .. }));
    }

    #[test]
    fn round_trip_time_from_lsr_and_dlsr() {
        let sent = 0x0000_1000_0000_0000u64;
        let block = ReportBlock {
            last_sr: ntp_middle(sent),
            delay_since_last_sr: 65536 / 2,
            ..Default::default()
        };
        let arrival = sent + (1u64 << 32);
        let rtt = round_trip(&block, arrival).unwrap();
        assert!((rtt - 0.5).abs() < 1e-4);
        assert_eq!(round_trip(&ReportBlock::default(), arrival), None);
    }

    #[test]
    fn a_dlsr_rounded_up_past_a_tiny_round_trip_reads_as_zero_and_a_bogus_one_as_none() {
        let sent = 0x0000_1000_0000_0000u64;
        // A 0.1 ms round trip, the peer's DLSR counted in whole milliseconds: 1 s + 1 ms for
        // the 1.0006 s it held our SR.
        let arrival = sent + (1u64 << 32) + (1u64 << 32) * 7 / 10_000;
        let block = ReportBlock {
            last_sr: ntp_middle(sent),
            delay_since_last_sr: 65536 + 65536 / 1000,
            ..Default::default()
        };
        assert_eq!(round_trip(&block, arrival), Some(0.0));
        // Half a second below zero is no rounding.
        let block = ReportBlock {
            delay_since_last_sr: 65536 * 3 / 2,
            ..block
        };
        assert_eq!(round_trip(&block, arrival), None);
    }
}

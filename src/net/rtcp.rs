//! RTCP (RFC 3550 section 6) through `rtcp-types`: sender and receiver reports with their
//! report blocks, SDES CNAME and NAME (the peer's display name), and BYE.

use std::time::{SystemTime, UNIX_EPOCH};

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
    },
    Bye {
        ssrcs: Vec<u32>,
    },
}

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
        for item in chunk.items() {
            let text = || Some(clean_name(&String::from_utf8_lossy(item.value())));
            match item.type_() {
                SdesItem::CNAME => cname = text(),
                SdesItem::NAME => name = text(),
                _ => {}
            }
        }
        items.push(RtcpItem::Names {
            ssrc: chunk.ssrc(),
            cname,
            name,
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
    pub bye: bool,
}

/// Builds the compound packet (SR or RR, then SDES, then an optional BYE) into `out`.
pub fn build(outgoing: &Outgoing<'_>, out: &mut Vec<u8>) -> Result<(), RtcpError> {
    let cname = clean_name(outgoing.cname);
    let name = outgoing.name.map(clean_name);
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
    compound = compound.add_packet(Sdes::builder().add_chunk(chunk));
    if outgoing.bye {
        compound = compound.add_packet(Bye::builder().add_source(outgoing.ssrc));
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

/// Round trip from a report block about us (RFC 3550 6.4.1), in seconds, if it has one.
pub fn round_trip(block: &ReportBlock, arrival_ntp: u64) -> Option<f64> {
    if block.last_sr == 0 {
        return None;
    }
    let rtt = ntp_middle(arrival_ntp)
        .wrapping_sub(block.last_sr)
        .wrapping_sub(block.delay_since_last_sr);
    // A negative round trip (clock steps, bogus reports) shows up as a huge value.
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
                bye: true,
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
                    name: Some("Anne".into())
                },
                RtcpItem::Bye { ssrcs: vec![42] },
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
}

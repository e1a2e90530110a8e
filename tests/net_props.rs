//! Random and mutated bytes into every packet parser of the transport, and random payloads of
//! every payload type into the receive path and every codec's decoder: errors are fine, panics
//! are not.

use std::time::{Duration, Instant};

use lipcall::codec::any::{Codec, PayloadMap};
use lipcall::codec::decoder::StreamDecoder;
use lipcall::codec::opus::fec::carries_fec;
use lipcall::codec::speex::split;
use lipcall::net::control::Control;
use lipcall::net::jitter::{JitterBuffer, JitterConfig};
use lipcall::net::peer::PeerReceiver;
use lipcall::net::relay::{RelayConfig, RelayCore};
use lipcall::net::srtp::{MasterKey, Srtp};
use lipcall::net::{classify, rtcp, rtp};
use proptest::prelude::*;

fn key() -> MasterKey {
    MasterKey::from_hex(&"5a".repeat(30)).unwrap()
}

fn valid_rtcp() -> Vec<u8> {
    let mut out = Vec::new();
    rtcp::build(
        &rtcp::Outgoing {
            ssrc: 1,
            sender: Some(rtcp::SenderInfo::default()),
            blocks: &[rtcp::ReportBlock::default()],
            cname: "c",
            name: Some("n"),
            note: Some("ringing"),
            bye: true,
            bye_reason: Some("declined"),
        },
        &mut out,
    )
    .unwrap();
    out
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn parsers_never_panic(data in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = classify(&data);
        let _ = rtp::parse(&data, None);
        let _ = rtp::parse(&data, Some(110));
        let _ = rtcp::parse(&data);
        let _ = Control::decode(&data);
        let _ = split::split_frames(&data);
        let _ = split::frame_count(&data);
        let mut srtp = Srtp::new(&key()).unwrap();
        let _ = srtp.unprotect_rtp(&mut data.clone());
        let _ = srtp.unprotect_rtcp(&mut data.clone());
        let _ = srtp.protect_rtp(&mut data.clone());
        let _ = srtp.protect_rtcp(&mut data.clone());
    }

    #[test]
    fn mutated_rtcp_never_panics(
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
        cut in any::<usize>(),
    ) {
        let mut data = valid_rtcp();
        for (at, x) in flips {
            let i = at % data.len();
            data[i] ^= x;
        }
        data.truncate(cut % (data.len() + 1));
        let _ = rtcp::parse(&data);
    }

    #[test]
    fn mutated_srtp_is_rejected_not_panicking(
        flip in any::<usize>(),
        bit in 0u8..8,
    ) {
        let mut tx = Srtp::new(&key()).unwrap();
        let mut rx = Srtp::new(&key()).unwrap();
        let mut packet = Vec::new();
        rtp::write(
            &rtp::RtpHeader { marker: true, payload_type: 110, sequence: 7, timestamp: 9, ssrc: 3 },
            b"payload bytes",
            &mut packet,
        ).unwrap();
        tx.protect_rtp(&mut packet).unwrap();
        let i = flip % packet.len();
        packet[i] ^= 1 << bit;
        prop_assert!(rx.unprotect_rtp(&mut packet).is_err());
    }

    #[test]
    fn jitter_buffer_survives_any_packet_order(
        packets in proptest::collection::vec(
            (any::<u16>(), any::<u32>(), any::<bool>(), 1u32..70, 0u64..2000),
            0..120,
        ),
        pulls in 0usize..200,
    ) {
        let t0 = Instant::now();
        let mut jb = JitterBuffer::new(JitterConfig::default(), t0);
        for (seq, ts, marker, frames, at) in &packets {
            jb.insert(*seq, *ts, *marker, &[1, 2], *frames, t0 + Duration::from_millis(*at));
            if *at % 7 == 0 {
                jb.hint_end(*ts);
            }
            if *at % 11 == 0 {
                jb.hint_start(*ts);
            }
        }
        for k in 0..pulls {
            let _ = jb.pop(t0 + Duration::from_millis(20 * k as u64));
        }
        let s = jb.stats();
        prop_assert!(s.buffered_frames <= JitterConfig::default().capacity * 64);
        let _ = jb.report();
    }

    #[test]
    fn relay_core_survives_anything(
        datagrams in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..64), 0u16..8),
            0..200,
        ),
    ) {
        let now = Instant::now();
        let mut core = RelayCore::new(RelayConfig { max_rooms: 4, max_members: 3, ..Default::default() }, now);
        for (data, port) in &datagrams {
            let from = std::net::SocketAddr::from(([127, 0, 0, 1], 1000 + port));
            core.handle(data, from, now, |_, _| true);
        }
        core.expire(now + Duration::from_secs(3600));
        prop_assert_eq!(core.stats().members, 0);
    }

    #[test]
    fn random_payloads_of_every_payload_type_never_panic(
        packets in proptest::collection::vec(
            (
                0u8..128,
                any::<u16>(),
                0u32..20_000,
                any::<bool>(),
                proptest::collection::vec(any::<u8>(), 1..400),
            ),
            0..60,
        ),
        remap in any::<bool>(),
    ) {
        let t0 = Instant::now();
        let payloads = if remap {
            PayloadMap::default().with_assignments(&["opus=100", "speex=127"]).unwrap()
        } else {
            PayloadMap::default()
        };
        let mut rx = PeerReceiver::with_payloads(JitterConfig::default(), t0, true, payloads.clone());
        let mut buf = Vec::new();
        let mut unknown = 0;
        for (k, (pt, seq, ts, marker, payload)) in packets.iter().enumerate() {
            rtp::write(
                &rtp::RtpHeader { marker: *marker, payload_type: *pt, sequence: *seq, timestamp: *ts, ssrc: 9 },
                payload,
                &mut buf,
            ).unwrap();
            let parsed = rtp::parse(&buf, None).unwrap();
            let at = t0 + Duration::from_millis(20 * k as u64);
            let known = rx.insert(&parsed, at);
            prop_assert_eq!(known, payloads.codec(*pt).is_some());
            unknown += u64::from(!known);
            for p in 0..2 {
                if let Some(f) = rx.pull(at + Duration::from_millis(10 * p)) {
                    prop_assert!(f.features.lsp.windows(2).all(|w| w[0] < w[1]));
                    prop_assert!(f.features.energy_db.is_finite());
                }
            }
        }
        prop_assert_eq!(rx.stats().unknown_payload, unknown);
    }

    #[test]
    fn every_decoder_takes_any_payload(
        payloads in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..1600), 0u32..2000, 0u8..3),
            1..12,
        ),
    ) {
        for codec in Codec::ALL {
            let mut dec = StreamDecoder::new(codec, true).unwrap();
            for (payload, offset, action) in &payloads {
                let _ = codec.payload_duration(payload);
                let _ = carries_fec(payload);
                let frame = match action {
                    0 => {
                        dec.packet(payload, *offset);
                        dec.frame()
                    }
                    1 => dec.lost(Some(payload)),
                    _ => dec.lost(None),
                };
                prop_assert!(frame.features.lsp.windows(2).all(|w| w[0] < w[1]));
            }
        }
    }
}

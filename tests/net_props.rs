//! Random and mutated bytes into every packet parser of the transport: errors are fine,
//! panics are not.

use std::time::{Duration, Instant};

use lipcall::codec::speex::split;
use lipcall::net::control::Control;
use lipcall::net::jitter::{JitterBuffer, JitterConfig};
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
            bye: true,
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
        let mut srtp = Srtp::new(&key());
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
        let mut tx = Srtp::new(&key());
        let mut rx = Srtp::new(&key());
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
}

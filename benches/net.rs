//! Relay forwarding rate on one core, and the receive path's CPU per peer per second of audio.

use std::hint::black_box;
use std::net::{SocketAddr, UdpSocket};
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lipcall::audio::wav;
use lipcall::codec::speex::codec::{Encoder, EncoderConfig, MAX_PACKET_BYTES};
use lipcall::net::control::{Control, ControlKind, Cookie, RoomId};
use lipcall::net::jitter::JitterConfig;
use lipcall::net::peer::PeerReceiver;
use lipcall::net::relay::{RelayConfig, RelayCore};
use lipcall::net::rtp::{self, RtpStream};
use lipcall::net::srtp::{MasterKey, Srtp};
use lipcall::vocab::FRAME_SIZE;

fn one_second_of_speech() -> Vec<Vec<u8>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
    let pcm = wav::read_narrowband(&path).expect("demo speech");
    let mut encoder = Encoder::new(EncoderConfig::default()).unwrap();
    let mut packet = [0u8; MAX_PACKET_BYTES];
    pcm.chunks_exact(FRAME_SIZE)
        .skip(50)
        .take(50)
        .map(|f| {
            let n = encoder
                .encode_frame(f.try_into().unwrap(), &mut packet)
                .unwrap();
            packet[..n].to_vec()
        })
        .collect()
}

/// Members joined as a client joins: a join, then the relay's cookie echoed.
fn join(core: &mut RelayCore, room: RoomId, members: &[SocketAddr], now: Instant) {
    for &m in members {
        let mut cookie = Cookie::NONE;
        let request = Control::new(ControlKind::Join, room, Cookie::NONE).encode();
        core.handle(&request, m, now, |d, _| {
            cookie = Control::decode(d).map_or(Cookie::NONE, |c| c.cookie);
            true
        });
        let confirm = Control::new(ControlKind::Confirm, room, cookie).encode();
        core.handle(&confirm, m, now, |_, _| true);
    }
    assert_eq!(core.stats().members, members.len());
}

fn relay_forwarding(c: &mut Criterion) {
    let now = Instant::now();
    let config = RelayConfig {
        rate_per_second: 1e12,
        burst: 1e12,
        ..Default::default()
    };
    let room = RoomId::from_name("bench");
    let members: Vec<SocketAddr> = (0..3)
        .map(|i| SocketAddr::from(([127, 0, 0, 1], 40000 + i)))
        .collect();
    let mut packet = Vec::new();
    RtpStream::new(1, 2, 3)
        .packetize(&[0x5a; 48], 1, &mut packet)
        .unwrap();

    let mut group = c.benchmark_group("relay");
    group.throughput(Throughput::Elements(1));
    group.bench_function("forward to 2 members (core, no I/O)", |b| {
        let mut core = RelayCore::new(config, now);
        join(&mut core, room, &members, now);
        b.iter(|| {
            core.handle(black_box(&packet), members[0], now, |d, to| {
                black_box((d, to));
                true
            })
        })
    });
    // The same with real sendto() calls to a loopback socket nobody reads (the kernel drops
    // what does not fit): the syscall is the cost that dominates a real relay.
    let sink = UdpSocket::bind("127.0.0.1:0").unwrap();
    let sink_addr = sink.local_addr().unwrap();
    let out = UdpSocket::bind("127.0.0.1:0").unwrap();
    group.bench_function("forward to 2 members (with sendto)", |b| {
        let mut core = RelayCore::new(config, now);
        join(&mut core, room, &members, now);
        b.iter(|| {
            core.handle(black_box(&packet), members[0], now, |d, _| {
                out.send_to(d, sink_addr).is_ok()
            })
        })
    });
    group.finish();
}

fn receive_path(c: &mut Criterion) {
    let packets = one_second_of_speech();
    let key = MasterKey::from_hex(&"11".repeat(30)).unwrap();
    let mut group = c.benchmark_group("receive");
    group.measurement_time(Duration::from_secs(8));
    group.throughput(Throughput::Elements(1));
    for encrypted in [false, true] {
        let name = if encrypted {
            "one peer, 1 s of audio (SRTP + RTP + jitter + decode + features)"
        } else {
            "one peer, 1 s of audio (RTP + jitter + decode + features)"
        };
        // Wire packets prepared once; each iteration is a fresh stream of 50 packets.
        group.bench_function(name, |b| {
            b.iter_batched(
                || {
                    let mut tx = Srtp::new(&key).unwrap();
                    let mut stream = RtpStream::new(7, 100, 1000);
                    let wire: Vec<Vec<u8>> = packets
                        .iter()
                        .map(|p| {
                            let mut buf = Vec::new();
                            stream.packetize(p, 1, &mut buf).unwrap();
                            if encrypted {
                                tx.protect_rtp(&mut buf).unwrap();
                            }
                            buf
                        })
                        .collect();
                    let epoch = Instant::now();
                    let rx = PeerReceiver::new(JitterConfig::default(), epoch, true);
                    (wire, rx, Srtp::new(&key).unwrap(), epoch)
                },
                |(wire, mut rx, mut srtp, epoch)| {
                    let frame = Duration::from_millis(20);
                    for (k, mut datagram) in wire.into_iter().enumerate() {
                        let at = epoch + frame * k as u32;
                        if encrypted {
                            srtp.unprotect_rtp(&mut datagram).unwrap();
                        }
                        let parsed = rtp::parse(&datagram, Some(110)).unwrap();
                        rx.insert(&parsed, at);
                        black_box(rx.pull(at + frame * 2));
                    }
                },
                criterion::BatchSize::SmallInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, relay_forwarding, receive_path);
criterion_main!(benches);

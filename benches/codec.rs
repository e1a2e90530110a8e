//! Decode alone against decode + LSP/energy features, per 20 ms frame (goal: ratio <= 1.05),
//! and the LPC analysis that gives codecs without LSPs their features (goal: < 10 us a frame).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lipcall::audio::wav;
use lipcall::codec::lpc::LpcAnalyser;
use lipcall::codec::speex::codec::{Decoder, EncoderConfig};
use lipcall::codec::speex::features::FrameTracker;
use lipcall::codec::speex::{ogg_file, stream};
use lipcall::vocab::FRAME_SIZE;

fn demo_packets() -> Vec<Vec<u8>> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
    let pcm = wav::read_narrowband(&path).expect("demo speech");
    let spx = stream::encode(&pcm, EncoderConfig::default()).expect("encode");
    let file = ogg_file::read(&spx).expect("read back");
    file.pages.into_iter().flat_map(|p| p.packets).collect()
}

fn decode_vs_features(c: &mut Criterion) {
    let packets = demo_packets();
    let mut group = c.benchmark_group("decode");
    group.throughput(Throughput::Elements(packets.len() as u64));
    group.bench_function("decode alone", |b| {
        let mut decoder = Decoder::new(true).unwrap();
        let mut out = [0i16; FRAME_SIZE];
        b.iter(|| {
            for p in &packets {
                decoder.load(p).unwrap();
                black_box(decoder.decode_next(&mut out).unwrap());
            }
        })
    });
    group.bench_function("decode + features", |b| {
        let mut decoder = Decoder::new(true).unwrap();
        let mut tracker = FrameTracker::new();
        let mut out = [0i16; FRAME_SIZE];
        b.iter(|| {
            for p in &packets {
                decoder.load(p).unwrap();
                tracker.start_packet(p).unwrap();
                black_box(decoder.decode_next(&mut out).unwrap());
                black_box(tracker.decoded(&out));
            }
        })
    });
    // The features' own cost, measured apart so that the ratio survives a noisy machine.
    group.bench_function("features alone", |b| {
        let mut decoder = Decoder::new(true).unwrap();
        let mut tracker = FrameTracker::new();
        let decoded: Vec<[i16; FRAME_SIZE]> = packets
            .iter()
            .map(|p| {
                let mut out = [0i16; FRAME_SIZE];
                decoder.load(p).unwrap();
                decoder.decode_next(&mut out).unwrap();
                out
            })
            .collect();
        b.iter(|| {
            for (p, pcm) in packets.iter().zip(&decoded) {
                tracker.start_packet(p).unwrap();
                black_box(tracker.decoded(pcm));
            }
        })
    });
    group.finish();
}

/// LPC analysis of one decoded 20 ms frame (the features of codecs without LSPs; goal < 10 us).
fn lpc_analysis_per_frame(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
    let pcm = wav::read_narrowband(&path).expect("demo speech");
    let frames: Vec<[i16; FRAME_SIZE]> = pcm
        .chunks_exact(FRAME_SIZE)
        .map(|f| f.try_into().unwrap())
        .collect();
    let mut group = c.benchmark_group("lpc");
    group.throughput(Throughput::Elements(1));
    group.bench_function("lpc_analysis_per_frame", |b| {
        let mut analyser = LpcAnalyser::new();
        let mut next = frames.iter().cycle();
        b.iter(|| black_box(analyser.analyse(black_box(next.next().unwrap()))))
    });
    group.finish();
}

criterion_group!(benches, decode_vs_features, lpc_analysis_per_frame);
/// Opus packets of the demo speech at 16 kb/s, from PCM at `rate` (8 kHz input gives
/// narrowband SILK, 16 kHz wideband SILK).
fn opus_demo_packets(rate: u32) -> Vec<Vec<u8>> {
    use lipcall::codec::opus;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/speech/demo.wav");
    let audio = wav::read_mono(&path).expect("demo speech");
    let pcm = wav::to_i16(&wav::resample(&audio, rate).expect("resample"));
    let config = opus::codec::EncoderConfig {
        input_rate: rate,
        ..Default::default()
    };
    let bytes = opus::stream::encode(&pcm, config).expect("encode");
    let file = opus::ogg_file::read(&bytes).expect("read back");
    file.pages.into_iter().flat_map(|p| p.packets).collect()
}

/// Opus decode alone, per 20 ms packet at 16 kb/s, decoded to 8 kHz: the baseline for
/// "Opus decode + NLSF features".
fn opus_decode_per_frame(c: &mut Criterion) {
    use lipcall::codec::opus::codec::Decoder as OpusDecoder;
    let mut group = c.benchmark_group("opus_decode");
    for (name, rate) in [("nb 16 kb/s", 8000), ("wb 16 kb/s", 16_000)] {
        let packets = opus_demo_packets(rate);
        group.throughput(Throughput::Elements(packets.len() as u64));
        group.bench_function(name, |b| {
            let mut decoder = OpusDecoder::new().unwrap();
            let mut out = [0i16; FRAME_SIZE];
            b.iter(|| {
                for p in &packets {
                    decoder.decode_frame(black_box(p), &mut out).unwrap();
                    black_box(&out);
                }
            })
        });
    }
    group.finish();
}

criterion_group!(opus_benches, opus_decode_per_frame);

/// The SILK walker alone (NLSFs from the bitstream), per 20 ms packet at 16 kb/s, as used
/// (stopping at the NLSFs) and reading every symbol, and with the decode beside it: against
/// "opus_decode" this is the cost of the NLSF features.
fn silk_walker_per_packet(c: &mut Criterion) {
    use lipcall::codec::opus::codec::Decoder as OpusDecoder;
    use lipcall::codec::silk::SilkWalker;
    let mut group = c.benchmark_group("opus_nlsf");
    for (name, rate) in [("nb 16 kb/s", 8000), ("wb 16 kb/s", 16_000)] {
        let packets = opus_demo_packets(rate);
        group.throughput(Throughput::Elements(packets.len() as u64));
        for (walk, read_to_end) in [("walker", false), ("walker read to end", true)] {
            group.bench_function(format!("{walk} {name}"), |b| {
                let mut walker = SilkWalker::new().read_to_end(read_to_end);
                let mut frames = Vec::with_capacity(4);
                b.iter(|| {
                    for p in &packets {
                        frames.clear();
                        walker.walk_packet_into(black_box(p), &mut frames).unwrap();
                        black_box(&frames);
                    }
                })
            });
        }
        group.bench_function(format!("decode + walker {name}"), |b| {
            let mut decoder = OpusDecoder::new().unwrap();
            let mut walker = SilkWalker::new();
            let mut frames = Vec::with_capacity(4);
            let mut out = [0i16; FRAME_SIZE];
            b.iter(|| {
                for p in &packets {
                    frames.clear();
                    walker.walk_packet_into(black_box(p), &mut frames).unwrap();
                    decoder.decode_frame(black_box(p), &mut out).unwrap();
                    black_box((&frames, &out));
                }
            })
        });
        // What the receiver does per frame: decode, walk, map the NLSFs onto the network's
        // narrowband LSPs, and the energy of the decoded samples.
        group.bench_function(format!("decode + NLSF features {name}"), |b| {
            use lipcall::codec::opus::features::narrowband_lsp;
            use lipcall::vocab::energy_db;
            let mut decoder = OpusDecoder::new().unwrap();
            let mut walker = SilkWalker::new();
            let mut frames = Vec::with_capacity(4);
            let mut out = [0i16; FRAME_SIZE];
            b.iter(|| {
                for p in &packets {
                    frames.clear();
                    walker.walk_packet_into(black_box(p), &mut frames).unwrap();
                    decoder.decode_frame(black_box(p), &mut out).unwrap();
                    let lsp = frames
                        .iter()
                        .rev()
                        .filter_map(|f| f.silk())
                        .find_map(|f| narrowband_lsp(&f.nlsf, f.internal_rate_hz));
                    black_box((lsp, energy_db(&out)));
                }
            })
        });
    }
    group.finish();
}

criterion_group!(silk_benches, silk_walker_per_packet);
criterion_main!(benches, opus_benches, silk_benches);

//! Mixer cost for one second of audio with 1, 4 and 16 peers: the sum alone, and the sum plus
//! the 8 kHz -> 48 kHz resampling the mixer thread does. Divide by the peer count for the
//! cost per peer per second.

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use lipcall::audio::mixer::{
    CHUNK, Mixer, PeerControls, PeerFeed, PeerId, Upsampler, peer_channel,
};
use lipcall::vocab::SAMPLE_RATE;

const CHUNKS_PER_SECOND: usize = SAMPLE_RATE as usize / CHUNK;

fn setup(peers: usize) -> (Mixer, Vec<PeerFeed>, Vec<i16>) {
    let mut mixer = Mixer::new();
    let mut feeds = Vec::new();
    for i in 0..peers {
        let controls = Arc::new(PeerControls::default());
        controls.set_volume(0.8);
        let (feed, mp, _clock) = peer_channel(PeerId(i as u32), SAMPLE_RATE as usize, controls);
        mixer.add(mp).expect("room");
        feeds.push(feed);
    }
    let second: Vec<i16> = (0..SAMPLE_RATE as usize)
        .map(|i| ((i * 37) % 2000) as i16 - 1000)
        .collect();
    (mixer, feeds, second)
}

fn mixer(c: &mut Criterion) {
    let mut group = c.benchmark_group("mix 1 s");
    group
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for peers in [1usize, 4, 16] {
        for upsample in [false, true] {
            let name = if upsample { "sum + 48k" } else { "sum" };
            group.bench_with_input(BenchmarkId::new(name, peers), &peers, |b, &peers| {
                let (mut mixer, mut feeds, second) = setup(peers);
                let mut up = Upsampler::new(48_000).expect("resampler");
                let mut chunk = [0.0f32; CHUNK];
                b.iter_custom(|iters| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iters {
                        // Refilling the queues is the decoders' work: not timed.
                        for f in &mut feeds {
                            f.push(&second);
                        }
                        let t = Instant::now();
                        for _ in 0..CHUNKS_PER_SECOND {
                            mixer.mix(&mut chunk);
                            if upsample {
                                black_box(up.process(&chunk).expect("resample"));
                            }
                            black_box(&chunk);
                        }
                        total += t.elapsed();
                    }
                    total
                });
            });
        }
    }
    group.finish();
}

criterion_group!(benches, mixer);
criterion_main!(benches);

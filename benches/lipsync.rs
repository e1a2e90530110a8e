//! Features -> viseme weights per frame for the built-in default network: the network step alone,
//! and the receiver pipeline the app runs per frame (look-ahead, speaker normalisation, closure
//! rule, still silence), with the next frame on time and with the fallback when it is late, and
//! re-projected onto a head's other viseme set; and
//! the living face's step per frame (pitch autocorrelation, blinks, saccades, head spring) on
//! voiced frames and in digital silence.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use lipcall::lipsync::life::LifeGenerator;
use lipcall::lipsync::network::Model;
use lipcall::lipsync::{LipSync, LipSyncOptions, default_model};
use lipcall::vocab::FRAME_SIZE;
use lipcall::vocab::FrameFeatures;
use lipcall::vocab::VisemeSet;

fn frames() -> Vec<FrameFeatures> {
    (0..64)
        .map(|n| {
            let x = n as f32;
            let mut lsp = [0.0; 10];
            for (i, l) in lsp.iter_mut().enumerate() {
                *l = 0.28 * (i + 1) as f32 + 0.03 * (0.3 * x + i as f32).sin();
            }
            FrameFeatures {
                family: lipcall::vocab::FeatureFamily::Bitstream,
                mode: Some(5),
                lsp,
                energy_db: -40.0 + 20.0 * (0.4 * x).sin(),
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let model = default_model();
    let mut state = model.new_state();
    let frames = frames();
    let mut weights = vec![0.0; model.outputs()];
    let mut n = 0;
    c.bench_function(
        &format!("default network step ({} MACs)", model.multiply_adds()),
        |b| {
            b.iter(|| {
                model.step(
                    &mut state,
                    black_box(&frames[n % frames.len()]),
                    &mut weights,
                );
                n += 1;
                black_box(&weights);
            })
        },
    );

    let mut lipsync = LipSync::new(&model, &LipSyncOptions::default()).unwrap();
    let name = format!("receiver push (look-ahead {})", lipsync.lookahead());
    bench_pushes(c, &name, &mut lipsync, &frames);
    let mut tag = 0u64;
    c.bench_function("receiver push + fallback (next frame always late)", |b| {
        b.iter(|| {
            let out = lipsync.push(tag, black_box(&frames[tag as usize % frames.len()]));
            black_box(out.map(|(t, w)| (t, w[0])));
            let late = lipsync.flush();
            tag += 1;
            black_box(late.map(|(t, w)| (t, w[0])));
        })
    });

    // A head with another viseme set: every frame goes through the re-projection map.
    for size in [15, 6, 3] {
        let options = LipSyncOptions {
            visemes: Some(VisemeSet::reduced(size).expect("a reduced size")),
            ..LipSyncOptions::default()
        };
        let mut lipsync = LipSync::new(&model, &options).unwrap();
        let name = format!("receiver push re-projected onto {size} visemes");
        bench_pushes(c, &name, &mut lipsync, &frames);
    }

    // Lip-sync v4: an articulation network (16 hidden units, as docs/model.md's) beside the viseme network; its
    // cost does not depend on its weights.
    let mut articulation = Model::zeros_with(
        model.visemes.clone(),
        model.scaling.clone(),
        model.context,
        model.dynamics,
        16,
    )
    .with_control_outputs();
    articulation.lookahead = model.lookahead;
    articulation.speaker_norm = model.speaker_norm.clone();
    articulation.w1.fill(0.01);
    let paired = model.clone().with_articulation(articulation).unwrap();
    let mut lipsync = LipSync::new(&paired, &LipSyncOptions::default()).unwrap();
    let name = format!(
        "receiver push with an articulation network ({} MACs)",
        paired.multiply_adds()
    );
    let mut tag = 0u64;
    c.bench_function(&name, |b| {
        b.iter(|| {
            let out =
                lipsync.push_with_controls(tag, black_box(&frames[tag as usize % frames.len()]));
            tag += 1;
            black_box(out.map(|(t, w, c)| (t, w[0], c.width)));
        })
    });

    // A voiced buzz gliding between 100 and 160 Hz, at speech level.
    let voiced: Vec<[i16; FRAME_SIZE]> = (0..64)
        .map(|n| {
            let f0 = 130.0 + 30.0 * (0.2 * n as f32).sin();
            std::array::from_fn(|i| {
                let t = (n * FRAME_SIZE + i) as f32 / 8000.0;
                let p = std::f32::consts::TAU * f0 * t;
                (6000.0 * (p.sin() + 0.5 * (2.0 * p).sin())) as i16
            })
        })
        .collect();
    let energy: Vec<f32> = voiced
        .iter()
        .map(|f| lipcall::vocab::energy_db(f))
        .collect();
    let mut life = LifeGenerator::new(1);
    let mut n = 0;
    c.bench_function("living face step (voiced frame)", |b| {
        b.iter(|| {
            let k = n % voiced.len();
            n += 1;
            black_box(life.step(black_box(energy[k]), black_box(&voiced[k])))
        })
    });
    let silence = [0i16; FRAME_SIZE];
    c.bench_function("living face step (digital silence)", |b| {
        b.iter(|| black_box(life.step(black_box(-100.0), black_box(&silence))))
    });
}

/// One receiver push per iteration, the next frame always on time.
fn bench_pushes(c: &mut Criterion, name: &str, lipsync: &mut LipSync, frames: &[FrameFeatures]) {
    let mut tag = 0u64;
    c.bench_function(name, |b| {
        b.iter(|| {
            let out = lipsync.push(tag, black_box(&frames[tag as usize % frames.len()]));
            tag += 1;
            black_box(out.map(|(t, w)| (t, w[0])));
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

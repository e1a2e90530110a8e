//! G.711 against the reference tools: sox (bit-exact) and GStreamer's mulawenc/alawenc and
//! mulawdec/alawdec, every 16-bit input and every code, and real speech.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;
use lipcall::codec::g711::Law;

fn write_s16(path: &Path, samples: &[i16]) {
    let bytes: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

fn read_s16(path: &Path) -> Vec<i16> {
    std::fs::read(path)
        .unwrap()
        .chunks_exact(2)
        .map(|b| i16::from_le_bytes([b[0], b[1]]))
        .collect()
}

fn all_samples() -> Vec<i16> {
    (i16::MIN..=i16::MAX).collect()
}

fn sox_name(law: Law) -> &'static str {
    match law {
        Law::Mu => "u-law",
        Law::A => "a-law",
    }
}

/// sox's encoding of raw 8 kHz 16-bit samples (no dither: `-D`).
fn sox_encode(dir: &Path, law: Law, samples: &[i16]) -> Vec<u8> {
    let input = dir.join("in.s16");
    let output = dir.join("out.g711");
    write_s16(&input, samples);
    run(Command::new("sox")
        .args([
            "-D", "-t", "raw", "-r", "8000", "-e", "signed", "-b", "16", "-c", "1",
        ])
        .arg(&input)
        .args(["-t", "raw", "-e", sox_name(law), "-b", "8"])
        .arg(&output));
    std::fs::read(output).unwrap()
}

fn sox_decode(dir: &Path, law: Law, codes: &[u8]) -> Vec<i16> {
    let input = dir.join("in.g711");
    let output = dir.join("out.s16");
    std::fs::write(&input, codes).unwrap();
    run(Command::new("sox")
        .args([
            "-t",
            "raw",
            "-r",
            "8000",
            "-e",
            sox_name(law),
            "-b",
            "8",
            "-c",
            "1",
        ])
        .arg(&input)
        .args(["-t", "raw", "-e", "signed", "-b", "16"])
        .arg(&output));
    read_s16(&output)
}

fn gst_element(law: Law) -> (&'static str, &'static str, &'static str) {
    match law {
        Law::Mu => ("mulawenc", "mulawdec", "audio/x-mulaw"),
        Law::A => ("alawenc", "alawdec", "audio/x-alaw"),
    }
}

fn gst_encode(dir: &Path, law: Law, samples: &[i16]) -> Vec<u8> {
    let input = dir.join("in.wav");
    let output = dir.join("gst.g711");
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut writer = hound::WavWriter::create(&input, spec).unwrap();
    for &s in samples {
        writer.write_sample(s).unwrap();
    }
    writer.finalize().unwrap();
    let (encoder, _, _) = gst_element(law);
    run(Command::new("gst-launch-1.0").args([
        "-q",
        "filesrc",
        &format!("location={}", input.display()),
        "!",
        "wavparse",
        "!",
        encoder,
        "!",
        "filesink",
        &format!("location={}", output.display()),
    ]));
    std::fs::read(output).unwrap()
}

fn gst_decode(dir: &Path, law: Law, codes: &[u8]) -> Vec<i16> {
    let input = dir.join("gst-in.g711");
    let output = dir.join("gst.s16");
    std::fs::write(&input, codes).unwrap();
    let (_, decoder, caps) = gst_element(law);
    run(Command::new("gst-launch-1.0").args([
        "-q",
        "filesrc",
        &format!("location={}", input.display()),
        "!",
        &format!("{caps},rate=8000,channels=1"),
        "!",
        decoder,
        "!",
        "audio/x-raw,format=S16LE",
        "!",
        "filesink",
        &format!("location={}", output.display()),
    ]));
    read_s16(&output)
}

fn first_mismatch<T: PartialEq + Copy + std::fmt::Debug>(
    ours: &[T],
    theirs: &[T],
) -> Option<(usize, T, T)> {
    ours.iter()
        .zip(theirs)
        .enumerate()
        .find(|(_, (a, b))| a != b)
        .map(|(i, (a, b))| (i, *a, *b))
}

/// Where each code sits among all 256 in order of decoded value.
fn rank(law: Law) -> [usize; 256] {
    let mut codes: Vec<u8> = (0..=255).collect();
    codes.sort_by_key(|&c| (law.decode_sample(c), c));
    let mut rank = [0; 256];
    for (r, c) in codes.into_iter().enumerate() {
        rank[usize::from(c)] = r;
    }
    rank
}

#[test]
fn encoding_every_sample_matches_sox_and_stays_within_a_step_of_gstreamer() {
    let dir = tempfile::tempdir().unwrap();
    let samples = all_samples();
    for law in [Law::Mu, Law::A] {
        let ours: Vec<u8> = samples.iter().map(|&s| law.encode_sample(s)).collect();
        let sox = sox_encode(dir.path(), law, &samples);
        assert_eq!(sox.len(), ours.len(), "sox {law:?}");
        if let Some((i, a, b)) = first_mismatch(&ours, &sox) {
            panic!(
                "sox {law:?}: sample {} -> ours {a:#04x}, sox {b:#04x}",
                samples[i]
            );
        }
        // GStreamer truncates the magnitude where sox rounds: neighbouring codes at most.
        let gst = gst_encode(dir.path(), law, &samples);
        assert_eq!(gst.len(), ours.len(), "gstreamer {law:?}");
        let rank = rank(law);
        let mut differ = 0;
        for ((&s, &a), &b) in samples.iter().zip(&ours).zip(&gst) {
            if a != b {
                differ += 1;
                let (ra, rb) = (rank[usize::from(a)], rank[usize::from(b)]);
                assert!(
                    ra.abs_diff(rb) <= 1,
                    "{law:?}: sample {s} -> ours {a:#04x}, gstreamer {b:#04x}"
                );
            }
        }
        println!("{law:?}: GStreamer's encoder differs by one step on {differ} of 65536 samples");
        assert!(differ < 65536 / 8, "{law:?}: {differ}");
    }
}

#[test]
fn decoding_every_code_matches_sox_and_gstreamer() {
    let dir = tempfile::tempdir().unwrap();
    let codes: Vec<u8> = (0..=255).collect();
    for law in [Law::Mu, Law::A] {
        let ours: Vec<i16> = codes.iter().map(|&c| law.decode_sample(c)).collect();
        for (tool, theirs) in [
            ("sox", sox_decode(dir.path(), law, &codes)),
            ("gstreamer", gst_decode(dir.path(), law, &codes)),
        ] {
            assert_eq!(theirs.len(), ours.len(), "{tool} {law:?}");
            if let Some((i, a, b)) = first_mismatch(&ours, &theirs) {
                panic!("{tool} {law:?}: code {i:#04x} -> ours {a}, {tool} {b}");
            }
        }
    }
}

#[test]
fn speech_round_trips_like_sox_frame_by_frame() {
    let dir = tempfile::tempdir().unwrap();
    let wav = demo_8k(dir.path());
    let (rate, pcm) = read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    for law in [Law::Mu, Law::A] {
        let theirs = sox_encode(dir.path(), law, &pcm);
        let decoded_by_sox = sox_decode(dir.path(), law, &theirs);
        let mut ours = Vec::new();
        let mut decoded = Vec::new();
        for chunk in pcm.chunks_exact(lipcall::vocab::FRAME_SIZE) {
            let frame = law.encode_frame(chunk.try_into().unwrap());
            decoded.extend_from_slice(&law.decode_frame(&frame));
            ours.extend_from_slice(&frame);
        }
        let whole = ours.len();
        assert_eq!(ours[..], theirs[..whole], "{law:?} encoding");
        assert_eq!(decoded[..], decoded_by_sox[..whole], "{law:?} decoding");
        let snr = snr_db(&pcm[..whole], &decoded);
        // G.711 keeps about 38 dB SNR over a wide range of speech levels.
        assert!(snr > 30.0, "{law:?}: SNR {snr:.1} dB");
    }
}

#[test]
fn any_length_of_payload_decodes_without_panic() {
    for law in [Law::Mu, Law::A] {
        let mut out = [0i16; 4];
        assert_eq!(law.decode_into(&[0xFF; 7], &mut out), 4);
        assert_eq!(law.decode_into(&[], &mut out), 0);
        let mut bytes = [0u8; 3];
        assert_eq!(law.encode_into(&[1, 2], &mut bytes), 2);
    }
}

//! Ogg Opus interop with opus-tools (opusenc, opusdec, opusinfo): what lipcall writes plays in
//! opusdec, what opusenc writes decodes in lipcall as opusdec decodes it, and broken files are
//! clean errors.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;
use lipcall::codec::opus::stream;

fn opusdec(input: &Path, output: &Path, rate: u32) {
    run(Command::new("opusdec")
        .args(["--quiet", "--no-dither", "--rate", &rate.to_string()])
        .arg(input)
        .arg(output));
}

fn opusenc(input: &Path, output: &Path, kbps: &str, framesize_ms: &str) {
    run(Command::new("opusenc")
        .args(["--quiet", "--bitrate", kbps, "--framesize", framesize_ms])
        .arg(input)
        .arg(output));
}

/// Two TIMIT utterances (dr1 and dr3) at their own 16 kHz, and the demo speech.
fn speech_16k(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for (speaker, utterance) in [("dr1-fvmh0", "sa1"), ("dr3-madc0", "sa2")] {
        let src = timit_dir().join(speaker).join(format!("{utterance}.wav"));
        let out = dir.join(format!("{speaker}-{utterance}.wav"));
        run(Command::new("sox")
            .arg(&src)
            .args(["-D", "-b", "16", "-c", "1"])
            .arg(&out));
        files.push(out);
    }
    let demo = dir.join("demo16k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "16000", "-b", "16", "-c", "1"])
        .arg(&demo));
    files.push(demo);
    files
}

fn max_abs_diff(a: &[i16], b: &[i16]) -> i32 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (i32::from(x) - i32::from(y)).abs())
        .max()
        .unwrap_or(0)
}

#[test]
fn lipcall_opus_plays_in_opusdec_with_the_input_length() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let input = demo_8k(d);
    let (_, original) = read_wav_i16(&input);
    for (name, args) in [
        ("12", vec!["--bitrate", "12"]),
        ("16", vec![]),
        ("24", vec!["--bitrate", "24"]),
        ("fec", vec!["--bitrate", "20", "--expect-loss", "10"]),
        ("dtx", vec!["--dtx"]),
    ] {
        let opus = d.join(format!("ours-{name}.opus"));
        run(lipcall().arg("encode").arg(&input).arg(&opus).args(&args));
        let info = run(Command::new("opusinfo").arg(&opus));
        let info = String::from_utf8_lossy(&info.stdout);
        assert!(info.contains("Pre-skip: 312"), "{info}");
        assert!(info.contains("Original sample rate: 8000 Hz"), "{info}");
        assert!(!info.to_lowercase().contains("warning"), "{info}");

        let wav = d.join(format!("opusdec-{name}.wav"));
        opusdec(&opus, &wav, 8000);
        let (rate, theirs) = read_wav_i16(&wav);
        assert_eq!(rate, 8000);
        // opusdec trims by the granule arithmetic: the exact input length.
        assert_eq!(theirs.len(), original.len(), "{name}: length");
        let ours_wav = d.join(format!("ours-{name}.wav"));
        run(lipcall()
            .arg("decode")
            .arg(&opus)
            .arg(&ours_wav)
            .args(["--rate", "8000"]));
        let (_, ours) = read_wav_i16(&ours_wav);
        assert_eq!(ours.len(), original.len(), "{name}: length");
        // opusdec decodes at 48 kHz and resamples with a fractional-sample delay, which costs
        // it SNR against the input that lipcall's direct 8 kHz decode does not lose.
        let snr_theirs = snr_db(&original, &theirs);
        let snr_ours = snr_db(&original, &ours);
        eprintln!(
            "{name}: against the input, opusdec {snr_theirs:.2} dB, lipcall {snr_ours:.2} dB"
        );
        assert!(snr_theirs > 4.0, "{name}: opusdec SNR {snr_theirs:.2} dB");
        assert!(snr_ours > 8.0, "{name}: lipcall SNR {snr_ours:.2} dB");

        // Before resampling, opusdec's decode is lipcall's, sample for sample.
        let wav48 = d.join(format!("opusdec48-{name}.wav"));
        opusdec(&opus, &wav48, 48_000);
        let (_, theirs48) = read_wav_i16(&wav48);
        let ours48 = stream::decode_at(&std::fs::read(&opus).unwrap(), 48_000).unwrap();
        assert_eq!(theirs48.len(), 6 * original.len(), "{name}: 48 kHz length");
        // `decode` writes the stream's own 48 kHz unless told another rate.
        let native_wav = d.join(format!("ours48-{name}.wav"));
        run(lipcall().arg("decode").arg(&opus).arg(&native_wav));
        assert_eq!(read_wav_i16(&native_wav), (48_000, ours48.pcm.clone()));
        assert_eq!(ours48.pcm.len(), theirs48.len(), "{name}: 48 kHz length");
        let diff = max_abs_diff(&ours48.pcm, &theirs48);
        let snr48 = snr_db(&theirs48, &ours48.pcm);
        eprintln!("{name}: 48 kHz max difference {diff}, SNR {snr48:.1} dB");
        if name == "dtx" {
            // The silent stretches are comfort noise, which libopus 1.3 (opusdec) and 1.6
            // (lipcall) do not generate identically.
            assert!(snr48 > 50.0, "{name}: 48 kHz SNR {snr48:.1} dB");
        } else {
            assert!(diff <= 1, "{name}: 48 kHz samples differ by up to {diff}");
        }
    }
}

#[test]
fn opusenc_files_decode_as_opusdec_decodes_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for wav in speech_16k(d) {
        let stem = wav.file_stem().unwrap().to_string_lossy().into_owned();
        for (framesize, stereo) in [("20", false), ("60", false), ("20", true)] {
            let name = format!(
                "{stem}-{framesize}ms{}",
                if stereo { "-stereo" } else { "" }
            );
            let source = if stereo {
                let s = d.join(format!("{stem}-stereo.wav"));
                run(Command::new("sox")
                    .arg(&wav)
                    .args(["-c", "2"])
                    .arg(&s)
                    .args(["remix", "1", "1v0.5"]));
                s
            } else {
                wav.clone()
            };
            let opus = d.join(format!("{name}.opus"));
            opusenc(&source, &opus, "16", framesize);
            let bytes = std::fs::read(&opus).unwrap();

            // At 48 kHz both run libopus with no resampler: sample for sample (stereo mixed
            // by libopus here and by the test from opusdec's two channels).
            let ours48 = stream::decode_at(&bytes, 48_000).unwrap();
            let theirs48_wav = d.join(format!("{name}-48k.wav"));
            opusdec(&opus, &theirs48_wav, 48_000);
            let theirs48 = mono(&theirs48_wav, stereo);
            assert_eq!(ours48.pcm.len(), theirs48.len(), "{name}: length at 48 kHz");
            let diff = max_abs_diff(&ours48.pcm, &theirs48);
            let snr48 = snr_db(&theirs48, &ours48.pcm);
            eprintln!("{name}: 48 kHz max difference {diff}, SNR {snr48:.1} dB");
            if stereo {
                assert!(snr48 > 40.0, "{name}: 48 kHz SNR {snr48:.1} dB");
            } else {
                assert!(diff <= 1, "{name}: 48 kHz samples differ by up to {diff}");
            }

            // At 8 kHz lipcall's libopus decodes straight to 8 kHz; opusdec decodes at 48 kHz
            // and resamples with the Speex resampler.
            let ours_wav = d.join(format!("{name}-ours.wav"));
            run(lipcall()
                .arg("decode")
                .arg(&opus)
                .arg(&ours_wav)
                .args(["--rate", "8000"]));
            let (rate, ours) = read_wav_i16(&ours_wav);
            assert_eq!(rate, 8000);
            let theirs_wav = d.join(format!("{name}-opusdec.wav"));
            opusdec(&opus, &theirs_wav, 8000);
            let theirs = mono(&theirs_wav, stereo);
            assert_eq!(ours.len(), theirs.len(), "{name}: length at 8 kHz");
            let snr8 = snr_db(&theirs, &ours);
            eprintln!("{name}: 8 kHz SNR against opusdec {snr8:.1} dB");
            assert!(snr8 > 10.0, "{name}: 8 kHz SNR {snr8:.1} dB");
        }
    }
}

/// A WAV's samples, the two channels averaged for a stereo one.
fn mono(path: &Path, stereo: bool) -> Vec<i16> {
    let (_, s) = read_wav_i16(path);
    if !stereo {
        return s;
    }
    s.chunks_exact(2)
        .map(|c| ((i32::from(c[0]) + i32::from(c[1])) / 2) as i16)
        .collect()
}

/// Mutated files (bytes flipped inside valid pages, cut anywhere) are errors or audio, never
/// a panic, and never more audio than the packets can carry.
#[test]
fn mutated_files_never_panic() {
    use lipcall::codec::opus::ogg_file;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = timit_8k(d, "dr2-faem0", "sa1");
    let opus = d.join("faem0.opus");
    run(lipcall().arg("encode").arg(&wav).arg(&opus));
    let bytes = std::fs::read(&opus).unwrap();
    let file = ogg_file::read(&bytes).unwrap();
    let mut seed = 0x2545_f491_u32;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed
    };
    let packets: Vec<Vec<u8>> = file.pages.iter().flat_map(|p| p.packets.clone()).collect();
    let mut outcomes = [0usize; 2];
    for round in 0..300 {
        let mut head = file.head.to_packet();
        let mut packets = packets.clone();
        for _ in 0..1 + next() % 4 {
            let target = next() as usize % (packets.len() + 1);
            let p = if target == packets.len() {
                &mut head
            } else {
                &mut packets[target]
            };
            let at = next() as usize % p.len();
            match next() % 3 {
                0 => p[at] ^= 1 << (next() % 8),
                1 => p.truncate(at),
                _ => p[at] = next() as u8,
            }
        }
        let granule = |i: usize| (i as u64 + 1) * 960 + u64::from(round % 3 == 0) * 1_000_000;
        let rebuilt = ogg_opus_raw(&head, &packets, granule);
        let cut = if round % 5 == 0 {
            next() as usize % rebuilt.len()
        } else {
            rebuilt.len()
        };
        match stream::decode(&rebuilt[..cut]) {
            Ok(decoded) => {
                assert!(decoded.pcm.len() <= packets.len() * 960);
                outcomes[0] += 1;
            }
            Err(e) => {
                assert!(!e.to_string().is_empty());
                outcomes[1] += 1;
            }
        }
    }
    eprintln!("{} decoded, {} refused", outcomes[0], outcomes[1]);
}

/// An Ogg Opus file around raw header and audio packets, with valid pages.
fn ogg_opus_raw(head: &[u8], audio: &[Vec<u8>], granule: impl Fn(usize) -> u64) -> Vec<u8> {
    use ogg::writing::{PacketWriteEndInfo, PacketWriter};
    let mut w = PacketWriter::new(Vec::new());
    let mut tags = b"OpusTags".to_vec();
    tags.extend_from_slice(&[0; 8]);
    w.write_packet(head.to_vec(), 9, PacketWriteEndInfo::EndPage, 0)
        .unwrap();
    w.write_packet(tags, 9, PacketWriteEndInfo::EndPage, 0)
        .unwrap();
    for (i, p) in audio.iter().enumerate() {
        let end = if i + 1 == audio.len() {
            PacketWriteEndInfo::EndStream
        } else if i % 50 == 49 {
            PacketWriteEndInfo::EndPage
        } else {
            PacketWriteEndInfo::NormalPacket
        };
        w.write_packet(p.clone(), 9, end, granule(i)).unwrap();
    }
    w.into_inner()
}

//! Bad input on the command line: a clear one-line error and exit 1 (2 for bad usage), no panic.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

fn fails_cleanly(args: &[&Path], expected: &str) {
    let out = lipcall().args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "one line: {stderr}");
    assert!(
        stderr.to_lowercase().contains(&expected.to_lowercase()),
        "{args:?}: expected {expected:?} in {stderr}"
    );
}

#[test]
fn unreadable_inputs_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = d.join("notes.wav");
    std::fs::write(&text, "this is not audio\n").unwrap();
    let empty = d.join("empty.spx");
    std::fs::write(&empty, b"").unwrap();
    let out_wav = d.join("out.wav");
    let out_spx = d.join("out.spx");
    let p = Path::new;

    fails_cleanly(&[p("encode"), &text, &out_spx], "not a readable WAV");
    fails_cleanly(&[p("encode"), &empty, &out_spx], "not a readable WAV");
    fails_cleanly(
        &[p("encode"), &d.join("missing.wav"), &out_spx],
        "No such file",
    );
    fails_cleanly(&[p("decode"), &empty, &out_wav], "empty");
    fails_cleanly(&[p("decode"), &text, &out_wav], "not an Ogg file");

    // Ogg Vorbis made by sox.
    let vorbis = d.join("tone.ogg");
    run(Command::new("sox")
        .args(["-n", "-r", "8000", "-c", "1"])
        .arg(&vorbis)
        .args(["synth", "0.5", "sine", "440"]));
    fails_cleanly(&[p("decode"), &vorbis, &out_wav], "Vorbis");

    // A real Speex file cut short.
    let wav = demo_8k(d);
    let spx = d.join("demo.spx");
    run(lipcall().arg("encode").arg(&wav).arg(&spx));
    let bytes = std::fs::read(&spx).unwrap();
    let truncated = d.join("truncated.spx");
    std::fs::write(&truncated, &bytes[..bytes.len() * 2 / 3]).unwrap();
    fails_cleanly(&[p("decode"), &truncated, &out_wav], "truncated");

    // What send cannot send; a payload type taken from the codec being sent.
    let to = p("127.0.0.1:9");
    fails_cleanly(&[p("send"), &text, p("--to"), to], "not a readable WAV");
    fails_cleanly(
        &[p("send"), &d.join("a.flac"), p("--to"), to],
        "expected a .wav, .spx or .opus",
    );
    fails_cleanly(&[p("send"), &empty, p("--to"), to], "empty");
    fails_cleanly(
        &[
            p("send"),
            &wav,
            p("--to"),
            to,
            p("--codec"),
            p("opus"),
            p("--pt"),
            p("speex=96"),
        ],
        "no RTP payload type is mapped to opus",
    );
}

/// An Ogg Opus file from raw packets (valid pages, so the packets themselves are what is bad):
/// head and tags alone on their pages, then audio packets 20 ms apart.
fn ogg_opus(head: &[u8], tags: &[u8], audio: &[Vec<u8>]) -> Vec<u8> {
    use ogg::writing::{PacketWriteEndInfo, PacketWriter};
    let mut w = PacketWriter::new(Vec::new());
    w.write_packet(head.to_vec(), 1, PacketWriteEndInfo::EndPage, 0)
        .unwrap();
    w.write_packet(tags.to_vec(), 1, PacketWriteEndInfo::EndPage, 0)
        .unwrap();
    for (i, p) in audio.iter().enumerate() {
        let end = if i + 1 == audio.len() {
            PacketWriteEndInfo::EndStream
        } else {
            PacketWriteEndInfo::NormalPacket
        };
        w.write_packet(p.clone(), 1, end, (i as u64 + 1) * 960)
            .unwrap();
    }
    w.into_inner()
}

#[test]
fn broken_opus_files_give_one_line_errors() {
    use lipcall::codec::opus::ogg_file;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out_wav = d.join("out.wav");
    let wav = demo_8k(d);
    let good = d.join("demo.opus");
    run(lipcall().arg("encode").arg(&wav).arg(&good));
    let bytes = std::fs::read(&good).unwrap();
    let file = ogg_file::read(&bytes).unwrap();
    let head = file.head.to_packet();
    let audio: Vec<Vec<u8>> = file.pages.iter().flat_map(|p| p.packets.clone()).collect();
    let mut tags = b"OpusTags".to_vec();
    tags.extend_from_slice(&[1, 0, 0, 0, b'v', 0, 0, 0, 0]);

    let case = |name: &str, data: &[u8], expected: &str| {
        let path = d.join(name);
        std::fs::write(&path, data).unwrap();
        fails_cleanly(&[Path::new("decode"), &path, &out_wav], expected);
    };
    let head_with = |at: usize, value: u8| {
        let mut h = head.clone();
        h[at] = value;
        ogg_opus(&h, &tags, &audio)
    };
    case("cut.opus", &bytes[..bytes.len() * 2 / 3], "truncated");
    case("magic.opus", &head_with(7, b'X'), "not Opus");
    case("version.opus", &head_with(8, 0x10), "version 16");
    case("nochannels.opus", &head_with(9, 0), "channel count 0");
    case("family0.opus", &head_with(9, 3), "1 or 2 channels");
    case("family1.opus", &head_with(18, 1), "mapping table");
    let mut surround = head.clone();
    surround[9] = 3;
    surround[18] = 1;
    surround.extend_from_slice(&[2, 1, 0, 1, 2]);
    case(
        "surround.opus",
        &ogg_opus(&surround, &tags, &audio),
        "2 streams",
    );
    let mut vendor = tags.clone();
    vendor[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    case(
        "vendor.opus",
        &ogg_opus(&head, &vendor, &audio),
        "vendor string",
    );
    let mut count = tags.clone();
    count[13..17].copy_from_slice(&0x4000_0000u32.to_le_bytes());
    case(
        "comments.opus",
        &ogg_opus(&head, &count, &audio),
        "more comments",
    );
    case(
        "notags.opus",
        &ogg_opus(&head, b"OpusHead", &audio),
        "OpusTags",
    );
    // Granule positions that disagree with the audio (a middle page a second ahead): decoded
    // by its packets, and said.
    let skewed = ogg_file::write(
        &file.head,
        "v",
        &[],
        &audio,
        |i| (i as u64 + 1) * 960 + if i == 99 { 48_000 } else { 0 },
        7,
    )
    .unwrap();
    let skewed_path = d.join("skewed.opus");
    std::fs::write(&skewed_path, skewed).unwrap();
    let out = lipcall()
        .arg("decode")
        .arg(&skewed_path)
        .arg(&out_wav)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("1 page(s) carry granule positions that disagree"),
        "{stderr}"
    );
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x55;
    case("crc.opus", &flipped, "damaged");
    // Every packet invalid (code 3 with a frame count of 0): no audio, not a second of silence.
    case(
        "allbad.opus",
        &ogg_opus(&head, &tags, &vec![vec![0xFF, 0x00]; 50]),
        "none of its 50 audio packets is valid Opus",
    );
    // A Speex file named .opus is named for what it is.
    let spx = d.join("demo.spx");
    run(lipcall().arg("encode").arg(&wav).arg(&spx));
    case(
        "speex.opus",
        &std::fs::read(&spx).unwrap(),
        "Speex, not Opus",
    );
    // Speex-only output flags on an Opus encode are bad usage, and so the other way round.
    for args in [
        vec!["encode", "a.wav", "b.opus", "--quality", "5"],
        vec!["encode", "a.wav", "b.spx", "--bitrate", "16"],
        vec!["encode", "a.wav", "b.spx", "--codec", "opus", "--vbr"],
        vec!["encode", "a.wav", "b.opus", "--bitrate", "3"],
    ] {
        let out = lipcall().args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
    }
}

#[test]
fn bad_usage_exits_2() {
    for args in [
        vec!["encode"],
        vec!["encode", "a.wav", "b.spx", "--quality", "11"],
        vec!["frobnicate"],
        vec!["send", "a.wav", "--to", "127.0.0.1:9", "--codec", "g729"],
        vec!["send", "a.wav", "--to", "127.0.0.1:9", "--pt", "opus=5"],
        vec!["send", "a.wav", "--to", "127.0.0.1:9", "--pt", "opus"],
        vec!["receive", "--listen", "127.0.0.1:0", "--pt", "vorbis=100"],
    ] {
        let out = lipcall().args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
    }
}

#[test]
fn a_payload_type_taken_from_a_codec_is_said_on_receive() {
    let out = lipcall()
        .args(["receive", "--listen", "127.0.0.1:0", "--seconds", "0.5"])
        .args(["--pt", "opus=110", "--pt", "speex=110"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("warning: --pt leaves opus without a payload type"),
        "{stderr}"
    );
    assert!(!stderr.contains("leaves speex"), "{stderr}");
}

#[test]
fn a_peer_timeout_too_short_to_hear_anyone_is_refused() {
    for timeout in ["1e-300", "0.001"] {
        let out = lipcall()
            .args(["receive", "--listen", "127.0.0.1:0", "--seconds", "1"])
            .args(["--peer-timeout", timeout])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{timeout}: {stderr}");
        assert!(stderr.contains("--peer-timeout"), "{stderr}");
    }
}

#[test]
fn a_48k_stereo_wav_is_resampled_not_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let stereo = d.join("stereo48k.wav");
    run(Command::new("sox")
        .arg(repo_file("assets/speech/demo.wav"))
        .args(["-D", "-r", "48000", "-c", "2", "-b", "16"])
        .arg(&stereo));
    let (_, original) = read_wav_i16(&stereo);
    let seconds = original.len() as f64 / 2.0 / 48_000.0;
    let spx = d.join("out.spx");
    let wav = d.join("out.wav");
    run(lipcall().arg("encode").arg(&stereo).arg(&spx));
    run(lipcall().arg("decode").arg(&spx).arg(&wav));
    let (rate, decoded) = read_wav_i16(&wav);
    assert_eq!(rate, 8000);
    let expected = (seconds * 8000.0).round() as usize;
    assert!(
        decoded.len().abs_diff(expected) < 160,
        "{} vs {expected}",
        decoded.len()
    );
    // And it still sounds like the speech: compare with the mono 8 kHz path.
    let mono = demo_8k(d);
    let (_, reference) = read_wav_i16(&mono);
    let snr = snr_db(&reference, &decoded);
    assert!(snr > 3.0, "SNR against the mono reference {snr:.2} dB");
}

#[test]
fn the_app_refuses_a_bad_listen_address_before_opening_a_window() {
    let p = Path::new;
    fails_cleanly(
        &[p("--listen"), p("not-an-address"), p("--no-audio")],
        "--listen",
    );
}

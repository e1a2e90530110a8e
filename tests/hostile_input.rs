//! Small hostile or careless inputs (issue 15): each gets a one-line error and exit 1, quickly
//! and in bounded memory; none hangs, aborts on allocation or panics.
//!
//! Every run is under an address-space limit and a deadline, so a regression fails the test
//! instead of taking the machine down. `LIPCALL_BIN` runs the checks against another build.

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Address space a run may take (the binary itself maps a few hundred MB).
const MEMORY_KB: u64 = 2_000_000;
/// A run is killed after this; an answer must come well before.
const DEADLINE: Duration = Duration::from_secs(15);
const FAST: Duration = Duration::from_secs(5);

fn lipcall_bin() -> PathBuf {
    std::env::var_os("LIPCALL_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_lipcall")))
}

struct Outcome {
    code: Option<i32>,
    stderr: String,
    elapsed: Duration,
}

fn run_bounded<S: AsRef<OsStr>>(args: &[S], dir: &Path) -> Outcome {
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {MEMORY_KB}; exec \"$0\" \"$@\""))
        .arg(lipcall_bin())
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if start.elapsed() > DEADLINE {
            child.kill().unwrap();
            child.wait().unwrap();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let elapsed = start.elapsed();
    let mut stderr = String::new();
    use std::io::Read;
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    Outcome {
        code: status.and_then(|s| s.code()),
        stderr,
        elapsed,
    }
}

/// `args` fail with exit 1, one line naming `expected`, within [`FAST`].
#[track_caller]
fn refused<S: AsRef<OsStr> + std::fmt::Debug>(dir: &Path, args: &[S], expected: &str) {
    let out = run_bounded(args, dir);
    let stderr = out.stderr.trim_end();
    assert!(
        out.elapsed < FAST,
        "{args:?}: took {:?} (exit {:?}): {stderr}",
        out.elapsed,
        out.code
    );
    assert_eq!(out.code, Some(1), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    assert_eq!(stderr.lines().count(), 1, "{args:?}: one line: {stderr}");
    assert!(
        stderr.to_lowercase().contains(&expected.to_lowercase()),
        "{args:?}: expected {expected:?} in {stderr}"
    );
}

/// A glTF head: one mesh of `vertices` positions (in a data URI, or in `uri`) with `targets`
/// morph targets named `aa`, all on the positions' own accessor, placed by `nodes` (JSON) and
/// a scene of `roots`.
fn gltf(vertices: usize, targets: usize, nodes: &str, roots: &str, uri: Option<&str>) -> String {
    let bytes = vertices * 12;
    let uri = match uri {
        Some(uri) => uri.to_owned(),
        None => {
            let mut data = Vec::with_capacity(bytes);
            for i in 0..vertices {
                for c in [i % 7, i % 5, i % 3] {
                    data.extend_from_slice(&(c as f32).to_le_bytes());
                }
            }
            format!(
                "data:application/octet-stream;base64,{}",
                common::base64(&data)
            )
        }
    };
    let target_list = vec![r#"{"POSITION":0}"#; targets].join(",");
    let names = vec![r#""aa""#; targets].join(",");
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots}}}],
"nodes":{nodes},
"meshes":[{{"extras":{{"targetNames":[{names}]}},
  "primitives":[{{"attributes":{{"POSITION":0}},"targets":[{target_list}]}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{vertices},"type":"VEC3",
  "min":[0,0,0],"max":[6,4,2]}}],
"bufferViews":[{{"buffer":0,"byteLength":{bytes}}}],
"buffers":[{{"byteLength":{bytes},"uri":"{uri}"}}]}}"#
    )
}

fn animate_with_head(head: &Path) -> Vec<PathBuf> {
    vec![
        "animate".into(),
        "missing.wav".into(),
        "--frames".into(),
        "frames".into(),
        "--head".into(),
        head.to_owned(),
    ]
}

#[test]
fn gltf_nodes_sharing_children_are_refused_not_walked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Node i has children [i+1, i+1]: 2^40 paths to the last node, which holds the mesh.
    let depth = 40;
    let nodes: Vec<String> = (0..depth)
        .map(|i| format!(r#"{{"children":[{0},{0}]}}"#, i + 1))
        .chain([r#"{"mesh":0}"#.to_owned()])
        .collect();
    let path = d.join("shared.gltf");
    std::fs::write(
        &path,
        gltf(3, 1, &format!("[{}]", nodes.join(",")), "[0]", None),
    )
    .unwrap();
    assert!(std::fs::metadata(&path).unwrap().len() < 4096);
    refused(d, &animate_with_head(&path), "more than one parent");
}

#[test]
fn one_accessor_behind_many_meshes_and_targets_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 240 KB of positions, read as 500 targets by each of 100 nodes: 50,000 copies.
    let nodes: Vec<&str> = vec![r#"{"mesh":0}"#; 100];
    let roots: Vec<String> = (0..100).map(|i| i.to_string()).collect();
    let path = d.join("shared-accessor.gltf");
    std::fs::write(
        &path,
        gltf(
            20_000,
            500,
            &format!("[{}]", nodes.join(",")),
            &format!("[{}]", roots.join(",")),
            None,
        ),
    )
    .unwrap();
    refused(
        d,
        &animate_with_head(&path),
        "far more data than the file holds",
    );
}

/// A 16-bit PCM WAV whose header claims `claimed` bytes of audio at `rate`, holding `real`.
fn wav_header_lying(path: &Path, rate: u32, claimed: u32, real: usize) {
    let mut b = b"RIFF".to_vec();
    b.extend_from_slice(&claimed.saturating_add(36).to_le_bytes());
    b.extend_from_slice(b"WAVEfmt ");
    b.extend_from_slice(&16u32.to_le_bytes());
    b.extend_from_slice(&1u16.to_le_bytes());
    b.extend_from_slice(&1u16.to_le_bytes());
    b.extend_from_slice(&rate.to_le_bytes());
    b.extend_from_slice(&(rate * 2).to_le_bytes());
    b.extend_from_slice(&2u16.to_le_bytes());
    b.extend_from_slice(&16u16.to_le_bytes());
    b.extend_from_slice(b"data");
    b.extend_from_slice(&claimed.to_le_bytes());
    b.resize(b.len() + real, 0);
    std::fs::write(path, b).unwrap();
}

#[test]
fn wav_headers_claiming_absurd_rates_or_sizes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 16 KB at 1 Hz: 8000 s of audio once resampled to 8 kHz.
    wav_header_lying(&d.join("1hz.wav"), 1, 16_000, 16_000);
    refused(d, &["encode", "1hz.wav", "out.spx"], "sample rate 1 Hz");
    wav_header_lying(&d.join("1mhz.wav"), 1_000_000, 16_000, 16_000);
    refused(
        d,
        &["encode", "1mhz.wav", "out.spx"],
        "sample rate 1000000 Hz",
    );
    // 20 KB claiming 2 GB.
    wav_header_lying(&d.join("2gb.wav"), 44_100, 0x7fff_fff0, 20_000);
    refused(
        d,
        &["encode", "2gb.wav", "out.spx"],
        "the file has 20044 bytes",
    );
    refused(d, &["animate", "2gb.wav", "--weights", "w.csv"], "claims");
    // The same in a corpus: the phone targets were sized by the header's length at 1 Hz.
    for region in 1..=6 {
        let speaker = d.join(format!("corpus/dr{region}-test0"));
        std::fs::create_dir_all(&speaker).unwrap();
        wav_header_lying(&speaker.join("sa1.wav"), 1, 0x7fff_fff0, 20_000);
        std::fs::write(speaker.join("sa1.phn"), "0 100 h#\n").unwrap();
    }
    refused(d, &["decompose", "--corpus", "corpus"], "sample rate 1 Hz");
    refused(d, &["evaluate", "--corpus", "corpus"], "sample rate 1 Hz");
    // train says what it is about to do first; the error is its last line.
    let args = ["train", "--corpus", "corpus", "--out", "m.lipmodel"];
    let out = run_bounded(&args, d);
    assert_eq!(out.code, Some(1), "{}", out.stderr);
    assert!(out.elapsed < FAST, "{:?}", out.elapsed);
    let last = out.stderr.trim_end().lines().last().unwrap_or_default();
    assert!(last.contains("sample rate 1 Hz"), "{}", out.stderr);
}

#[test]
fn devices_and_fifos_are_refused_as_input_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = d.join("tone.wav");
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(&wav, spec).unwrap();
    for i in 0..8000 {
        w.write_sample(((i as f32 * 0.3).sin() * 8000.0) as i16)
            .unwrap();
    }
    w.finalize().unwrap();
    let zero = "/dev/zero";
    refused(d, &["decode", zero, "out.wav"], "not a regular file");
    refused(d, &["encode", zero, "out.spx"], "not a regular file");
    refused(
        d,
        &["animate", zero, "--weights", "w.csv"],
        "not a regular file",
    );
    refused(
        d,
        &["animate", "tone.wav", "--model", zero, "--weights", "w.csv"],
        "not a regular file",
    );
    refused(
        d,
        &["animate", "tone.wav", "--head", zero, "--frames", "f"],
        "not a regular file",
    );
    refused(
        d,
        &["decompose", "--markers", zero, "--key-frames", zero],
        "not a regular file",
    );
    // Links to it, named as the file types they stand for.
    for name in ["zero.bin", "zero.spx"] {
        std::os::unix::fs::symlink(zero, d.join(name)).unwrap();
    }
    refused(
        d,
        &["send", "zero.spx", "--to", "127.0.0.1:9"],
        "not a regular file",
    );
    // A glTF whose external buffer is one.
    let path = d.join("linked.gltf");
    std::fs::write(
        &path,
        gltf(3, 1, r#"[{"mesh":0}]"#, "[0]", Some("zero.bin")),
    )
    .unwrap();
    refused(d, &animate_with_head(&path), "not a regular file");
    // A FIFO nobody writes to would block the open itself.
    let fifo = d.join("pipe.spx");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    refused(d, &["decode", "pipe.spx", "out.wav"], "not a regular file");
    // A directory.
    refused(d, &["decode", ".", "out.wav"], "not a regular file");
}

#[test]
fn a_missing_file_names_its_os_error_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for args in [
        vec!["encode", "missing.wav", "out.spx"],
        vec![
            "animate",
            "missing.wav",
            "--frames",
            "f",
            "--head",
            "none.glb",
        ],
        vec![
            "decompose",
            "--markers",
            "none.csv",
            "--key-frames",
            "k.csv",
        ],
        vec!["train", "--corpus", "no-corpus", "--out", "m.lipmodel"],
    ] {
        refused(d, &args, "No such file");
        let out = run_bounded(&args, d);
        assert_eq!(
            out.stderr.matches("os error 2").count(),
            1,
            "{args:?}: {}",
            out.stderr
        );
    }
}

#[test]
fn run_lengths_that_are_not_a_number_of_seconds_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for bad in ["NaN", "inf", "-1", "0", "1e300"] {
        for command in ["receive", "relay"] {
            let args = [command, "--listen", "127.0.0.1:0", "--seconds", bad];
            let out = run_bounded(&args, d);
            assert_eq!(out.code, Some(2), "{args:?}: {}", out.stderr);
            assert!(out.elapsed < FAST, "{args:?}: {:?}", out.elapsed);
            assert!(
                out.stderr.contains("must be a number of seconds above 0"),
                "{args:?}: {}",
                out.stderr
            );
        }
        let out = run_bounded(&["--quit-after", bad, "--no-audio"], d);
        assert_eq!(out.code, Some(2), "--quit-after {bad}: {}", out.stderr);
    }
    // A good one still runs, and stops.
    let out = run_bounded(&["relay", "--listen", "127.0.0.1:0", "--seconds", "0.2"], d);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
}

/// The built-in model with every value of the lines named in `keys` replaced by `value`, the
/// signs alternating.
fn model_with(keys: &[&str], value: &str) -> String {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/models/default.lipmodel"),
    )
    .unwrap();
    let mut out = String::new();
    for line in text.lines() {
        let mut words = line.split(' ');
        let key = words.next().unwrap_or_default();
        if keys.contains(&key) {
            out.push_str(key);
            for (i, _) in words.enumerate() {
                out.push_str(if i % 2 == 0 { " " } else { " -" });
                out.push_str(value);
            }
        } else {
            out.push_str(line);
        }
        out.push('\n');
    }
    out
}

#[test]
fn models_with_huge_weights_are_refused_and_the_largest_allowed_give_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wav = d.join("tone.wav");
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(&wav, spec).unwrap();
    for i in 0..16_000 {
        let t = i as f32 / 8000.0;
        let s = (t * 2.0 * std::f32::consts::PI * 180.0).sin() * (t * 7.0).sin().abs();
        w.write_sample((s * 12_000.0) as i16).unwrap();
    }
    w.finalize().unwrap();
    let all = ["input_scale", "w1", "b1", "w2", "b2"];
    std::fs::write(d.join("huge.lipmodel"), model_with(&all, "3e38")).unwrap();
    for visemes in ["6", "15"] {
        refused(
            d,
            &[
                "animate",
                "tone.wav",
                "--model",
                "huge.lipmodel",
                "--visemes",
                visemes,
                "--weights",
                "w.csv",
            ],
            "bad number",
        );
    }
    // At the limit the logits stay finite: every row is convex weights.
    std::fs::write(d.join("limit.lipmodel"), model_with(&all, "10000")).unwrap();
    for visemes in [None, Some("6")] {
        let mut args = vec!["animate", "tone.wav", "--model", "limit.lipmodel"];
        args.extend(["--weights", "w.csv"]);
        if let Some(v) = visemes {
            args.extend(["--visemes", v]);
        }
        let out = run_bounded(&args, d);
        assert_eq!(out.code, Some(0), "{args:?}: {}", out.stderr);
        let csv = std::fs::read_to_string(d.join("w.csv")).unwrap();
        let rows: Vec<&str> = csv.lines().skip(1).collect();
        assert!(rows.len() > 90, "{}", rows.len());
        for row in rows {
            let weights: Vec<f32> = row.split(',').skip(2).map(|x| x.parse().unwrap()).collect();
            let sum: f32 = weights.iter().sum();
            assert!(
                weights.iter().all(|w| w.is_finite() && *w >= 0.0) && (sum - 1.0).abs() < 1e-2,
                "{args:?}: {row}"
            );
        }
    }
}

/// An Ogg Speex file with its audio packets scrambled and valid page checksums (so the Ogg
/// layer passes them on and the codec sees the damage).
fn scrambled_speex(good: &[u8]) -> Vec<u8> {
    use ogg::writing::{PacketWriteEndInfo, PacketWriter};
    let mut reader = ogg::reading::PacketReader::new(std::io::Cursor::new(good));
    let mut writer = PacketWriter::new(Vec::new());
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut index = 0;
    while let Some(packet) = reader.read_packet().unwrap() {
        let mut data = packet.data.clone();
        if index >= 2 {
            for byte in &mut data {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                if state.is_multiple_of(3) {
                    *byte = (state >> 40) as u8;
                }
            }
        }
        let end = if packet.last_in_stream() {
            PacketWriteEndInfo::EndStream
        } else if packet.last_in_page() {
            PacketWriteEndInfo::EndPage
        } else {
            PacketWriteEndInfo::NormalPacket
        };
        writer
            .write_packet(data, packet.stream_serial(), end, packet.absgp_page())
            .unwrap();
        index += 1;
    }
    writer.into_inner()
}

#[test]
fn a_damaged_speex_stream_gets_one_summary_not_a_line_per_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(d.join("tone.wav"), spec).unwrap();
    for i in 0..40_000 {
        let t = i as f32 / 8000.0;
        let s = (t * 2.0 * std::f32::consts::PI * 220.0).sin() * (t * 3.0).sin();
        w.write_sample((s * 12_000.0) as i16).unwrap();
    }
    w.finalize().unwrap();
    let out = run_bounded(&["encode", "tone.wav", "good.spx"], d);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    let good = std::fs::read(d.join("good.spx")).unwrap();
    std::fs::write(d.join("bad.spx"), scrambled_speex(&good)).unwrap();
    let out = run_bounded(&["decode", "bad.spx", "out.wav"], d);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(!out.stderr.contains("notification"), "{}", out.stderr);
    let lines: Vec<&str> = out.stderr.lines().collect();
    assert!(lines.len() <= 2, "{}", out.stderr);
    assert!(
        lines
            .iter()
            .any(|l| l.contains("damaged packet(s) were partly skipped")),
        "{}",
        out.stderr
    );
}

#[test]
fn an_empty_passphrase_is_refused_not_called_encrypted() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let key = d.join("key");
    for (text, why) in [
        ("", "its first line is empty"),
        ("\nsecond line", "its first line is empty"),
        ("   \n", "passphrase is blank"),
    ] {
        std::fs::write(&key, text).unwrap();
        let key = key.to_str().unwrap();
        for args in [
            vec![
                "receive",
                "--listen",
                "127.0.0.1:0",
                "--seconds",
                "0.3",
                "--key-file",
                key,
            ],
            vec![
                "send",
                "missing.wav",
                "--to",
                "127.0.0.1:9",
                "--key-file",
                key,
            ],
        ] {
            let out = run_bounded(&args, d);
            assert_eq!(out.code, Some(1), "{args:?}: {}", out.stderr);
            assert!(out.stderr.contains(why), "{args:?}: {}", out.stderr);
        }
    }
}

#[test]
fn send_fails_when_no_packet_could_be_sent() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(d.join("short.wav"), spec).unwrap();
    for i in 0..2400 {
        w.write_sample(((i as f32 * 0.2).sin() * 6000.0) as i16)
            .unwrap();
    }
    w.finalize().unwrap();
    // Broadcast without SO_BROADCAST: every send fails (EACCES).
    let args = [
        "send",
        "short.wav",
        "--to",
        "255.255.255.255:9",
        "--no-rtcp",
    ];
    let out = run_bounded(&args, d);
    assert_eq!(out.code, Some(1), "{}", out.stderr);
    let last = out.stderr.trim_end().lines().last().unwrap_or_default();
    assert!(
        last.contains("no packet could be sent to 255.255.255.255:9"),
        "{}",
        out.stderr
    );
}

/// The header and comment packets of an Ogg stream, without a single audio packet.
fn headers_only(good: &[u8]) -> Vec<u8> {
    use ogg::writing::{PacketWriteEndInfo, PacketWriter};
    let mut reader = ogg::reading::PacketReader::new(std::io::Cursor::new(good));
    let mut writer = PacketWriter::new(Vec::new());
    for end in [PacketWriteEndInfo::EndPage, PacketWriteEndInfo::EndStream] {
        let packet = reader.read_packet().unwrap().unwrap();
        let serial = packet.stream_serial();
        writer.write_packet(packet.data, serial, end, 0).unwrap();
    }
    writer.into_inner()
}

#[test]
fn decode_refuses_a_stream_without_audio_as_animate_does() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(d.join("tone.wav"), spec).unwrap();
    for i in 0..4000 {
        w.write_sample(((i as f32 * 0.2).sin() * 6000.0) as i16)
            .unwrap();
    }
    w.finalize().unwrap();
    for ext in ["spx", "opus"] {
        let good = format!("good.{ext}");
        let out = run_bounded(&["encode", "tone.wav", &good], d);
        assert_eq!(out.code, Some(0), "{}", out.stderr);
        let empty = format!("empty.{ext}");
        std::fs::write(
            d.join(&empty),
            headers_only(&std::fs::read(d.join(&good)).unwrap()),
        )
        .unwrap();
        refused(d, &["decode", &empty, "out.wav"], "holds no audio frame");
        refused(
            d,
            &["animate", &empty, "--weights", "w.csv"],
            "holds no audio frame",
        );
        assert!(!d.join("out.wav").exists());
    }
}

#[test]
fn a_stereo_speex_file_is_said_to_be_mixed_to_mono() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = hound::WavSpec {
        channels: 2,
        sample_rate: 8000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(d.join("stereo.wav"), spec).unwrap();
    for i in 0..8000 {
        let s = (i as f32 * 0.15).sin() * 8000.0;
        w.write_sample(s as i16).unwrap();
        w.write_sample((s * 0.25) as i16).unwrap();
    }
    w.finalize().unwrap();
    let made = Command::new("speexenc")
        .args(["--stereo", "-n", "stereo.wav", "stereo.spx"])
        .current_dir(d)
        .output()
        .expect("speexenc (install it: see README)");
    assert!(made.status.success(), "{made:?}");
    let out = run_bounded(&["decode", "stereo.spx", "out.wav"], d);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(
        out.stderr.contains("(stereo mixed to mono)"),
        "{}",
        out.stderr
    );
    let reader = hound::WavReader::open(d.join("out.wav")).unwrap();
    assert_eq!(reader.spec().channels, 1);
    assert!(
        reader.duration().abs_diff(8000) < 400,
        "{}",
        reader.duration()
    );
}

/// Starts `args` (which print `marker ADDR` on stderr once listening) and returns the child,
/// the address and a reader over the rest of its stderr.
fn spawn_listening(
    args: &[&str],
    marker: &str,
) -> (
    std::process::Child,
    std::net::SocketAddr,
    std::io::BufReader<std::process::ChildStderr>,
) {
    use std::io::BufRead;
    let mut child = Command::new(lipcall_bin())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    let found = loop {
        line.clear();
        match stderr.read_line(&mut line) {
            Ok(n) if n > 0 => {}
            _ => break None,
        }
        if let Some(rest) = line.split(marker).nth(1) {
            break rest.trim().parse().ok();
        }
    };
    match found {
        Some(addr) => (child, addr, stderr),
        None => {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{args:?}: no {marker:?} line with an address");
        }
    }
}

fn rtp_packet(seq: u16, payload_len: usize) -> Vec<u8> {
    let mut p = vec![0x80, 110];
    p.extend_from_slice(&seq.to_be_bytes());
    p.extend_from_slice(&(u32::from(seq) * 160).to_be_bytes());
    p.extend_from_slice(&0x1234_5678u32.to_be_bytes());
    p.resize(12 + payload_len, 0);
    p
}

#[test]
fn oversized_datagrams_are_dropped_and_counted_not_parsed_truncated() {
    use std::io::Read;
    let (mut child, addr, mut stderr) = spawn_listening(
        &["receive", "--listen", "127.0.0.1:0", "--seconds", "1"],
        "listening on ",
    );
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // Too large for any buffer the receiver takes: the kernel would cut it short.
    socket.send_to(&rtp_packet(1, 4000), addr).unwrap();
    socket.send_to(&rtp_packet(2, 38), addr).unwrap();
    let status = child.wait().unwrap();
    let mut rest = String::new();
    stderr.read_to_string(&mut rest).unwrap();
    assert!(status.success(), "{rest}");
    let summary = rest
        .lines()
        .find(|l| l.contains("datagrams="))
        .unwrap_or_else(|| panic!("{rest}"));
    assert!(
        summary.contains("datagrams=2 rtp=1 ") && summary.contains("malformed=1 "),
        "{summary}"
    );
}

#[test]
fn the_relay_drops_oversized_datagrams_instead_of_forwarding_them_cut() {
    use lipcall::net::control::{Control, ControlKind, Cookie, RoomId};
    use std::io::Read;
    let (mut child, relay, mut stderr) = spawn_listening(
        &["relay", "--listen", "127.0.0.1:0", "--seconds", "1.5"],
        "relay listening on ",
    );
    let room = RoomId::from_name("hostile");
    let members: Vec<std::net::UdpSocket> = (0..2)
        .map(|_| {
            let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            s.set_read_timeout(Some(Duration::from_millis(500)))
                .unwrap();
            let mut buf = [0u8; 64];
            // Join, then echo the relay's cookie.
            let mut request = Control::new(ControlKind::Join, room, Cookie::NONE);
            for answer in [ControlKind::Challenge, ControlKind::Joined] {
                s.send_to(&request.encode(), relay).unwrap();
                let (n, _) = s.recv_from(&mut buf).expect("the relay answers a join");
                let got = Control::decode(&buf[..n]).unwrap();
                assert_eq!(got.kind, answer);
                request = Control::new(ControlKind::Confirm, room, got.cookie);
            }
            s
        })
        .collect();
    members[0].send_to(&rtp_packet(1, 4000), relay).unwrap();
    members[0].send_to(&rtp_packet(2, 38), relay).unwrap();
    let mut sizes = Vec::new();
    let mut buf = vec![0u8; 8192];
    while let Ok((n, _)) = members[1].recv_from(&mut buf) {
        sizes.push(n);
    }
    assert_eq!(sizes, [50], "what the other member received");
    let status = child.wait().unwrap();
    let mut rest = String::new();
    stderr.read_to_string(&mut rest).unwrap();
    assert!(status.success(), "{rest}");
    assert!(rest.contains(" malformed=1 "), "{rest}");
}

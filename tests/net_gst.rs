//! Interop with GStreamer's RTP elements, both ways: Speex plain and with SRTP, Opus and PCMU;
//! payload types nobody mapped; several codecs in one call.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::net::{
    Announce, align, align_frames, decode_frames, fields, finish, num, ogg_packets,
    snr_at_best_lag, spawn, spawn_listening,
};
use common::{band_db, lipcall, read_wav_i16, run};
use lipcall::codec::any::{Codec, EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
use lipcall::codec::decoder::StreamDecoder;
use lipcall::net::srtp::MasterKey;

/// One test at a time: each runs real-time GStreamer pipelines and lipcall processes, and on a
/// loaded machine running them all at once starves the receivers' 20 ms pacing.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn clip(dir: &Path, seconds: &str) -> std::path::PathBuf {
    let demo = common::demo_8k(dir);
    let out = dir.join("clip.wav");
    run(Command::new("sox")
        .arg(&demo)
        .arg(&out)
        .args(["trim", "0", seconds]));
    out
}

fn gst_send(clip: &Path, port: u16, srtp: Option<&str>, reference: &Path) -> Command {
    let mut cmd = Command::new("gst-launch-1.0");
    cmd.arg("-q")
        .arg("filesrc")
        .arg(format!("location={}", clip.display()))
        .args(["!", "wavparse", "!", "audioconvert", "!", "audioresample"])
        .args(["!", "audio/x-raw,rate=8000,channels=1", "!", "speexenc"])
        .args(["!", "tee", "name=t", "t.", "!", "queue", "!", "rtpspeexpay"]);
    if let Some(key) = srtp {
        cmd.args(["!", "srtpenc"]).arg(format!("key={key}")).args([
            "rtp-cipher=aes-128-icm",
            "rtp-auth=hmac-sha1-80",
            "rtcp-cipher=aes-128-icm",
            "rtcp-auth=hmac-sha1-80",
        ]);
    }
    cmd.args(["!", "udpsink", "host=127.0.0.1"])
        .arg(format!("port={port}"))
        .args(["t.", "!", "queue", "!", "oggmux", "!", "filesink"])
        .arg(format!("location={}", reference.display()));
    cmd
}

fn gst_to_lipcall(srtp: bool) {
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let out = dir.path().join("received.wav");
    let features = dir.path().join("features.csv");
    let reference = dir.path().join("reference.spx");
    let key = MasterKey::from_passphrase("interop", "").to_hex();
    let mut receive = lipcall();
    receive
        .args(["receive", "--listen", "127.0.0.1:0"])
        .arg("--wav")
        .arg(&out)
        .arg("--features")
        .arg(&features)
        .args(["--seconds", "6"]);
    if srtp {
        receive.env("LIPCALL_KEY_HEX", &key);
    }
    let receiver = spawn_listening(&mut receive, Announce::Lipcall);
    run(&mut gst_send(
        &clip,
        receiver.port,
        srtp.then_some(key.as_str()),
        &reference,
    ));
    let (_, stderr) = receiver.finish(Duration::from_secs(60), "lipcall receive");
    let peer = fields(&stderr, "peer ");
    assert!(num(&peer, "received") >= 140.0, "{stderr}");
    if srtp {
        assert_eq!(num(&fields(&stderr, "lipcall: played"), "auth_failed"), 0.0);
    }

    // Nothing was lost on loopback, and nothing is claimed lost: rtpspeexpay stamps its first
    // packet 120 ticks long, which is no gap in the sequence.
    assert_eq!(num(&peer, "lost"), 0.0, "{stderr}");
    assert_eq!(num(&peer, "dropped"), 0.0, "{stderr}");

    let expected = decode_frames(&ogg_packets(&reference));
    let (rate, got) = read_wav_i16(&out);
    assert_eq!(rate, 8000);
    // Played = the stream, plus what is concealed after it while a late packet might still
    // come (it ends without BYE): the buffer's delay, one frame unless the machine is loaded.
    let frames = got.len() as i64 / 160;
    let sent = expected.len() as i64 / 160;
    let hold = (num(&peer, "target_ms") / 20.0).ceil().max(1.0) as i64;
    assert!(
        frames >= sent && frames <= sent + hold,
        "{frames} vs {sent}: {stderr}"
    );
    let a = align(&expected, &got, 2000);
    assert!(a.chunk_snr.len() >= 8, "{a:?}");
    assert!(a.median() > 60.0, "median SNR {:.1} dB: {a:?}", a.median());
    // Aligned throughout: at the one lag that fits the first second, the whole stream is
    // speexdec's decode of the same frames (no frame skipped or inserted on loopback).
    let (whole, lag) = snr_at_best_lag(&expected, &got, 2000);
    let line = stderr
        .lines()
        .find(|l| l.starts_with("peer "))
        .unwrap_or("");
    eprintln!(
        "whole stream against speexdec: {whole:.1} dB at lag {lag}; {frames} frames for {sent}; {line}"
    );
    assert!(whole > 60.0, "{whole:.1} dB at lag {lag}: {a:?}");
    assert_eq!(lag % 160, 0);
    let rows = std::fs::read_to_string(&features).unwrap().lines().count() - 1;
    assert_eq!(rows as i64, frames);
}

/// GStreamer speexenc + rtpspeexpay into `lipcall receive`: the WAV matches a direct decode
/// of the very packets GStreamer encoded (captured with a tee into an Ogg file).
#[test]
fn gstreamer_rtpspeexpay_into_lipcall_receive() {
    let _serial = serial();
    gst_to_lipcall(false);
}

/// The same through GStreamer's srtpenc (libsrtp) into `lipcall receive` with LIPCALL_KEY_HEX.
#[test]
fn gstreamer_srtpenc_into_lipcall_receive() {
    let _serial = serial();
    gst_to_lipcall(true);
}

fn lipcall_to_gst(srtp: bool) {
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let spx = dir.path().join("clip.spx");
    run(lipcall().arg("encode").arg(&clip).arg(&spx));
    let out = dir.path().join("gst.wav");
    let key = MasterKey::from_passphrase("interop", "").to_hex();
    let ssrc = 0x1234_abcd_u32;
    let caps = if srtp {
        format!(
            "application/x-srtp,media=audio,clock-rate=8000,encoding-name=SPEEX,payload=110,\
             ssrc=(uint){ssrc},srtp-key=(buffer){key},srtp-cipher=aes-128-icm,\
             srtp-auth=hmac-sha1-80,srtcp-cipher=aes-128-icm,srtcp-auth=hmac-sha1-80,roc=(uint)0"
        )
    } else {
        "application/x-rtp,media=audio,clock-rate=8000,encoding-name=SPEEX,payload=110".into()
    };
    let mut gst = gst_udpsrc(&caps);
    if srtp {
        gst.args(["!", "srtpdec"]);
    }
    gst.args([
        "!",
        "rtpspeexdepay",
        "!",
        "speexdec",
        "!",
        "wavenc",
        "!",
        "filesink",
    ])
    .arg(format!("location={}", out.display()));
    let gst = spawn_listening(&mut gst, Announce::GstUdpsrc);
    let mut send = lipcall();
    send.arg("send")
        .arg(&spx)
        .args(["--to", &gst.addr(), "--no-rtcp"])
        .args(["--ssrc", &format!("{ssrc:x}")]);
    if srtp {
        send.env("LIPCALL_KEY_HEX", &key);
    }
    run(&mut send);
    stop_udpsrc(gst);

    let packets = ogg_packets(&spx);
    let expected = decode_frames(&packets);
    let (rate, got) = read_wav_i16(&out);
    assert_eq!(rate, 8000);
    let frames = got.len() as i64 / 160;
    assert!(
        (frames - packets.len() as i64).abs() <= 1,
        "GStreamer decoded {frames} frames of {}",
        packets.len()
    );
    let a = align(&expected, &got, 400);
    assert!(a.median() > 60.0, "median SNR {:.1} dB: {a:?}", a.median());
    assert!(a.share_above(25.0) >= 0.95, "{a:?}");
}

/// `lipcall send` into udpsrc ! rtpspeexdepay ! speexdec: right audio, right duration.
#[test]
fn lipcall_send_into_gstreamer_rtpspeexdepay() {
    let _serial = serial();
    lipcall_to_gst(false);
}

/// `lipcall send` with LIPCALL_KEY_HEX into GStreamer's srtpdec (libsrtp).
#[test]
fn lipcall_send_into_gstreamer_srtpdec() {
    let _serial = serial();
    lipcall_to_gst(true);
}

// ---------------------------------------------------------------------------------------------
// Other codecs: Opus (RFC 7587) and G.711, and payload types nobody mapped.

/// What `lipcall receive` made of a stream GStreamer sent, beside GStreamer's own decode of the
/// very RTP packets it sent (a tee after the payloader).
struct Received {
    rate: u32,
    source: Vec<i16>,
    reference: Vec<i16>,
    played: Vec<i16>,
    stderr: String,
    /// Frames played after the last one with a mode: the concealed tail after a stream that
    /// ends without BYE.
    tail: usize,
    feature_rows: usize,
    weight_rows: usize,
}

/// Rows of a FEATURES.csv, and how many at its end are concealed (no mode).
fn feature_rows(path: &Path) -> (usize, usize) {
    let text = std::fs::read_to_string(path).unwrap();
    let modes: Vec<bool> = text
        .lines()
        .skip(1)
        .map(|l| !l.split(',').nth(2).unwrap_or("").is_empty())
        .collect();
    let tail = modes.iter().rev().take_while(|&&m| !m).count();
    (modes.len(), tail)
}

fn csv_rows(path: &Path) -> usize {
    std::fs::read_to_string(path).unwrap().lines().count() - 1
}

/// The GStreamer elements reading an 8 kHz mono WAV.
fn gst_wav_source(cmd: &mut Command, clip: &Path) {
    gst_wav_source_at(cmd, clip, 8000);
}

/// The GStreamer elements reading a mono WAV at `rate`.
fn gst_wav_source_at(cmd: &mut Command, clip: &Path, rate: u32) {
    cmd.arg("filesrc")
        .arg(format!("location={}", clip.display()))
        .args(["!", "wavparse", "!", "audioconvert", "!", "audioresample"])
        .arg("!")
        .arg(format!("audio/x-raw,rate={rate},channels=1"));
}

/// `seconds` of speech at `rate`: the demo (16 kHz) as it is or resampled, and above 16 kHz
/// with a hiss from 5 kHz up mixed in (speech recorded at 16 kHz has nothing above 8 kHz).
fn clip_at(dir: &Path, seconds: &str, rate: u32) -> std::path::PathBuf {
    if rate == 8000 {
        return clip(dir, seconds);
    }
    let speech = dir.join(format!("speech{rate}.wav"));
    run(Command::new("sox")
        .arg(common::repo_file("assets/speech/demo.wav"))
        .args(["-D", "-b", "16", "-c", "1", "-r", &rate.to_string()])
        .arg(&speech)
        .args(["trim", "0", seconds]));
    if rate <= 16_000 {
        return speech;
    }
    let hiss = dir.join("hiss.wav");
    run(Command::new("sox")
        .args(["-n", "-D", "-b", "16", "-c", "1", "-r", &rate.to_string()])
        .arg(&hiss)
        .args([
            "synth",
            seconds,
            "pinknoise",
            "highpass",
            "5000",
            "gain",
            "-28",
        ]));
    let out = dir.join(format!("clip{rate}.wav"));
    run(Command::new("sox")
        .args(["-m", "-D"])
        .arg(&speech)
        .arg(&hiss)
        .arg(&out));
    out
}

fn chain(cmd: &mut Command, elements: &[&str]) {
    for e in elements {
        cmd.arg("!").args(e.split(' '));
    }
}

/// `gst-launch-1.0 -v -e udpsrc port=0 caps=CAPS`: udpsrc binds a port of its own and `-v`
/// prints it once bound (read by `spawn_listening`); `-e` finishes the files on SIGINT.
fn gst_udpsrc(caps: &str) -> Command {
    let mut gst = Command::new("gst-launch-1.0");
    gst.args(["-v", "-e", "udpsrc", "port=0"])
        .arg(format!("caps={caps}"));
    gst
}

/// Ends a `gst_udpsrc` pipeline once the sender is done. The sender's last packet left when
/// `lipcall send` exited; the pause lets udpsrc and the decoder take what is still in the
/// socket before the EOS that SIGINT sends (udpsrc does not read its socket after that).
fn stop_udpsrc(gst: common::net::Listening) {
    std::thread::sleep(Duration::from_millis(500));
    gst.interrupt();
    gst.finish(Duration::from_secs(30), "gst-launch udpsrc");
}

/// `source ! ENCODER ! PAYLOADER ! tee` into `lipcall receive` (with `receive_args`) and into
/// `DEPAYLOADER ! DECODER ! wavenc` for GStreamer's own decode.
fn gst_into_receive(
    encoder: &[&str],
    payloader: &str,
    decoder: &[&str],
    receive_args: &[&str],
) -> Received {
    gst_into_receive_at(encoder, payloader, decoder, receive_args, 8000)
}

/// [`gst_into_receive`] of a clip at `rate`, GStreamer decoding at `rate` too.
fn gst_into_receive_at(
    encoder: &[&str],
    payloader: &str,
    decoder: &[&str],
    receive_args: &[&str],
    rate: u32,
) -> Received {
    let dir = tempfile::tempdir().unwrap();
    let clip = clip_at(dir.path(), "3", rate);
    let out = dir.path().join("received.wav");
    let features = dir.path().join("features.csv");
    let weights = dir.path().join("weights.csv");
    let reference = dir.path().join("gst.wav");
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0"])
            .arg("--wav")
            .arg(&out)
            .arg("--features")
            .arg(&features)
            .arg("--weights")
            .arg(&weights)
            .args(["--seconds", "6"])
            .args(receive_args),
        Announce::Lipcall,
    );
    let mut gst = Command::new("gst-launch-1.0");
    gst.arg("-q");
    gst_wav_source_at(&mut gst, &clip, rate);
    chain(&mut gst, encoder);
    chain(&mut gst, &[payloader, "tee name=t"]);
    gst.args(["t.", "!", "queue", "!", "udpsink", "host=127.0.0.1"])
        .arg(format!("port={}", receiver.port))
        .args(["t.", "!", "queue"]);
    chain(&mut gst, decoder);
    let caps = format!("audio/x-raw,rate={rate},channels=1");
    chain(&mut gst, &[&caps, "wavenc", "filesink"]);
    gst.arg(format!("location={}", reference.display()));
    run(&mut gst);
    let (_, stderr) = receiver.finish(Duration::from_secs(60), "lipcall receive");
    let (rows, tail) = feature_rows(&features);
    let (played_rate, played) = read_wav_i16(&out);
    if !played.is_empty() {
        assert_eq!(played_rate, rate, "OUT.wav at the stream's own rate");
    }
    Received {
        rate,
        source: read_wav_i16(&clip).1,
        reference: read_wav_i16(&reference).1,
        played,
        stderr,
        tail,
        feature_rows: rows,
        weight_rows: csv_rows(&weights),
    }
}

/// The played stream against GStreamer's decode of it: duration, and coding quality against
/// the source.
fn check_against_gstreamer(r: &Received, codec: &str) {
    let peer = fields(&r.stderr, "peer ");
    assert_eq!(peer["codec"], codec, "{}", r.stderr);
    assert!(num(&peer, "received") >= 20.0, "{}", r.stderr);
    assert_eq!(num(&peer, "decode_errors"), 0.0, "{}", r.stderr);
    // Frames and offsets in samples of the stream's own rate.
    let frame = r.rate as usize / 50;
    let scale = r.rate as usize / 8000;
    assert_eq!(r.played.len() % frame, 0);
    let frames = r.played.len() / frame;
    assert_eq!(r.feature_rows, frames);
    assert_eq!(r.weight_rows, frames);
    // The stream as played lasts as GStreamer's decode, +-1 frame: without the concealed tail
    // after it, and without the frames the jitter buffer inserted or skipped to follow the
    // delay (counted; a loaded machine makes the receiver's ticks late now and then).
    let (stretched, dropped) = (num(&peer, "stretched"), num(&peer, "dropped"));
    let stream = (frames - r.tail) as i64 - stretched as i64 + dropped as i64;
    let theirs = r.reference.len().div_ceil(frame) as i64;
    assert!(
        (stream - theirs).abs() <= 1,
        "{codec}: played {stream} frames (+{} concealed), GStreamer decoded {theirs}",
        r.tail
    );
    // Against the source, 200 ms at a time, each chunk at its best whole-frame shift. The
    // median chunk is the measure; over all chunks together too when the buffer did not adapt
    // (a chunk across an inserted frame compares concealment with speech).
    let gst = align_frames(&r.source, &r.reference, 2000 * scale, frame);
    let ours = align_frames(&r.source, &r.played, 2000 * scale, frame);
    let same = align_frames(&r.reference, &r.played, 2000 * scale, frame);
    let (whole, lag) = snr_at_best_lag(&r.source, &r.reference, 2000 * scale);
    eprintln!(
        "{codec}: against the source, median 200 ms: GStreamer {:.2} dB, lipcall {:.2} dB; all \
         chunks: GStreamer {:.2} dB, lipcall {:.2} dB (GStreamer's whole clip at lag {lag}: \
         {whole:.2} dB); lipcall against GStreamer median {:.1} dB; {stream} frames vs {theirs}; \
         stretched {stretched} dropped {dropped}",
        gst.median(),
        ours.median(),
        gst.overall(),
        ours.overall(),
        same.median(),
    );
    assert!(
        (ours.median() - gst.median()).abs() <= 1.0,
        "{codec}: lipcall {:.2} dB vs GStreamer {:.2} dB against the source; {same:?}\n{}",
        ours.median(),
        gst.median(),
        r.stderr
    );
    if stretched + dropped == 0.0 {
        assert!(
            (ours.overall() - gst.overall()).abs() <= 1.0,
            "{codec}: lipcall {:.2} dB vs GStreamer {:.2} dB against the source",
            ours.overall(),
            gst.overall()
        );
    }
    // And sample for sample, GStreamer's decode is what lipcall played.
    assert!(same.median() > 60.0, "{codec}: {same:?}");
    // Above the narrowband: the same energy from 4 kHz up as GStreamer heard.
    if r.rate > 8000 {
        let (ours, theirs) = (
            band_db(&r.played, r.rate, 4000.0),
            band_db(&r.reference, r.rate, 4000.0),
        );
        let whole = band_db(&r.reference, r.rate, 20.0);
        eprintln!(
            "{codec}: energy above 4 kHz: lipcall {ours:.2} dB, GStreamer {theirs:.2} dB ({:.1} dB \
             below the whole band)",
            whole - theirs
        );
        assert!(
            (ours - theirs).abs() <= 1.0,
            "{codec}: {ours:.2} vs {theirs:.2} dB"
        );
        assert!(
            whole - theirs < 30.0,
            "{codec}: nothing above 4 kHz to compare"
        );
    }
}

/// GStreamer `opusenc ! rtpopuspay` (payload type 96, 48 kHz clock) into `lipcall receive
/// --wav --weights`: the played audio is as good as GStreamer's own decode of the same RTP.
#[test]
fn gstreamer_rtpopuspay_into_lipcall_receive() {
    let _serial = serial();
    let r = gst_into_receive_at(
        &["opusenc bitrate=16000"],
        "rtpopuspay",
        &["rtpopusdepay", "opusdec"],
        &[],
        48_000,
    );
    check_against_gstreamer(&r, "opus");
    assert!(num(&fields(&r.stderr, "peer "), "received") >= 140.0);
}

/// GStreamer's Opus in 10 ms frames (`opusenc frame-size=10`: a packet every 10 ms) into
/// `lipcall receive`: it plays as GStreamer's own decode does, and animates one weights row
/// per 20 ms (two packets a feature step, the network's step).
#[test]
fn gstreamer_opus_in_10_ms_frames_into_lipcall_receive() {
    let _serial = serial();
    let r = gst_into_receive_at(
        &["opusenc bitrate=16000 frame-size=10"],
        "rtpopuspay",
        &["rtpopusdepay", "opusdec"],
        &[],
        48_000,
    );
    check_against_gstreamer(&r, "opus");
    assert!(num(&fields(&r.stderr, "peer "), "received") >= 280.0);
}

/// Fullband Opus from GStreamer (`opusenc` at 48 kHz, up to 20 kHz) into `lipcall receive
/// --wav`: a 48 kHz WAV as good as GStreamer's own 48 kHz decode, with the same energy from
/// 4 to 20 kHz.
#[test]
fn gstreamer_fullband_opus_into_lipcall_receive_at_48_khz() {
    let _serial = serial();
    let r = gst_into_receive_at(
        &["opusenc bitrate=64000 bandwidth=fullband"],
        "rtpopuspay",
        &["rtpopusdepay", "opusdec"],
        &[],
        48_000,
    );
    check_against_gstreamer(&r, "opus");
}

/// GStreamer's Speex wideband (`speexenc` of 16 kHz audio) into `lipcall receive --pt
/// speex-wb=110`: 16 kHz audio as GStreamer's `speexdec` decodes it.
#[test]
fn gstreamer_speex_wideband_into_lipcall_receive_at_16_khz() {
    let _serial = serial();
    let r = gst_into_receive_at(
        &["speexenc"],
        "rtpspeexpay",
        &["rtpspeexdepay", "speexdec"],
        // (Speex narrowband moves aside: a session keeps a type for the codec it sends.)
        &["--pt", "speex-wb=110", "--pt", "speex=111"],
        16_000,
    );
    check_against_gstreamer(&r, "speex-wb");
}

/// GStreamer's G.722 (`avenc_g722` from gstreamer1.0-libav) on its static payload type 9 into
/// `lipcall receive --wav`: 16 kHz audio, both sub-bands, as GStreamer's `avdec_g722` decodes.
#[test]
fn gstreamer_g722_into_lipcall_receive_at_16_khz() {
    let _serial = serial();
    if !Command::new("gst-inspect-1.0")
        .arg("avenc_g722")
        .output()
        .is_ok_and(|o| o.status.success())
    {
        common::unavailable("GStreamer's avenc_g722 (gstreamer1.0-libav)");
        return;
    }
    let r = gst_into_receive_at(
        &["avenc_g722"],
        "rtpg722pay",
        &["rtpg722depay", "avdec_g722"],
        &[],
        16_000,
    );
    check_against_gstreamer(&r, "g722");
}

/// GStreamer `mulawenc ! rtppcmupay` (static payload type 0, packets of 173.5 and 82.5 ms)
/// into `lipcall receive`: the same samples as GStreamer's mulawdec.
#[test]
fn gstreamer_rtppcmupay_into_lipcall_receive() {
    let _serial = serial();
    let r = gst_into_receive(
        &["mulawenc"],
        "rtppcmupay",
        &["rtppcmudepay", "mulawdec"],
        &[],
    );
    check_against_gstreamer(&r, "pcmu");
}

/// Speex on payload type 100, which nobody mapped: counted and dropped, never decoded as any
/// codec (and no peer made of it); told that 100 is Speex (`--pt speex=100`), the receiver
/// plays it.
#[test]
fn a_payload_type_nobody_mapped_is_counted_and_dropped() {
    let _serial = serial();
    let r = gst_into_receive(
        &["speexenc"],
        "rtpspeexpay pt=100",
        &["rtpspeexdepay", "speexdec"],
        &[],
    );
    // Media no codec can read makes no peer (junk must not fill the peer table).
    let session = fields(&r.stderr, "lipcall: played");
    assert!(num(&session, "unknown_pt") >= 140.0, "{}", r.stderr);
    assert!(!r.stderr.contains("peer ssrc="), "{}", r.stderr);
    assert!(r.played.is_empty());

    let r = gst_into_receive(
        &["speexenc"],
        "rtpspeexpay pt=100",
        &["rtpspeexdepay", "speexdec"],
        &["--pt", "speex=100"],
    );
    let peer = fields(&r.stderr, "peer ");
    assert_eq!(peer["codec"], "speex");
    assert!(num(&peer, "received") >= 140.0, "{}", r.stderr);
    assert_eq!(num(&peer, "unknown_pt"), 0.0);
    let same = align(&r.reference, &r.played, 2000);
    assert!(same.median() > 60.0, "{same:?}");
}

/// `lipcall send` into `udpsrc caps=... ! DEPAYLOADER ! DECODER ! wavenc`; GStreamer's decode.
fn lipcall_send_into_gst(
    input: &Path,
    send_args: &[&str],
    caps: &str,
    decoder: &[&str],
) -> Vec<i16> {
    lipcall_send_into_gst_at(input, send_args, caps, decoder, 8000)
}

/// [`lipcall_send_into_gst`], GStreamer decoding at `rate`.
fn lipcall_send_into_gst_at(
    input: &Path,
    send_args: &[&str],
    caps: &str,
    decoder: &[&str],
    rate: u32,
) -> Vec<i16> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("gst.wav");
    let mut gst = gst_udpsrc(caps);
    chain(&mut gst, decoder);
    let raw = format!("audio/x-raw,rate={rate},channels=1");
    chain(&mut gst, &[&raw, "wavenc", "filesink"]);
    gst.arg(format!("location={}", out.display()));
    let gst = spawn_listening(&mut gst, Announce::GstUdpsrc);
    run(lipcall()
        .arg("send")
        .arg(input)
        .args(["--to", &gst.addr(), "--no-rtcp"])
        .args(send_args));
    stop_udpsrc(gst);
    let (got, pcm) = read_wav_i16(&out);
    assert_eq!(got, rate);
    pcm
}

/// What lipcall's own encoder and decoder make of a clip: the payloads `send` sends.
struct RoundTrip {
    payloads: Vec<Vec<u8>>,
    /// The 8 kHz decode the features come from.
    narrowband: Vec<i16>,
    /// The decode the ear gets, at the codec's own rate.
    audio: Vec<i16>,
}

/// Payloads lipcall sends for `clip` with `codec` (its encoder at its input rate, the settings
/// of `send`), and their decode, frame after frame as a receiver hears them.
fn encode_and_decode(clip: &Path, codec: Codec) -> (usize, Vec<i16>) {
    let trip = round_trip(clip, codec);
    (trip.payloads.len(), trip.narrowband)
}

fn round_trip(clip: &Path, codec: Codec) -> RoundTrip {
    use lipcall::audio::wav;
    use lipcall::codec::opus::codec::Bandwidth;
    let settings = EncoderSettings::wideband(Bandwidth::Fullband);
    let mut encoder = FrameEncoder::new(codec, &settings).unwrap();
    let audio = wav::read_mono(clip).unwrap();
    let pcm = wav::to_i16(&wav::resample(&audio, encoder.input_rate()).unwrap());
    let mut decoder = StreamDecoder::new(codec, true).unwrap();
    let mut payload = [0u8; MAX_FRAME_PAYLOAD];
    let mut trip = RoundTrip {
        payloads: Vec::new(),
        narrowband: Vec::new(),
        audio: Vec::new(),
    };
    let n_frame = encoder.frame_samples();
    for chunk in pcm.chunks(n_frame) {
        let mut frame = vec![0i16; n_frame];
        frame[..chunk.len()].copy_from_slice(chunk);
        let (n, _) = encoder.encode(&frame, &mut payload).unwrap().unwrap();
        decoder.packet(&payload[..n], 0);
        let decoded = decoder.frame();
        trip.narrowband.extend_from_slice(&decoded.pcm);
        trip.audio.extend_from_slice(decoded.audio.samples());
        trip.payloads.push(payload[..n].to_vec());
    }
    trip
}

fn check_sent(codec: Codec, packets: usize, expected: &[i16], got: &[i16], source: &[i16]) {
    let frames = got.len() as i64 / 160;
    assert!(
        (frames - packets as i64).abs() <= 1,
        "{codec}: GStreamer decoded {frames} frames of {packets}"
    );
    let a = align(expected, got, 400);
    let quality = align(source, got, 800);
    eprintln!(
        "{codec}: GStreamer's decode against lipcall's median {:.1} dB; against the source \
         {:.2} dB; {frames} frames of {packets}",
        a.median(),
        quality.overall()
    );
    assert!(a.median() > 60.0, "{codec}: {a:?}");
    assert!(a.share_above(40.0) >= 0.95, "{codec}: {a:?}");
}

/// `lipcall send --codec opus` into `udpsrc ! rtpopusdepay ! opusdec`: the audio lipcall's own
/// encoder made, for as long as it lasts.
#[test]
fn lipcall_send_opus_into_gstreamer_rtpopusdepay() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let got = lipcall_send_into_gst(
        &clip,
        &["--codec", "opus"],
        "application/x-rtp,media=audio,clock-rate=48000,encoding-name=OPUS,payload=96",
        &["rtpopusdepay", "opusdec"],
    );
    let (packets, expected) = encode_and_decode(&clip, Codec::Opus);
    check_sent(
        Codec::Opus,
        packets,
        &expected,
        &got,
        &read_wav_i16(&clip).1,
    );
}

/// `lipcall send --codec opus` of a 48 kHz WAV into `udpsrc ! rtpopusdepay ! opusdec` at
/// 48 kHz: a fullband stream (every TOC says so), which GStreamer decodes as well as lipcall's
/// own round trip does, up to 20 kHz.
#[test]
fn lipcall_send_fullband_opus_into_gstreamer_at_48_khz() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip_at(dir.path(), "3", 48_000);
    let got = lipcall_send_into_gst_at(
        &clip,
        &["--codec", "opus"],
        "application/x-rtp,media=audio,clock-rate=48000,encoding-name=OPUS,payload=96",
        &["rtpopusdepay", "opusdec"],
        48_000,
    );
    let trip = round_trip(&clip, Codec::Opus);
    // TOC configurations 14-15 (hybrid) and 28-31 (CELT) are fullband (RFC 6716 3.1).
    for p in &trip.payloads {
        let config = p[0] >> 3;
        assert!(matches!(config, 14 | 15 | 28..=31), "TOC config {config}");
    }
    let source = read_wav_i16(&clip).1;
    let theirs = align_frames(&source, &got, 12_000, 960);
    let ours = align_frames(&source, &trip.audio, 12_000, 960);
    let same = align_frames(&trip.audio, &got, 2400, 960);
    let frames = got.len() as i64 / 960;
    let (band_theirs, band_source) = (
        band_db(&got, 48_000, 12_000.0),
        band_db(&source, 48_000, 12_000.0),
    );
    eprintln!(
        "opus fullband: against the source, GStreamer's decode {:.2} dB (median {:.2}), \
         lipcall's round trip {:.2} dB (median {:.2}); GStreamer against lipcall median {:.1} dB; \
         above 12 kHz GStreamer {band_theirs:.1} dB, source {band_source:.1} dB; {frames} frames \
         of {}",
        theirs.overall(),
        theirs.median(),
        ours.overall(),
        ours.median(),
        same.median(),
        trip.payloads.len()
    );
    assert!((frames - trip.payloads.len() as i64).abs() <= 1);
    assert!((theirs.median() - ours.median()).abs() <= 1.0);
    assert!((theirs.overall() - ours.overall()).abs() <= 1.0);
    assert!(
        (band_theirs - band_source).abs() <= 6.0,
        "the band above 12 kHz is missing"
    );
}

/// `lipcall send --codec speex-wb` of a 16 kHz WAV into `rtpspeexdepay ! speexdec` at 16 kHz
/// (payload type 97, RTP clock 16000, RFC 5574): what lipcall's own decoder makes of it.
#[test]
fn lipcall_send_speex_wideband_into_gstreamer_at_16_khz() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip_at(dir.path(), "3", 16_000);
    let got = lipcall_send_into_gst_at(
        &clip,
        &["--codec", "speex-wb"],
        "application/x-rtp,media=audio,clock-rate=16000,encoding-name=SPEEX,payload=97",
        &["rtpspeexdepay", "speexdec"],
        16_000,
    );
    let trip = round_trip(&clip, Codec::SpeexWb);
    let same = align_frames(&trip.audio, &got, 800, 320);
    let frames = got.len() as i64 / 320;
    eprintln!(
        "speex-wb: GStreamer's decode against lipcall's median {:.1} dB; {frames} frames of {}",
        same.median(),
        trip.payloads.len()
    );
    assert!((frames - trip.payloads.len() as i64).abs() <= 1);
    assert!(same.median() > 60.0, "{same:?}");
    assert!(band_db(&got, 16_000, 4000.0) > band_db(&got, 16_000, 20.0) - 30.0);
}

/// An Ogg Opus file goes as it is: its packets, timestamped by their durations.
#[test]
fn lipcall_send_of_an_opus_file_into_gstreamer() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let file = dir.path().join("clip.opus");
    run(lipcall()
        .args(["encode", "--codec", "opus", "--bitrate", "24"])
        .arg(&clip)
        .arg(&file));
    let got = lipcall_send_into_gst(
        &file,
        &[],
        "application/x-rtp,media=audio,clock-rate=48000,encoding-name=OPUS,payload=96",
        &["rtpopusdepay", "opusdec"],
    );
    let decoded = lipcall::codec::opus::stream::decode(&std::fs::read(&file).unwrap()).unwrap();
    let mut decoder = StreamDecoder::new(Codec::Opus, true).unwrap();
    let mut expected = Vec::new();
    for p in &decoded.packets {
        decoder.packet(&p.data, 0);
        for _ in 0..p.samples / 160 {
            expected.extend_from_slice(&decoder.frame().pcm);
        }
    }
    check_sent(
        Codec::Opus,
        decoded.packets.len(),
        &expected,
        &got,
        &read_wav_i16(&clip).1,
    );
}

/// `lipcall send --codec pcmu` into `udpsrc ! rtppcmudepay ! mulawdec`.
#[test]
fn lipcall_send_pcmu_into_gstreamer_rtppcmudepay() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let got = lipcall_send_into_gst(
        &clip,
        &["--codec", "pcmu"],
        "application/x-rtp,media=audio,clock-rate=8000,encoding-name=PCMU,payload=0",
        &["rtppcmudepay", "mulawdec"],
    );
    let (packets, expected) = encode_and_decode(&clip, Codec::Pcmu);
    check_sent(
        Codec::Pcmu,
        packets,
        &expected,
        &got,
        &read_wav_i16(&clip).1,
    );
}

/// Three peers, three codecs, one session: GStreamer's Opus, lipcall's PCMA and lipcall's Speex
/// are each decoded with their own codec and mixed.
#[test]
fn peers_with_different_codecs_in_one_call() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let out = dir.path().join("mix.wav");
    let features = dir.path().join("features.csv");
    let receiver = spawn_listening(
        lipcall()
            .args(["receive", "--listen", "127.0.0.1:0"])
            .arg("--wav")
            .arg(&out)
            .arg("--features")
            .arg(&features)
            .args(["--seconds", "6", "--rate", "8000"]),
        Announce::Lipcall,
    );
    let (port, to) = (receiver.port, receiver.addr());
    let mut gst = Command::new("gst-launch-1.0");
    gst.arg("-q");
    gst_wav_source(&mut gst, &clip);
    chain(
        &mut gst,
        &["opusenc", "rtpopuspay", "udpsink host=127.0.0.1"],
    );
    gst.arg(format!("port={port}"));
    let senders = [
        spawn(&mut gst),
        spawn(
            lipcall()
                .arg("send")
                .arg(&clip)
                .args(["--to", &to, "--codec", "pcma", "--name", "A"]),
        ),
        spawn(
            lipcall()
                .arg("send")
                .arg(&clip)
                .args(["--to", &to, "--name", "S"]),
        ),
    ];
    for s in senders {
        finish(s, Duration::from_secs(30), "sender");
    }
    let (_, stderr) = receiver.finish(Duration::from_secs(60), "lipcall receive");
    let peers: Vec<_> = stderr
        .lines()
        .filter(|l| l.starts_with("peer "))
        .map(|l| fields(l, "peer "))
        .collect();
    let mut codecs: Vec<&str> = peers.iter().map(|p| p["codec"].as_str()).collect();
    codecs.sort();
    assert_eq!(codecs, ["opus", "pcma", "speex"], "{stderr}");
    for p in &peers {
        assert!(num(p, "received") >= 140.0, "{stderr}");
        assert_eq!(num(p, "decode_errors"), 0.0, "{stderr}");
    }
    // One feature file per peer, each as long as the mixed audio.
    let frames = read_wav_i16(&out).1.len() / 160;
    let files: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(|e| {
            let name = e.unwrap().file_name().into_string().unwrap();
            name.starts_with("features").then_some(name)
        })
        .collect();
    assert_eq!(files.len(), 3, "{files:?}");
    for f in files {
        let rows = csv_rows(&dir.path().join(&f));
        assert!(
            rows + 20 >= frames && rows <= frames,
            "{f}: {rows} of {frames}"
        );
    }
}

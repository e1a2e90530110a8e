//! Interop with GStreamer's RTP Speex elements, both ways, plain and with SRTP.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::net::{
    align, decode_frames, fields, finish, free_port, interrupt, num, ogg_packets, spawn,
};
use common::{lipcall, read_wav_i16, run};
use lipcall::net::srtp::MasterKey;

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
    let port = free_port();
    let out = dir.path().join("received.wav");
    let features = dir.path().join("features.csv");
    let reference = dir.path().join("reference.spx");
    let key = MasterKey::from_passphrase("interop", "").to_hex();
    let mut receive = lipcall();
    receive
        .args(["receive", "--listen", &format!("127.0.0.1:{port}")])
        .arg("--wav")
        .arg(&out)
        .arg("--features")
        .arg(&features)
        .args(["--seconds", "6"]);
    if srtp {
        receive.args(["--key-hex", &key]);
    }
    let receiver = spawn(&mut receive);
    std::thread::sleep(Duration::from_millis(300));
    run(&mut gst_send(
        &clip,
        port,
        srtp.then_some(key.as_str()),
        &reference,
    ));
    let (_, stderr) = finish(receiver, Duration::from_secs(60), "lipcall receive");
    let peer = fields(&stderr, "peer ");
    assert!(num(&peer, "received") >= 140.0, "{stderr}");
    if srtp {
        assert_eq!(num(&fields(&stderr, "lipcall: played"), "auth_failed"), 0.0);
    }

    let expected = decode_frames(&ogg_packets(&reference));
    let (rate, got) = read_wav_i16(&out);
    assert_eq!(rate, 8000);
    // Played = the stream, plus at most the concealed tail before the talk spurt times out.
    let frames = got.len() as i64 / 160;
    let sent = expected.len() as i64 / 160;
    assert!(
        frames >= sent - 1 && frames <= sent + 17,
        "{frames} vs {sent}"
    );
    let a = align(&expected, &got, 2000);
    assert!(a.chunk_snr.len() >= 8, "{a:?}");
    assert!(a.median() > 60.0, "median SNR {:.1} dB: {a:?}", a.median());
    // A delay adjustment of the jitter buffer (a skipped or inserted frame) puts the decoder
    // off the reference for a moment; everything else is bit-exact.
    assert!(a.share_above(25.0) >= 0.85, "{a:?}");
    let rows = std::fs::read_to_string(&features).unwrap().lines().count() - 1;
    assert_eq!(rows as i64, frames);
}

/// GStreamer speexenc + rtpspeexpay into `lipcall receive`: the WAV matches a direct decode
/// of the very packets GStreamer encoded (captured with a tee into an Ogg file).
#[test]
fn gstreamer_rtpspeexpay_into_lipcall_receive() {
    gst_to_lipcall(false);
}

/// The same through GStreamer's srtpenc (libsrtp) into `lipcall receive --key-hex`.
#[test]
fn gstreamer_srtpenc_into_lipcall_receive() {
    gst_to_lipcall(true);
}

fn lipcall_to_gst(srtp: bool) {
    let dir = tempfile::tempdir().unwrap();
    let clip = clip(dir.path(), "3");
    let spx = dir.path().join("clip.spx");
    run(lipcall().arg("encode").arg(&clip).arg(&spx));
    let port = free_port();
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
    let mut gst = Command::new("gst-launch-1.0");
    gst.args(["-q", "-e", "udpsrc"])
        .arg(format!("port={port}"))
        .arg(format!("caps={caps}"));
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
    let gst = spawn(&mut gst);
    std::thread::sleep(Duration::from_millis(800));
    let mut send = lipcall();
    send.arg("send")
        .arg(&spx)
        .args(["--to", &format!("127.0.0.1:{port}"), "--no-rtcp"])
        .args(["--ssrc", &format!("{ssrc:x}")]);
    if srtp {
        send.args(["--key-hex", &key]);
    }
    run(&mut send);
    std::thread::sleep(Duration::from_millis(500));
    interrupt(&gst);
    finish(gst, Duration::from_secs(30), "gst-launch udpsrc");

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
    lipcall_to_gst(false);
}

/// `lipcall send --key-hex` into GStreamer's srtpdec (libsrtp).
#[test]
fn lipcall_send_into_gstreamer_srtpdec() {
    lipcall_to_gst(true);
}

//! Ringing anyone notices (issue 46): the app (its window under Xvfb) registered with kamailio
//! on 127.0.0.1 takes baresip's call. While it rings the `--status` file says `ringing`, the
//! ringtone's two tones reach a PulseAudio null sink of the test's own, and a notification
//! with Answer and Decline reaches the freedesktop Notifications server this test serves on a
//! private session bus (`dbus-daemon`); the server's ActionInvoked "answer" answers the call,
//! which stops the tone and closes the notification. A direct caller (`lipcall send`) rings the
//! same, and is answered from the notification the same way.

mod common;

use std::collections::HashMap;
use std::f64::consts::TAU;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::pulse::NullSink;
use common::sip::{Logged, PASSWORD, Peer, baresip, free_port, have, kamailio, tell_baresip};
use lipcall::app::settings::Settings;
use lipcall::audio::ringtone::{RING_LEVEL, RING_TONES_HZ};

const RATE: u32 = 48_000;
/// One case at a time: two apps coming up on PulseAudio together sometimes leave one playing
/// into nothing its null sink records (seen as a silent recording), and each case asserts on
/// what it hears.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());
const PATH: &str = "/org/freedesktop/Notifications";
const INTERFACE: &str = "org.freedesktop.Notifications";

/// A notification the server was asked to show.
#[derive(Debug, Clone)]
struct Notified {
    id: u32,
    summary: String,
    actions: Vec<String>,
    urgency: Option<u8>,
}

#[derive(Debug, Default)]
struct Record {
    notified: Vec<Notified>,
    closed: Vec<u32>,
}

/// The notification server: records what it is asked.
struct Server {
    record: Arc<Mutex<Record>>,
}

#[zbus::interface(name = "org.freedesktop.Notifications")]
impl Server {
    #[allow(clippy::too_many_arguments)]
    fn notify(
        &mut self,
        _app_name: String,
        _replaces_id: u32,
        _app_icon: String,
        summary: String,
        _body: String,
        actions: Vec<String>,
        hints: HashMap<String, zbus::OwnedVariant>,
        _expire_timeout: i32,
    ) -> u32 {
        let mut record = self.record.lock().unwrap();
        let id = record.notified.len() as u32 + 1;
        let urgency = hints.get("urgency").and_then(|v| u8::try_from(v).ok());
        record.notified.push(Notified {
            id,
            summary,
            actions,
            urgency,
        });
        id
    }

    fn close_notification(&mut self, id: u32) {
        self.record.lock().unwrap().closed.push(id);
    }

    fn get_capabilities(&self) -> Vec<String> {
        vec!["actions".into(), "body".into()]
    }

    #[zbus(out_args("name", "vendor", "version", "spec_version"))]
    fn get_server_information(&self) -> (String, String, String, String) {
        ("test".into(), "lipcall".into(), "1".into(), "1.2".into())
    }
}

/// A private session bus, stopped when dropped.
struct Bus {
    daemon: Child,
    address: String,
}

impl Bus {
    fn start(dir: &Path) -> Self {
        let mut daemon = Command::new("dbus-daemon")
            .args(["--session", "--nofork", "--print-address"])
            .arg(format!("--address=unix:path={}", dir.join("bus").display()))
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("dbus-daemon runs");
        let mut line = String::new();
        BufReader::new(daemon.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let address = line.trim().to_owned();
        assert!(address.starts_with("unix:"), "dbus-daemon said {address:?}");
        Self { daemon, address }
    }
}

impl Drop for Bus {
    fn drop(&mut self) {
        let _ = self.daemon.kill();
        let _ = self.daemon.wait();
    }
}

/// Serves [`Server`] on the bus at `address` from a thread of its own; each `(id, key)` sent
/// on the returned channel is emitted as ActionInvoked.
fn serve(
    address: String,
    record: Arc<Mutex<Record>>,
) -> tokio::sync::mpsc::UnboundedSender<(u32, String)> {
    let (emit, mut to_emit) = tokio::sync::mpsc::unbounded_channel::<(u32, String)>();
    let (ready, serving) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async move {
            let built = zbus::connection::Builder::address(address.as_str())
                .name(INTERFACE)
                .serve_at(PATH, Server { record })
                .build();
            let connection = match built.await {
                Ok(c) => c,
                Err(e) => {
                    let _ = ready.send(Err(e.to_string()));
                    return;
                }
            };
            let _ = ready.send(Ok(()));
            while let Some((id, key)) = to_emit.recv().await {
                connection
                    .emit_signal(None::<&str>, PATH, INTERFACE, "ActionInvoked", &(id, key))
                    .await
                    .expect("ActionInvoked emitted");
            }
        });
    });
    serving
        .recv_timeout(Duration::from_secs(10))
        .expect("the notification server started")
        .expect("the notification server owns its name");
    emit
}

/// The sink's monitor as it is recorded, sample by sample (48 kHz mono).
struct Recording {
    parec: Child,
    samples: Arc<Mutex<Vec<i16>>>,
}

impl Recording {
    fn start(sink: &str) -> Self {
        let mut parec = Command::new("parec")
            .args(["-d", &format!("{sink}.monitor"), "--raw", "--format=s16le"])
            .args([
                "--channels=1",
                &format!("--rate={RATE}"),
                "--latency-msec=20",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("parec (pulseaudio-utils) runs");
        let mut out = parec.stdout.take().unwrap();
        let samples = Arc::new(Mutex::new(Vec::new()));
        let into = Arc::clone(&samples);
        std::thread::spawn(move || {
            let mut buf = [0u8; 4800];
            while let Ok(n) = out.read(&mut buf) {
                if n == 0 {
                    break;
                }
                let mut s = into.lock().unwrap();
                s.extend(
                    buf[..n & !1]
                        .chunks_exact(2)
                        .map(|b| i16::from_le_bytes([b[0], b[1]])),
                );
            }
        });
        Self { parec, samples }
    }

    fn len(&self) -> usize {
        self.samples.lock().unwrap().len()
    }

    fn since(&self, start: usize) -> Vec<i16> {
        self.samples.lock().unwrap()[start..].to_vec()
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        let _ = self.parec.kill();
        let _ = self.parec.wait();
    }
}

/// The amplitude of the `hz` component of `x` (Goertzel), in samples' units.
fn amplitude_at(x: &[i16], hz: f64) -> f64 {
    let w = TAU * hz / f64::from(RATE);
    let (mut s1, mut s2) = (0.0f64, 0.0f64);
    for &v in x {
        let s = f64::from(v) + 2.0 * w.cos() * s1 - s2;
        s2 = s1;
        s1 = s;
    }
    let power = s1 * s1 + s2 * s2 - 2.0 * w.cos() * s1 * s2;
    2.0 * power.max(0.0).sqrt() / x.len() as f64
}

/// The loudest 100 ms of `x` at `hz`.
fn loudest_at(x: &[i16], hz: f64) -> f64 {
    x.chunks_exact(RATE as usize / 10)
        .map(|c| amplitude_at(c, hz))
        .fold(0.0, f64::max)
}

/// The `call=` word of the status file's first line.
fn call_word(status: &Path) -> String {
    let text = std::fs::read_to_string(status).unwrap_or_default();
    text.lines()
        .next()
        .and_then(|l| l.split_whitespace().find_map(|w| w.strip_prefix("call=")))
        .unwrap_or("")
        .to_owned()
}

fn wait_until(what: &str, limit: Duration, log: &dyn Fn() -> String, done: &dyn Fn() -> bool) {
    let deadline = Instant::now() + limit;
    while !done() {
        assert!(
            Instant::now() < deadline,
            "{what}; the app's log:\n{}",
            log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The app (its window on an Xvfb of its own, both stopped when dropped) with the settings in
/// `settings`, its notifications on `bus`, its sound in `sink`, its status in `status`.
fn app(bus: &Bus, sink: &NullSink, settings: &Path, status: &Path) -> (Logged, Logged, String) {
    let xvfb = Peer::spawn_logged(
        "Xvfb",
        Command::new("Xvfb").args(["-displayfd", "1", "-screen", "0", "1280x720x24"]),
    );
    let display_limit = Instant::now() + Duration::from_secs(20);
    let display = loop {
        if let Some(n) = xvfb
            .text()
            .lines()
            .find_map(|l| l.trim().parse::<u32>().ok())
        {
            break n;
        }
        assert!(Instant::now() < display_limit, "Xvfb: {}", xvfb.text());
        std::thread::sleep(Duration::from_millis(50));
    };
    let app = Peer::spawn_logged(
        "lipcall",
        common::lipcall()
            .args([
                "--no-demo",
                "--quit-after",
                "240",
                "--listen",
                "127.0.0.1:0",
            ])
            .arg("--status")
            .arg(status)
            .arg("--settings")
            .arg(settings)
            .env("DISPLAY", format!(":{display}"))
            .env("DBUS_SESSION_BUS_ADDRESS", &bus.address)
            .env("PULSE_SINK", &sink.name)
            .env("RUST_LOG", "lipcall=info"),
    );
    (xvfb, app, format!(":{display}"))
}

/// The window as it is on `display` now; copied into `LIPCALL_SHOTS` (a folder) as `name` where
/// that is set (docs/states/ringing.png is taken so).
fn screenshot(dir: &Path, display: &str, name: &str) -> image::RgbImage {
    let path = dir.join(name);
    common::run(
        Command::new("import")
            .args(["-display", display, "-window", "root"])
            .arg(&path),
    );
    if let Some(shots) = std::env::var_os("LIPCALL_SHOTS") {
        std::fs::copy(&path, Path::new(&shots).join(name)).unwrap();
    }
    image::open(&path).unwrap().to_rgb8()
}

/// Pixels of the ringing banner's blue (at any point of its pulse).
fn banner_pixels(img: &image::RgbImage) -> usize {
    img.pixels()
        .filter(|p| {
            let [r, g, b] = p.0;
            (15..=45).contains(&r) && (55..=135).contains(&g) && (105..=225).contains(&b)
        })
        .count()
}

/// The tools every case needs; under CI a missing one fails.
fn have_all(more: &[&str]) -> bool {
    let every = ["dbus-daemon", "Xvfb", "parec", "pactl", "import"];
    if !have(&every) || !have(more) {
        return false;
    }
    if !common::pulse_running() {
        common::unavailable("no PulseAudio server (start .ci/pulse-null-sink.sh): not run");
        return false;
    }
    true
}

#[test]
fn an_incoming_sip_call_rings_sounds_notifies_and_is_answered_from_the_notification() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if !have(&[
        "dbus-daemon",
        "kamailio",
        "baresip",
        "sox",
        "Xvfb",
        "parec",
        "pactl",
    ]) {
        return;
    }
    if !common::pulse_running() {
        common::unavailable("no PulseAudio server (start .ci/pulse-null-sink.sh): not run");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start(dir.path());
    let record = Arc::new(Mutex::new(Record::default()));
    let emit = serve(bus.address.clone(), Arc::clone(&record));

    let (kam_port, bob_port, control, sip_port) = (
        free_port(false),
        free_port(false),
        free_port(false),
        free_port(false),
    );
    let _kamailio = kamailio(dir.path(), kam_port, "");
    // Bob says nothing: once the call is answered the sink hears only what the app adds.
    let silence = dir.path().join("silence.wav");
    common::run(
        Command::new("sox")
            .args(["-n", "-r", "8000", "-c", "1", "-b", "16"])
            .arg(&silence)
            .args(["trim", "0", "30"]),
    );
    let bob = baresip(
        dir.path(),
        bob_port,
        control,
        "\"Bob Builder\" <sip:bob@127.0.0.1>;regint=0;audio_codecs=PCMU",
        &silence,
    );

    let mut settings = Settings {
        name: "Alice".into(),
        ..Settings::default()
    };
    settings.sip.account = format!("sip:alice@127.0.0.1:{kam_port}");
    settings.sip.password = PASSWORD.into();
    settings.sip.local_port = sip_port;
    let settings_file = dir.path().join("settings.json");
    settings.save(&settings_file).unwrap();

    let sink = NullSink::load("ring_sip", RATE);
    let recording = Recording::start(&sink.name);
    let status = dir.path().join("status.txt");
    let (_xvfb, app, display) = app(&bus, &sink, &settings_file, &status);
    let log = || app.text();
    let limit = Duration::from_secs(60);
    wait_until("registered", limit, &log, &|| {
        app.text().contains("registered with")
    });
    wait_until("the status file", limit, &log, &|| {
        call_word(&status) == "idle"
    });

    tell_baresip(control, "dial", &format!("sip:alice@127.0.0.1:{kam_port}"));
    wait_until("call=ringing", limit, &log, &|| {
        call_word(&status) == "ringing"
    });
    let rang = recording.len();
    wait_until("the notification", limit, &log, &|| {
        !record.lock().unwrap().notified.is_empty()
    });
    let notified = record.lock().unwrap().notified[0].clone();
    assert_eq!(notified.summary, "Bob Builder is calling", "{notified:?}");
    for action in ["answer", "Answer", "decline", "Decline"] {
        assert!(notified.actions.iter().any(|a| a == action), "{notified:?}");
    }
    assert_eq!(notified.urgency, Some(2), "critical: {notified:?}");

    // A whole cadence (1 s of tone, 2 s of silence) and a margin.
    wait_until("4 s recorded while ringing", limit, &log, &|| {
        recording.len() >= rang + 4 * RATE as usize
    });
    assert_eq!(call_word(&status), "ringing", "still ringing");
    // The banner: across the window, a good 50 pixels high.
    let shot = screenshot(dir.path(), &display, "ringing.png");
    let banner = banner_pixels(&shot);
    assert!(banner > 1280 * 50, "the banner's blue: {banner} pixels");
    let ringing = recording.since(rang);
    let expected = f64::from(RING_LEVEL) * 32768.0;
    for hz in RING_TONES_HZ {
        let heard = loudest_at(&ringing, f64::from(hz));
        eprintln!("while ringing: {hz} Hz at {heard:.0} (the tone's {expected:.0})");
        assert!(
            heard > expected * 0.5,
            "{hz} Hz: {heard:.0} of {expected:.0}"
        );
    }
    assert!(
        loudest_at(&ringing, 1000.0) < expected * 0.05,
        "nothing but the tones"
    );

    emit.send((notified.id, "answer".into())).unwrap();
    wait_until("call=in_call", limit, &log, &|| {
        call_word(&status) == "in_call"
    });
    wait_until("the notification closed", limit, &log, &|| {
        record.lock().unwrap().closed.contains(&notified.id)
    });
    assert!(
        bob.wait_for("Call answered", Duration::from_secs(10))
            || bob.text().contains("established"),
        "baresip: {}",
        bob.text()
    );
    // The tone stops within the output's buffer; what is left in the sink is after it.
    std::thread::sleep(Duration::from_millis(500));
    let answered = recording.len();
    wait_until("4 s recorded in the call", limit, &log, &|| {
        recording.len() >= answered + 4 * RATE as usize
    });
    let after = recording.since(answered);
    for hz in RING_TONES_HZ {
        let heard = loudest_at(&after, f64::from(hz));
        eprintln!("in the call: {hz} Hz at {heard:.0}");
        assert!(
            heard < expected * 0.02,
            "{hz} Hz after answering: {heard:.0}"
        );
    }
    assert_eq!(record.lock().unwrap().notified.len(), 1, "one notification");
    assert!(!app.text().contains("panicked"), "{}", app.text());
    // The banner went with the ringing.
    let shot = screenshot(dir.path(), &display, "answered.png");
    assert!(
        banner_pixels(&shot) < 1280 * 5,
        "the banner stayed after answering"
    );
}

/// The `listening=` address of the status file's first line.
fn listening(status: &Path) -> Option<String> {
    let text = std::fs::read_to_string(status).ok()?;
    let first = text.lines().next()?.to_owned();
    first
        .split_whitespace()
        .find_map(|w| w.strip_prefix("listening="))
        .filter(|a| *a != "-")
        .map(str::to_owned)
}

#[test]
fn a_direct_caller_rings_sounds_notifies_and_is_answered_from_the_notification() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    if !have_all(&["sox"]) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let bus = Bus::start(dir.path());
    let record = Arc::new(Mutex::new(Record::default()));
    let emit = serve(bus.address.clone(), Arc::clone(&record));
    let settings_file = dir.path().join("settings.json");
    Settings {
        name: "Alice".into(),
        ..Settings::default()
    }
    .save(&settings_file)
    .unwrap();
    // Ann sends a 300 Hz tone, long enough to ring through: far from the ringtone's.
    let wav = dir.path().join("ann.wav");
    common::run(
        Command::new("sox")
            .args(["-n", "-D", "-b", "16", "-c", "1", "-r", "16000"])
            .arg(&wav)
            .args(["synth", "90", "sine", "300", "gain", "-12"]),
    );
    let sink = NullSink::load("ring_direct", RATE);
    let recording = Recording::start(&sink.name);
    let status = dir.path().join("status.txt");
    let (_xvfb, app, display) = app(&bus, &sink, &settings_file, &status);
    let log = || app.text();
    let limit = Duration::from_secs(60);
    wait_until("listening", limit, &log, &|| listening(&status).is_some());
    let to = listening(&status).unwrap();
    let _ann = Peer::spawn_logged(
        "lipcall send",
        common::lipcall()
            .arg("send")
            .arg(&wav)
            .args(["--to", &to, "--name", "Ann"]),
    );
    wait_until("call=ringing", limit, &log, &|| {
        call_word(&status) == "ringing"
    });
    let rang = recording.len();
    wait_until("the notification", limit, &log, &|| {
        !record.lock().unwrap().notified.is_empty()
    });
    let notified = record.lock().unwrap().notified[0].clone();
    assert_eq!(notified.summary, "Ann is calling", "{notified:?}");
    for action in ["answer", "Answer", "decline", "Decline"] {
        assert!(notified.actions.iter().any(|a| a == action), "{notified:?}");
    }
    // The app's output may reach the sink a while after it listens: waited for, not timed.
    let expected = f64::from(RING_LEVEL) * 32768.0;
    // The last 4 s only: each look is cheap, so the looking does not starve the app's output.
    let heard = |hz: f64| {
        let from = rang.max(recording.len().saturating_sub(4 * RATE as usize));
        loudest_at(&recording.since(from), hz)
    };
    wait_until("4 s recorded while ringing", limit, &log, &|| {
        recording.len() >= rang + 4 * RATE as usize
    });
    let levels = || {
        let at: Vec<String> = RING_TONES_HZ
            .iter()
            .map(|&hz| f64::from(hz))
            .chain([300.0])
            .map(|hz| format!("{hz} Hz at {:.0}", heard(hz)))
            .collect();
        format!("{} in the sink\n{}", at.join(", "), app.text())
    };
    wait_until(
        "the ringtone's tones and the caller in the sink",
        limit,
        &levels,
        &|| {
            RING_TONES_HZ
                .iter()
                .all(|&hz| heard(f64::from(hz)) > expected * 0.5)
                && heard(300.0) > expected * 0.1
        },
    );
    for hz in RING_TONES_HZ.iter().map(|&hz| f64::from(hz)).chain([300.0]) {
        eprintln!(
            "direct caller ringing: {hz} Hz at {:.0} (the tone's {expected:.0})",
            heard(hz)
        );
    }
    assert_eq!(call_word(&status), "ringing", "rings while she sends");
    let shot = screenshot(dir.path(), &display, "direct_caller.png");
    assert!(
        banner_pixels(&shot) > 1280 * 50,
        "the banner says who is calling"
    );
    emit.send((notified.id, "answer".into())).unwrap();
    wait_until("call=in_call", limit, &log, &|| {
        call_word(&status) == "in_call"
    });
    wait_until("the notification closed", limit, &log, &|| {
        record.lock().unwrap().closed.contains(&notified.id)
    });
    assert!(app.text().contains("the user answered"), "{}", app.text());
    // In the call with Ann (docs/states/in_call.png): her tile, a few seconds on its timer.
    wait_until("Ann's tile shown", limit, &log, &|| {
        shown_peers(&status) >= 1
    });
    std::thread::sleep(Duration::from_secs(3));
    screenshot(dir.path(), &display, "in_call.png");
    // Bob and Carol call during it: each rings over the call and is answered from its own
    // notification (docs/states/peers.png: the three of them).
    let mut callers = Vec::new();
    for name in ["Bob", "Carol"] {
        let before = record.lock().unwrap().notified.len();
        callers.push(Peer::spawn_logged(
            "lipcall send",
            common::lipcall()
                .arg("send")
                .arg(&wav)
                .args(["--to", &to, "--name", name]),
        ));
        wait_until(&format!("{name}'s notification"), limit, &log, &|| {
            record.lock().unwrap().notified.len() > before
        });
        let notified = record.lock().unwrap().notified[before].clone();
        assert_eq!(
            notified.summary,
            format!("{name} is calling"),
            "{notified:?}"
        );
        wait_until(&format!("{name} rings over the call"), limit, &log, &|| {
            call_word(&status) == "ringing"
        });
        emit.send((notified.id, "answer".into())).unwrap();
        wait_until(&format!("{name} answered"), limit, &log, &|| {
            call_word(&status) == "in_call"
        });
    }
    wait_until("three tiles shown", limit, &log, &|| {
        shown_peers(&status) == 3
    });
    std::thread::sleep(Duration::from_secs(2));
    screenshot(dir.path(), &display, "peers.png");
    assert!(!app.text().contains("panicked"), "{}", app.text());
}

/// Peers the status file says have a tile drawn.
fn shown_peers(status: &Path) -> usize {
    let text = std::fs::read_to_string(status).unwrap_or_default();
    text.lines()
        .filter(|l| l.starts_with("peer "))
        .filter(|l| {
            l.split_whitespace()
                .find_map(|w| w.strip_prefix("shown="))
                .and_then(|n| n.parse::<u64>().ok())
                .is_some_and(|n| n > 0)
        })
        .count()
}

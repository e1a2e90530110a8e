//! The app's engine without a window or audio devices, as the app tests drive it.

use std::time::{Duration, Instant};

use lipcall::app::engine::{Engine, EngineConfig, lock};
use lipcall::audio::DeviceChoice;

/// An engine named `name` with silent playback and no microphone, listening for direct calls
/// on `listen` (none: it only places calls).
pub fn headless_engine(name: &str, listen: Option<&str>) -> Engine {
    engine(name, listen, true)
}

/// [`headless_engine`] with real devices: PulseAudio's default sink (a test's null sink
/// through `PULSE_SINK`) and default source (the null sink's monitor) as its microphone.
pub fn engine_with_audio(name: &str, listen: Option<&str>) -> Engine {
    engine(name, listen, false)
}

fn engine(name: &str, listen: Option<&str>, no_audio: bool) -> Engine {
    Engine::start(EngineConfig {
        listen: listen.map(|a| a.parse().expect("a socket address")),
        demo: false,
        name: name.into(),
        input: DeviceChoice::Default,
        output: DeviceChoice::Default,
        no_audio,
        output_margin: lipcall::audio::DEFAULT_OUTPUT_MARGIN,
    })
    .expect("the engine starts")
}

/// Waits up to `limit` for `done` to hold of the engine's shared state; past it, fails naming
/// `what` with the call, the phone and the peers as they were.
pub fn wait_for(
    engine: &Engine,
    what: &str,
    limit: Duration,
    done: impl Fn(&lipcall::app::engine::Shared) -> bool,
) {
    let deadline = Instant::now() + limit;
    loop {
        {
            let s = lock(&engine.shared);
            if done(&s) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: call {:?}, phone {:?}, peers {:?}",
                s.call,
                s.phone,
                s.peers.views()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

static SHOWN_SINCE: std::sync::LazyLock<std::time::Instant> =
    std::sync::LazyLock::new(std::time::Instant::now);

/// A peer as the tiles and the list are drawn from: named `name`, SSRC `ssrc` (its mixer feed
/// too), at `addr`, in the call since `joined_ms` after the first one; quiet, nothing lost.
pub fn shown_peer(
    name: &str,
    ssrc: u32,
    addr: std::net::SocketAddr,
    joined_ms: u64,
) -> lipcall::app::ShownPeer {
    lipcall::app::ShownPeer {
        view: lipcall::app::peer::PeerView {
            peer: lipcall::net::transport::PeerId::Ssrc(ssrc),
            name: name.into(),
            named: true,
            addr,
            feed: lipcall::audio::PeerId(ssrc),
            is_demo: false,
            codec: None,
            talking: false,
            level_db: -30.0,
            joined: *SHOWN_SINCE + std::time::Duration::from_millis(joined_ms),
            in_call_since: Some(*SHOWN_SINCE + std::time::Duration::from_millis(joined_ms)),
            loss_percent: 0.0,
            jitter_ms: 0.0,
            delay_ms: 0.0,
            frames_animated: 0,
            frames_received: 0,
            frames_recovered: 0,
            unknown_payload: 0,
            queued_ms: 0.0,
            buffer: Default::default(),
        },
        face: None,
        prefs: lipcall::app::settings::PeerPrefs::default(),
        frames_shown: 0,
    }
}

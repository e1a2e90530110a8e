//! The app's engine without a window or audio devices, as the app tests drive it.

use std::time::{Duration, Instant};

use lipcall::app::engine::{Engine, EngineConfig, lock};
use lipcall::audio::DeviceChoice;

/// An engine named `name` with silent playback and no microphone, listening for direct calls
/// on `listen` (none: it only places calls).
pub fn headless_engine(name: &str, listen: Option<&str>) -> Engine {
    Engine::start(EngineConfig {
        listen: listen.map(|a| a.parse().expect("a socket address")),
        demo: false,
        name: name.into(),
        input: DeviceChoice::Default,
        output: DeviceChoice::Default,
        no_audio: true,
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

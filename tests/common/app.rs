//! The app's engine without a window or audio devices, as the app tests drive it.

use lipcall::app::engine::{Engine, EngineConfig};
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
    })
    .expect("the engine starts")
}

//! The app under a flood of new SSRCs: one socket on 127.0.0.1 sends 2,000 valid packets a
//! second to the app's engine, each from a new SSRC, while a real caller talks to it. The
//! caller must still be heard and shown (its peer table once evicted every newcomer).

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::net::{new_ssrc_flood, talk};
use lipcall::app::engine::lock;
use lipcall::net::session::{Session, SessionConfig};

/// Frames the caller talks: 10 s.
const FRAMES: u32 = 500;

#[test]
fn the_app_hears_a_caller_through_a_flood_of_new_ssrcs() {
    let engine = common::app::headless_engine("Eve", Some("127.0.0.1:0"));
    let to = lock(&engine.shared)
        .call
        .local_addr
        .expect("the idle session listens");
    let stop = Arc::new(AtomicBool::new(false));
    let flood = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || new_ssrc_flood(to, &stop))
    };
    std::thread::sleep(Duration::from_millis(500));
    let caller = std::thread::spawn(move || {
        let mut config = SessionConfig::new("127.0.0.1:0".parse().unwrap());
        config.destinations = vec![to];
        config.name = Some("Alice".into());
        config.rtcp_interval = Duration::from_millis(200);
        let session = Session::start(config).unwrap();
        talk(&session, FRAMES);
        // Its last frames played out before it says goodbye.
        std::thread::sleep(Duration::from_millis(600));
        session.leave();
    });
    // The most frames the app showed the caller as played, and whether it was ever shown.
    let mut played = 0u64;
    let mut animated = 0u64;
    let deadline = Instant::now() + Duration::from_secs(FRAMES as u64 / 50 + 15);
    while !caller.is_finished() && Instant::now() < deadline {
        {
            let s = lock(&engine.shared);
            for view in s.peers.views().iter().filter(|v| v.name == "Alice") {
                played = played.max(view.buffer.played);
                animated = animated.max(view.frames_animated);
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    caller.join().unwrap();
    stop.store(true, Ordering::Relaxed);
    let flooded = flood.join().unwrap();
    let shown = lock(&engine.shared).peers.len();
    eprintln!(
        "flood of {flooded} packets; the app played {played} of the caller's {FRAMES} frames, \
         animated {animated}; {shown} peers shown at the end"
    );
    assert!(flooded > 10_000, "{flooded}");
    assert!(
        played >= u64::from(FRAMES) * 9 / 10,
        "the app played {played} of the caller's {FRAMES} frames"
    );
    assert!(animated >= u64::from(FRAMES) * 9 / 10, "{animated}");
}

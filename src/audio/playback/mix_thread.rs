//! The mixer thread: takes peers and sinks by command and keeps the current sink's ring
//! filled to its target, mixing a piece (10 ms) at a time (and resampling where the sink's rate
//! is not the mixer's).
//!
//! It parks between looks and the output wakes it after each buffer it plays
//! ([`OutputClock::wake_me`]), so the ring is topped up at once and can be kept at one device
//! period plus a margin.
//!
//! Its peers' frames are pulled on its demand, one frame ahead ([`crate::audio::pacer`]): the
//! puller is woken as each frame is mixed and queues the next while the ring still plays. When
//! a peer heard in the last piece has nothing queued yet, the mixer waits for it as long as the
//! ring holds more than the device's next callback takes, then mixes without it: a puller held up costs ring,
//! not a gap in that peer's stream.

use std::sync::{Arc, Mutex, PoisonError, mpsc};
use std::time::Duration;

use super::sink::RingTarget;
use crate::audio::clock::{OutputClock, SinkMapping};
use crate::audio::mixer::{Mixer, MixerPeer, PeerId, Upsampler};
use crate::vocab::MAX_FRAME_SAMPLES;

pub(super) enum Command {
    Attach {
        ring: rtrb::Producer<f32>,
        clock: Arc<OutputClock>,
        target: RingTarget,
    },
    Add(MixerPeer),
    Remove(PeerId),
    Stop,
}

/// The mixer thread: keeps the current sink's ring filled to its target.
pub(super) fn mixer_thread(
    mut mixer: Mixer,
    commands: mpsc::Receiver<Command>,
    detached: &Mutex<Option<String>>,
) {
    let detach = |why: String| {
        tracing::warn!("{why}");
        *detached.lock().unwrap_or_else(PoisonError::into_inner) = Some(why);
    };
    let mut chunk = [0.0f32; MAX_FRAME_SAMPLES];
    let chunk = &mut chunk[..mixer.piece_len()];
    let mut sink: Option<(rtrb::Producer<f32>, Upsampler, RingTarget)> = None;
    loop {
        loop {
            match commands.try_recv() {
                Ok(Command::Attach {
                    ring,
                    clock,
                    target,
                }) => match Upsampler::in_pieces(mixer.rate(), clock.rate(), chunk.len()) {
                    Ok(up) => {
                        clock.wake_me();
                        clock.set_mapping(SinkMapping {
                            mix_start: mixer.position(),
                            ring_start: 0,
                            resampler_delay: up.delay() as u64,
                            rate: clock.rate(),
                            mix_rate: mixer.rate(),
                        });
                        sink = Some((ring, up, target));
                    }
                    Err(e) => {
                        detach(format!("output not attached: {e}"));
                        sink = None;
                    }
                },
                Ok(Command::Add(p)) => {
                    if let Err(p) = mixer.add(p) {
                        tracing::warn!("peer {:?} not mixed: table full", p.id());
                    }
                }
                Ok(Command::Remove(id)) => {
                    mixer.remove(id);
                }
                Ok(Command::Stop) | Err(mpsc::TryRecvError::Disconnected) => return,
                Err(mpsc::TryRecvError::Empty) => break,
            }
        }
        let mut waiting = false;
        if let Some((ring, up, target)) = sink.as_mut() {
            let cap = ring.buffer().capacity();
            while cap - ring.slots() < target.fill && ring.slots() >= up.next_len() {
                // Safe while the next callback still finds a period in the ring.
                if cap - ring.slots() > target.period && mixer.awaits_peer(chunk.len()) {
                    waiting = true;
                    break;
                }
                mixer.mix(chunk);
                match up.process(chunk) {
                    Ok(out) => {
                        // Room was checked above; a short push cannot happen.
                        let _ = ring.push_partial_slice(out);
                    }
                    Err(e) => {
                        detach(format!("resampling failed, output detached: {e}"));
                        sink = None;
                        break;
                    }
                }
            }
        }
        // Woken by the output as it takes each buffer; the timeout serves commands and a
        // waited-for peer.
        std::thread::park_timeout(Duration::from_millis(if waiting { 1 } else { 5 }));
    }
}

//! What the threads that talk to Janus (the HTTP long poll, the WebSocket) hand the session:
//! events, bounded so that a flooding server waits for the reader; and the keepalive's pace.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::time::Duration;

use serde_json::Value;

use super::JanusError;

/// Janus destroys a session after 60 s of silence (its default `session_timeout`).
pub(super) const KEEPALIVE: Duration = Duration::from_secs(15);

/// What the long-poll (or WebSocket) thread hands over.
pub(super) enum Polled {
    Event(Value),
    /// The session is gone or Janus unreachable; the thread has stopped.
    Lost(JanusError),
}

/// A fresh transaction id.
pub(super) fn transaction(counter: &AtomicU64) -> String {
    format!("lipcall-{}", counter.fetch_add(1, Ordering::Relaxed))
}

/// Waits until the owner has room for `polled`; false when the owner is gone or stopping.
pub(super) fn hand_over(tx: &SyncSender<Polled>, stop: &AtomicBool, mut polled: Polled) -> bool {
    loop {
        match tx.try_send(polled) {
            Ok(()) => return true,
            Err(TrySendError::Disconnected(_)) => return false,
            Err(TrySendError::Full(back)) => {
                if stop.load(Ordering::Relaxed) {
                    return false;
                }
                polled = back;
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
}

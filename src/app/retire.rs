//! Links the engine is done with, hung up and dropped on a thread of their own. Hanging up
//! waits on the other side (a SIP CANCEL's or BYE's answer, a Janus leave's): on the worker it
//! would hold up every other peer's audio and face for as long.

use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::call::link::Link;
use crate::net::join::join_within;

/// Links waiting to be hung up at most; past it the worker hangs up itself (a user who ends
/// calls faster than servers answer waits, rather than threads or memory growing).
const WAITING: usize = 8;
/// How long the app's end waits for the last hang-ups (their BYEs on the wire).
const LAST_WORDS: Duration = Duration::from_secs(3);

pub struct Retirer {
    links: Option<SyncSender<Box<dyn Link>>>,
    thread: Option<JoinHandle<()>>,
}

impl Retirer {
    pub fn start() -> std::io::Result<Self> {
        let (links, waiting) = sync_channel(WAITING);
        let thread = std::thread::Builder::new()
            .name("lipcall-hang-up".into())
            .spawn(move || hang_up_each(&waiting))?;
        Ok(Self {
            links: Some(links),
            thread: Some(thread),
        })
    }

    /// Hangs `link` up and drops it. lipcall's own sessions only say BYE on their socket and
    /// close it, at once: they end here, so that their port is free when this returns.
    pub fn retire(&self, mut link: Box<dyn Link>) {
        if link.session().is_some() {
            link.leave();
            return;
        }
        let Some(links) = &self.links else {
            link.leave();
            return;
        };
        match links.try_send(link) {
            Ok(()) => {}
            Err(TrySendError::Full(mut link) | TrySendError::Disconnected(mut link)) => {
                tracing::warn!("{WAITING} calls are still hanging up: hanging this one up here");
                link.leave();
            }
        }
    }
}

fn hang_up_each(waiting: &Receiver<Box<dyn Link>>) {
    while let Ok(mut link) = waiting.recv() {
        link.leave();
        drop(link);
    }
}

impl Drop for Retirer {
    fn drop(&mut self) {
        self.links = None;
        if !join_within(&mut self.thread, LAST_WORDS) {
            tracing::warn!("calls still hanging up at exit: left to end with the process");
        }
    }
}

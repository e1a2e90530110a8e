//! The engine's side of [`crate::app::lookup`]: a call whose host has a name is placed once
//! the name is found, off the worker.

use std::net::SocketAddr;
use std::sync::PoisonError;
use std::time::Instant;

use super::{Then, Worker, lock};

impl Worker {
    /// Finds `host` off the worker, then goes on as `then` says ([`Worker::follow_lookup`]).
    pub(super) fn look_up(
        &mut self,
        host: &str,
        then: Then,
        find: impl FnOnce() -> Result<SocketAddr, String> + Send + 'static,
    ) -> anyhow::Result<()> {
        self.lookups.start(host, then, find)?;
        let mut s = lock(&self.shared);
        s.call.state = format!("looking up {host}…");
        s.call.error = None;
        Ok(())
    }

    /// Places the call whose host was found, each pass of the worker's loop.
    pub(super) fn follow_lookup(&mut self) {
        let Some((then, found)) = self.lookups.answered(Instant::now()) else {
            return;
        };
        let placed = found.map_err(anyhow::Error::msg).and_then(|at| match then {
            Then::Direct(spec, key) => self.call_direct(&spec, at, key.get().cloned()),
            Then::Sip { target, media } => {
                match media.lock().unwrap_or_else(PoisonError::into_inner).take() {
                    Some(media) => self.dial_from(target, at, media),
                    None => Err(anyhow::anyhow!("the call's media sockets were not bound")),
                }
            }
            Then::Janus(spec) => self.join_janus_at(&spec, at),
        });
        if let Err(e) = placed {
            self.fail(format!("{e:#}"));
        }
    }
}

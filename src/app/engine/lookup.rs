//! Host names looked up off the worker. DNS can take seconds (a resolver that does not
//! answer): a worker waiting on it would hold up every peer's audio and face. The look-up
//! runs on a short-lived thread and its answer comes back to the worker's loop, which then
//! places the call. A newer call or a leave forgets a look-up still running (its thread ends
//! on its own), and one that takes longer than [`LOOKUP_WAIT`] fails the call.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, sync_channel};
use std::time::{Duration, Instant};

use super::{CallSpec, Worker, lock};

/// Look-ups running at once at most, forgotten ones included (a user who redials while the
/// resolver is silent waits, rather than threads piling up).
const MOST_RUNNING: usize = 4;
/// How long a call waits for its host's address.
pub(super) const LOOKUP_WAIT: Duration = Duration::from_secs(15);

/// What the address found is for.
pub(super) enum Then {
    /// A direct call (or a relay room) to the address.
    Direct(Box<CallSpec>),
    /// A SIP call to `target`, from the local address found.
    Sip { target: String },
}

struct Lookup {
    then: Then,
    host: String,
    began: Instant,
    answer: Receiver<Result<SocketAddr, String>>,
}

#[derive(Default)]
pub(super) struct Lookups {
    running: Arc<AtomicUsize>,
    pending: Option<Lookup>,
}

/// Counts a look-up's thread out however it ends.
struct Running(Arc<AtomicUsize>);

impl Drop for Running {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

impl Lookups {
    /// Starts finding `host` with `find` on a thread of its own, replacing any look-up
    /// pending.
    pub(super) fn start(
        &mut self,
        host: &str,
        then: Then,
        find: impl FnOnce() -> Result<SocketAddr, String> + Send + 'static,
    ) -> anyhow::Result<()> {
        self.pending = None;
        if self.running.load(Ordering::Relaxed) >= MOST_RUNNING {
            anyhow::bail!(
                "cannot look {host} up: {MOST_RUNNING} look-ups are still waiting on the resolver"
            );
        }
        self.running.fetch_add(1, Ordering::Relaxed);
        let running = Running(Arc::clone(&self.running));
        let (tell, answer) = sync_channel(1);
        std::thread::Builder::new()
            .name("lipcall-lookup".into())
            .spawn(move || {
                let _running = running;
                let _ = tell.send(find());
            })
            .map_err(|e| anyhow::anyhow!("cannot look {host} up: {e}"))?;
        self.pending = Some(Lookup {
            then,
            host: host.to_owned(),
            began: Instant::now(),
            answer,
        });
        Ok(())
    }

    pub(super) fn forget(&mut self) {
        self.pending = None;
    }

    /// The pending look-up's answer, once it came (or it waited too long).
    fn answered(&mut self, now: Instant) -> Option<(Then, Result<SocketAddr, String>)> {
        let lookup = self.pending.as_ref()?;
        let found = match lookup.answer.try_recv() {
            Ok(found) => found,
            Err(TryRecvError::Empty) if now - lookup.began < LOOKUP_WAIT => return None,
            Err(TryRecvError::Empty) => Err(format!(
                "no address for {} within {} s (the resolver does not answer)",
                lookup.host,
                LOOKUP_WAIT.as_secs()
            )),
            Err(TryRecvError::Disconnected) => Err(format!("looking {} up failed", lookup.host)),
        };
        let lookup = self.pending.take()?;
        Some((lookup.then, found))
    }
}

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
            Then::Direct(spec) => self.call_direct(&spec, at),
            Then::Sip { target } => self.dial_from(target, at),
        });
        if let Err(e) = placed {
            if !self.in_call {
                self.set_idle_status();
            }
            lock(&self.shared).call.error = Some(format!("{e:#}"));
        }
    }
}

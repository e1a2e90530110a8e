//! What a SIP peer can make lipcall say, bounded: a fault it may repeat without end is warned
//! about once and counted ([`Repeated`]), and ezk's own warnings (one per malformed or orphaned
//! datagram, per response to an early dialog we let go) are limited per line of ezk's source
//! ([`EzkLogLimit`], a layer of the log's subscriber).

use std::collections::HashMap;
use std::fmt::{Debug, Display};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, Layer};

/// A fault a peer may repeat without end: warned the first time, then counted, and the count said
/// once when the call is over (the value dropped).
#[derive(Debug)]
pub struct Repeated {
    what: &'static str,
    times: u64,
}

impl Repeated {
    pub const fn new(what: &'static str) -> Self {
        Self { what, times: 0 }
    }

    pub fn warn(&mut self, detail: impl Display) {
        self.times += 1;
        if self.times == 1 {
            tracing::warn!("{}: {detail}", self.what);
        } else {
            tracing::debug!("{}: {detail}", self.what);
        }
    }
}

impl Drop for Repeated {
    fn drop(&mut self) {
        if self.times > 1 {
            tracing::warn!("{}: {} times in all", self.what, self.times);
        }
    }
}

/// Warnings and errors one line of ezk's source may print per [`LOG_WINDOW`].
pub const LOG_BURST: u32 = 5;
pub const LOG_WINDOW: Duration = Duration::from_secs(60);

/// Limits ezk's warnings and errors to [`LOG_BURST`] per line of its source per [`LOG_WINDOW`]
/// (its debug output, asked for with RUST_LOG, is left whole). The table has one entry per line
/// of ezk that warns: it cannot grow with what peers send.
#[derive(Default)]
pub struct EzkLogLimit {
    said: Mutex<HashMap<(String, u32), (Instant, u32)>>,
}

/// Where an event was written: ezk logs through the `log` crate, whose records reach tracing
/// with the target "log" and the real one in their fields.
#[derive(Default)]
struct Origin {
    target: Option<String>,
    line: u32,
}

impl Visit for Origin {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "log.target" {
            self.target = Some(value.to_owned());
        }
    }

    fn record_u64(&mut self, field: &Field, value: u64) {
        if field.name() == "log.line" {
            self.line = u32::try_from(value).unwrap_or(u32::MAX);
        }
    }

    fn record_debug(&mut self, _: &Field, _: &dyn Debug) {}
}

impl EzkLogLimit {
    fn allow(&self, target: &str, line: u32, now: Instant) -> bool {
        let Ok(mut said) = self.said.lock() else {
            return true;
        };
        let (since, count) = said.entry((target.to_owned(), line)).or_insert((now, 0));
        if now.saturating_duration_since(*since) >= LOG_WINDOW {
            (*since, *count) = (now, 0);
        }
        *count += 1;
        *count <= LOG_BURST
    }
}

impl<S: Subscriber> Layer<S> for EzkLogLimit {
    fn event_enabled(&self, event: &Event<'_>, _: Context<'_, S>) -> bool {
        let meta = event.metadata();
        if *meta.level() > Level::WARN {
            return true;
        }
        let mut origin = Origin {
            target: None,
            line: meta.line().unwrap_or(0),
        };
        if meta.target() == "log" {
            event.record(&mut origin);
        }
        let target = origin.target.as_deref().unwrap_or(meta.target());
        !target.starts_with("ezk") || self.allow(target, origin.line, Instant::now())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_line_of_ezk_is_limited_on_its_own_and_again_after_the_window() {
        let limit = EzkLogLimit::default();
        let t0 = Instant::now();
        let said = (0..100)
            .filter(|_| limit.allow("ezk_sip_core::transport::parse", 71, t0))
            .count();
        assert_eq!(said, LOG_BURST as usize);
        assert!(limit.allow("ezk_sip_core::endpoint", 300, t0));
        assert!(!limit.allow("ezk_sip_core::transport::parse", 71, t0 + LOG_WINDOW / 2));
        assert!(limit.allow("ezk_sip_core::transport::parse", 71, t0 + LOG_WINDOW));
    }
}

//! `lipcall relay`: the room relay on a socket, with its counters every ten seconds.

use std::time::{Duration, Instant};

use anyhow::Result;

use super::net::resolve;
use super::recording::{stop_flag, stopped};
use crate::net::relay::{Relay, RelayConfig};

/// `lipcall relay`.
#[derive(Debug, Clone, clap::Args)]
pub struct RelayArgs {
    /// Address to listen on, HOST:PORT (port 0 picks one). Once bound, one stderr line
    /// says the address: `lipcall: relay listening on IP:PORT` (a stable format).
    #[arg(long, value_name = "HOST:PORT")]
    pub listen: String,
    /// Stop after this many seconds (otherwise until Ctrl-C (SIGINT) or SIGTERM, which end it
    /// at any time).
    #[arg(long, allow_hyphen_values = true, value_parser = super::parse_seconds)]
    pub seconds: Option<f64>,
}

/// How often the relay's loop looks at the clock and the stop flag.
const LOOK: Duration = Duration::from_millis(20);

pub fn relay(listen: &str, seconds: Option<f64>) -> Result<()> {
    let stop = stop_flag()?;
    let relay = Relay::start(resolve(listen)?, RelayConfig::default())?;
    eprintln!("lipcall: relay listening on {}", relay.local_addr());
    let start = Instant::now();
    let until = seconds.map(|s| start + Duration::from_secs_f64(s));
    let mut next_report = start + Duration::from_secs(10);
    loop {
        let now = Instant::now();
        if until.is_some_and(|until| now >= until) {
            break;
        }
        if stopped(&stop) {
            eprintln!("lipcall: stopped by a signal");
            break;
        }
        let wake = until.map_or(now + LOOK, |until| until.min(now + LOOK));
        std::thread::sleep(wake.saturating_duration_since(now));
        if Instant::now() >= next_report {
            print_relay(&relay);
            next_report += Duration::from_secs(10);
        }
    }
    print_relay(&relay);
    Ok(())
}

fn print_relay(relay: &Relay) {
    let s = relay.stats();
    eprintln!(
        "relay rooms={} members={} datagrams={} forwarded={} copies={} challenges={} joins={} \
         refused={} source_limited={} leaves={} expired={} bad_cookie={} outdated={} \
         unknown_source={} malformed={} rate_limited={}",
        s.rooms,
        s.members,
        s.datagrams,
        s.forwarded,
        s.copies,
        s.challenges,
        s.joins,
        s.refused,
        s.source_limited,
        s.leaves,
        s.expired,
        s.bad_cookie,
        s.outdated,
        s.unknown_source,
        s.malformed,
        s.rate_limited
    );
}

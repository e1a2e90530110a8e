//! `lipcall relay`: the room relay on a socket, with its counters every ten seconds.

use std::time::{Duration, Instant};

use anyhow::Result;

use super::net::resolve;
use crate::net::relay::{Relay, RelayConfig};

/// `lipcall relay`.
#[derive(Debug, Clone, clap::Args)]
pub struct RelayArgs {
    /// Address to listen on, HOST:PORT (port 0 picks one). Once bound, one stderr line
    /// says the address: `lipcall: relay listening on IP:PORT` (a stable format).
    #[arg(long, value_name = "HOST:PORT")]
    pub listen: String,
    /// Stop after this many seconds (otherwise run until killed).
    #[arg(long, allow_hyphen_values = true, value_parser = super::parse_seconds)]
    pub seconds: Option<f64>,
}

pub fn relay(listen: &str, seconds: Option<f64>) -> Result<()> {
    let relay = Relay::start(resolve(listen)?, RelayConfig::default())?;
    eprintln!("lipcall: relay listening on {}", relay.local_addr());
    let start = Instant::now();
    let mut next_report = start + Duration::from_secs(10);
    loop {
        std::thread::sleep(Duration::from_millis(100));
        if seconds.is_some_and(|s| start.elapsed().as_secs_f64() >= s) {
            break;
        }
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

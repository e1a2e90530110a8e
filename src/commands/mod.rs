//! The command-line subcommands. Each takes its parsed arguments and returns an anyhow error
//! whose one-line rendering is what the user sees.

pub mod animate;
pub mod audio;
pub mod codec;
pub mod evaluate;
pub mod grid;
pub mod janus;
pub mod lipsync;
pub mod mumble;
pub mod net;
mod playout;
mod recording;
pub mod redact;
pub mod relay;
pub mod sip;

/// The one line a user sees for an error: its chain joined by ": ", leaving out a cause whose
/// text is already in the line (library errors name their `io::Error` in their own message and
/// also give it as their source, which would print the OS error twice).
pub fn error_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if text.is_empty() || line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

/// Longest run a `--seconds` limit may ask for (about four months).
pub const MAX_SECONDS: f64 = 1e7;

/// Parses a run's duration in seconds (clap value parser): a finite number above 0 and at most
/// [`MAX_SECONDS`]; NaN, infinities, negative numbers and 0 are usage errors, not a run that
/// never stops, stops at once or panics converting to a `Duration`.
pub fn parse_seconds(arg: &str) -> Result<f64, String> {
    match arg.trim().parse::<f64>() {
        Ok(s) if s > 0.0 && s <= MAX_SECONDS => Ok(s),
        _ => Err(format!(
            "must be a number of seconds above 0, at most {MAX_SECONDS:e}"
        )),
    }
}

/// `--bandwidth` (clap value parser): an Opus band.
pub fn parse_bandwidth(arg: &str) -> Result<crate::codec::opus::codec::Bandwidth, String> {
    arg.parse()
}

/// `--frame-ms` (clap value parser): Opus's frame length, 10 or 20 ms.
pub fn parse_frame_ms(arg: &str) -> Result<u8, String> {
    match arg.trim().parse::<u8>() {
        Ok(ms) if crate::codec::opus::codec::FRAME_MS.contains(&ms) => Ok(ms),
        _ => Err(format!("{arg:?}: Opus goes in frames of 10 or 20 ms")),
    }
}

/// Opus's frame length `frame_ms` for `codec`: only Opus sends other than 20 ms frames.
pub fn check_frame_ms(codec: crate::codec::any::Codec, frame_ms: u8) -> anyhow::Result<()> {
    if frame_ms != 20 && codec != crate::codec::any::Codec::Opus {
        anyhow::bail!(
            "--frame-ms {frame_ms}: only Opus goes in frames other than 20 ms, not {codec}"
        );
    }
    Ok(())
}

/// A sample rate a 20 ms frame holds whole, 8 to 48 kHz (`receive --rate`).
pub fn parse_frame_rate(arg: &str) -> Result<u32, String> {
    let rate: u32 = arg.trim().parse().map_err(|e| format!("{e}"))?;
    if crate::vocab::audio::valid_rate(rate) {
        Ok(rate)
    } else {
        Err(format!(
            "{rate} Hz: expected 8000 to 48000, divisible by 50 (8000, 16000, 44100, 48000)"
        ))
    }
}

/// `--peer-timeout` (clap value parser): [`parse_seconds`], and at least a second. A peer is
/// not gone between two packets: with Opus DTX a quiet one sends one every 400 ms, and a timeout
/// of a few microseconds would drop every caller at once.
pub fn parse_peer_timeout(arg: &str) -> Result<f64, String> {
    const MIN: f64 = 1.0;
    match parse_seconds(arg) {
        Ok(s) if s >= MIN => Ok(s),
        _ => Err(format!(
            "must be a number of seconds from {MIN} to {MAX_SECONDS:e} (how long a peer may \
             send nothing before it counts as gone)"
        )),
    }
}

/// Checks a room passphrase: a blank one keys nothing a listener could not guess, and a call
/// keyed by it must not be called encrypted.
pub fn parse_passphrase(passphrase: &str) -> Result<(), String> {
    if passphrase.trim().is_empty() {
        return Err("the passphrase is blank (give none for a plain, unencrypted call)".into());
    }
    Ok(())
}

/// Diagnostics (`tracing` events, and the `log` records of wgpu, eframe and ezk) go to stderr:
/// warnings and errors, or what RUST_LOG asks for (`debug`, `lipcall=debug,wgpu=warn`), with
/// keys, digests, passwords and tokens redacted at every level ([`redact`]).
pub fn install_logging() {
    use std::io::IsTerminal;
    use tracing_subscriber::filter::{LevelFilter, Targets};
    use tracing_subscriber::prelude::*;
    let warnings = || Targets::new().with_default(LevelFilter::WARN);
    let mut unreadable = None;
    let filter = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => spec.parse::<Targets>().unwrap_or_else(|e| {
            unreadable = Some(format!("RUST_LOG={spec:?} ignored ({e}): warnings only"));
            warnings()
        }),
        _ => warnings(),
    };
    // ureq's trace hex-dumps every HTTP request and response (a Janus's api_secret, token and
    // room pin among them), split across lines where no redaction can find them.
    let filter = filter.with_target("ureq_proto::util", LevelFilter::DEBUG);
    let layer = tracing_subscriber::fmt::layer()
        .with_writer(redact::RedactedStderr)
        .with_ansi(std::io::stderr().is_terminal());
    let installed = tracing_subscriber::registry()
        .with(layer)
        .with(filter)
        .with(crate::net::sip::quiet::EzkLogLimit::default())
        .try_init();
    if let (Ok(()), Some(why)) = (installed, unreadable) {
        tracing::warn!("{why}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_are_finite_positive_and_bounded() {
        assert_eq!(parse_seconds("2.5"), Ok(2.5));
        assert_eq!(parse_seconds("1e7"), Ok(1e7));
        for bad in [
            "NaN", "nan", "inf", "-inf", "-1", "0", "-0", "1e300", "", "ten",
        ] {
            assert!(parse_seconds(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_peer_timeout("1"), Ok(1.0));
        assert_eq!(parse_peer_timeout("30"), Ok(30.0));
        for bad in ["1e-300", "0.5", "0", "nan", "1e300"] {
            let why = parse_peer_timeout(bad).unwrap_err();
            assert!(why.contains("from 1 to"), "{bad}: {why}");
        }
    }

    #[test]
    fn an_os_error_named_by_its_wrapper_is_printed_once() {
        let e = crate::input::read(
            std::path::Path::new("/nonexistent/lipcall.wav"),
            crate::input::MAX_INPUT_BYTES,
        )
        .unwrap_err();
        let e = anyhow::Error::new(e).context("loading the head");
        let line = error_line(&e);
        assert_eq!(line.matches("os error 2").count(), 1, "{line}");
        assert!(line.starts_with("loading the head: cannot read"), "{line}");
    }
}

//! The log's writer: each event reaches stderr whole, with its secrets replaced. ezk prints
//! every SIP message at trace level, and those carry SDES master keys (`a=crypto: …
//! inline:KEY`, RFC 4568) and digest responses (`response="HEX"`, which a word list cracks
//! offline); a filter on ezk's targets would lose those dumps for debugging and miss any other
//! line that carries one, so the writer redacts every line instead.

use std::borrow::Cow;
use std::io::Write;

use tracing_subscriber::fmt::MakeWriter;

/// What replaces a secret.
pub const REDACTED: &str = "(redacted)";

/// Whether a byte can be part of a secret's value.
type ValueByte = fn(&u8) -> bool;

/// A named field's value in JSON, a URL's query or `Debug` output: up to its quote, `&`, `,`,
/// a closing bracket or a space.
fn field_byte(b: &u8) -> bool {
    !(b.is_ascii_whitespace() || matches!(*b, b'"' | b'\\' | b'&' | b',' | b';' | b'}' | b')'))
}

/// The markers a secret follows (with their separator), each with the bytes its value is
/// made of.
const MARKED: [(&str, ValueByte); 2] = [
    ("inline:", |b| {
        b.is_ascii_alphanumeric() || matches!(*b, b'+' | b'/' | b'=')
    }),
    ("response=", u8::is_ascii_alphanumeric),
];

/// Field names whose value is a secret wherever a `:` or `=` follows them (the value quoted,
/// or unquoted right after the separator):
/// Janus's `apisecret`, `token` and room `pin` in its requests and long-poll URLs (ureq logs
/// both), and any password or passphrase.
const FIELDS: [&str; 6] = [
    "apisecret",
    "secret",
    "token",
    "pin",
    "password",
    "passphrase",
];

/// `text` with the value after each secret's marker or field name (case aside, quoted or not,
/// its quotes printed escaped or not) replaced by [`REDACTED`].
pub fn redact(text: &str) -> Cow<'_, str> {
    // ASCII lowercasing keeps every byte where it was.
    let lower = text.to_ascii_lowercase();
    let bytes = text.as_bytes();
    let mut spans = Vec::new();
    let quotes = |at: usize| {
        bytes[at..]
            .iter()
            .take_while(|b| matches!(**b, b'"' | b'\\'))
            .count()
    };
    let mut value = |start: usize, in_value: ValueByte| {
        let start = start + quotes(start);
        let end = start + bytes[start..].iter().take_while(|b| in_value(b)).count();
        if end > start {
            spans.push((start, end));
        }
        end
    };
    for (marker, in_value) in MARKED {
        let mut from = 0;
        while let Some(at) = lower[from..].find(marker) {
            from = value(from + at + marker.len(), in_value);
        }
    }
    for name in FIELDS {
        let mut from = 0;
        while let Some(at) = lower[from..].find(name) {
            let begin = from + at;
            let mut next = begin + name.len();
            from = next;
            // A whole word: `spin=` and `pings:` are no pin.
            if begin > 0 && bytes[begin - 1].is_ascii_alphanumeric() {
                continue;
            }
            next += quotes(next);
            if !matches!(bytes.get(next), Some(b':' | b'=')) {
                continue;
            }
            next += 1;
            let spaces = bytes[next..].iter().take_while(|b| **b == b' ').count();
            next += spaces;
            if lower[next..].starts_with("some(") {
                next += "some(".len();
            } else if spaces > 0 && quotes(next) == 0 {
                // Prose (`the secret: …`), not a field.
                continue;
            }
            from = value(next, field_byte);
        }
    }
    if spans.is_empty() {
        return Cow::Borrowed(text);
    }
    spans.sort_unstable();
    let mut out = String::with_capacity(text.len());
    let mut copied = 0;
    for (start, end) in spans {
        if start < copied {
            continue;
        }
        out.push_str(&text[copied..start]);
        out.push_str(REDACTED);
        copied = end;
    }
    out.push_str(&text[copied..]);
    Cow::Owned(out)
}

/// stderr for `tracing`'s formatter: one [`RedactedEvent`] per event.
pub struct RedactedStderr;

impl<'a> MakeWriter<'a> for RedactedStderr {
    type Writer = RedactedEvent;

    fn make_writer(&'a self) -> Self::Writer {
        RedactedEvent(Vec::new())
    }
}

/// One event's text, written to stderr redacted when the formatter is done with it.
pub struct RedactedEvent(Vec<u8>);

impl Write for RedactedEvent {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for RedactedEvent {
    fn drop(&mut self) {
        let text = String::from_utf8_lossy(&self.0);
        // Nowhere to say that stderr failed.
        let _ = std::io::stderr().lock().write_all(redact(&text).as_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn keys_and_digest_responses_are_replaced_and_the_rest_kept() {
        let dump = "a=crypto:1 AES_CM_128_HMAC_SHA1_80 inline:WVNfX19zZW1jdGwgKCkgewkyMjA7fQp9CnVubGVz|2^20|1:4\\r\\n\n\
                    Authorization: Digest username=\\\"alice\\\", realm=\\\"home\\\", \
                    nonce=\\\"abc\\\", uri=\\\"sip:x\\\", response=\\\"6629fae49393a05397450978507c4ef1\\\", algorithm=MD5";
        let shown = redact(dump);
        for secret in [
            "WVNfX19zZW1jdGwgKCkgewkyMjA7fQp9CnVubGVz",
            "6629fae49393a05397450978507c4ef1",
        ] {
            assert!(!shown.contains(secret), "{shown}");
        }
        for kept in [
            "|2^20|1:4",
            "username=\\\"alice\\\"",
            "nonce=\\\"abc\\\"",
            "algorithm=MD5",
        ] {
            assert!(shown.contains(kept), "{kept}: {shown}");
        }
        assert_eq!(shown.matches(REDACTED).count(), 2, "{shown}");
        assert_eq!(
            redact("Proxy-Authorization: Digest RESPONSE=\"0a1b\"").as_ref(),
            "Proxy-Authorization: Digest RESPONSE=\"(redacted)\""
        );
        assert!(matches!(
            redact("nothing secret: inline: response=\"\""),
            Cow::Borrowed(_)
        ));
    }

    #[test]
    fn janus_credentials_pins_and_passwords_are_replaced() {
        let url = "GET http://h:8088/janus/7?maxev=10&apisecret=s3cr3t-api&token=t0ken-abc HTTP";
        let shown = redact(url);
        assert_eq!(
            shown,
            "GET http://h:8088/janus/7?maxev=10&apisecret=(redacted)&token=(redacted) HTTP"
        );
        let json = r#"{"janus":"message","apisecret":"s3cr3t-api","body":{"request":"join","pin": "my pin","ptype":"publisher"}}"#;
        let shown = redact(json);
        assert!(
            !shown.contains("s3cr3t-api") && !shown.contains("my"),
            "{shown}"
        );
        assert!(shown.contains(r#""request":"join""#), "{shown}");
        let debug = r#"Authenticate { username: Some("ann"), password: Some("hunter2"), api_secret: \"x1\" }"#;
        let shown = redact(debug);
        assert!(
            !shown.contains("hunter2") && !shown.contains("x1"),
            "{shown}"
        );
        assert!(shown.contains(r#"username: Some("ann")"#), "{shown}");
        for kept in [
            "pings: 3",
            "spin=4",
            "the token_auth plugin",
            "secrets.rs:12",
        ] {
            assert!(matches!(redact(kept), Cow::Borrowed(_)), "{kept}");
        }
    }

    proptest! {
        #[test]
        fn any_text_is_redacted_without_panicking(text in "\\PC{0,80}", key in "[A-Za-z0-9+/]{8,40}") {
            let line = format!("{text} inline:{key} {text}");
            let shown = redact(&line);
            let unredacted = format!("inline:{key}");
            prop_assert!(!shown.contains(&unredacted));
            prop_assert!(shown.contains(REDACTED));
        }
    }
}

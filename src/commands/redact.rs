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

/// The markers a secret follows, each with the bytes its value is made of.
const SECRETS: [(&str, ValueByte); 2] = [
    ("inline:", |b| {
        b.is_ascii_alphanumeric() || matches!(*b, b'+' | b'/' | b'=')
    }),
    ("response=", u8::is_ascii_alphanumeric),
];

/// `text` with the value after each secret's marker (case aside, quoted or not, its quotes
/// printed escaped or not) replaced by [`REDACTED`].
pub fn redact(text: &str) -> Cow<'_, str> {
    // ASCII lowercasing keeps every byte where it was.
    let lower = text.to_ascii_lowercase();
    let bytes = text.as_bytes();
    let mut spans = Vec::new();
    for (marker, in_value) in SECRETS {
        let mut from = 0;
        while let Some(at) = lower[from..].find(marker) {
            let mut start = from + at + marker.len();
            start += bytes[start..]
                .iter()
                .take_while(|b| matches!(**b, b'"' | b'\\'))
                .count();
            let end = start + bytes[start..].iter().take_while(|b| in_value(b)).count();
            if end > start {
                spans.push((start, end));
            }
            from = end;
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

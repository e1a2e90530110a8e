//! DTMF keys sent as RFC 4733 events on a negotiated call's stream: each digit a few packets
//! of growing duration on one timestamp, then three end packets, then a pause.

use std::time::Instant;

use super::negotiated::Digit;
use super::protocol::SessionCore;
use crate::net::NetError;

/// One DTMF digit: this many 20 ms packets of the tone, then the end packets, then a pause.
const DIGIT_PACKETS: u32 = 5;
const END_PACKETS: u32 = 3;
const PAUSE_PACKETS: u32 = 5;
/// The RFC 4733 volume field (-10 dBm0).
const EVENT_VOLUME: u8 = 10;

/// The RFC 4733 event code of a DTMF key.
pub fn event_code(key: char) -> Option<u8> {
    match key.to_ascii_uppercase() {
        d @ '0'..='9' => Some(d as u8 - b'0'),
        '*' => Some(10),
        '#' => Some(11),
        l @ 'A'..='D' => Some(l as u8 - b'A' + 12),
        _ => None,
    }
}

impl SessionCore {
    /// Queues DTMF keys (0-9 * # A-D) to send as RFC 4733 events; `false` where the call
    /// agreed no events (or is no negotiated call) or a key is not one.
    pub fn queue_digits(&mut self, keys: &str) -> bool {
        let codes: Option<Vec<u8>> = keys.chars().map(event_code).collect();
        match (codes, self.call.as_mut()) {
            (Some(codes), Some(call)) if call.config.events.is_some() => {
                call.digits.extend(codes);
                true
            }
            _ => false,
        }
    }

    /// Whether every queued digit went out.
    pub fn digits_sent(&self) -> bool {
        self.call
            .as_ref()
            .is_none_or(|c| c.digits.is_empty() && c.digit.is_none())
    }

    /// One 20 ms step of the digit being sent: a packet of its event (RFC 4733 2.5), its
    /// duration growing, then the end packets, then a pause before the next digit.
    pub fn step_digits(&mut self, now: Instant) -> Result<(), NetError> {
        let next_timestamp = self.stream.next_timestamp();
        let Some(call) = self.call.as_mut() else {
            return Ok(());
        };
        let Some(events_pt) = call.config.events else {
            call.digits.clear();
            return Ok(());
        };
        if call.digit.is_none() {
            let Some(event) = call.digits.pop_front() else {
                return Ok(());
            };
            call.digit = Some(Digit {
                event,
                timestamp: next_timestamp,
                step: 0,
            });
        }
        let Some(digit) = call.digit.as_mut() else {
            return Ok(());
        };
        let step = digit.step;
        digit.step += 1;
        let (event, timestamp) = (digit.event, digit.timestamp);
        if step >= DIGIT_PACKETS + END_PACKETS + PAUSE_PACKETS {
            call.digit = None;
            // Where no audio went out meanwhile (no microphone), the stream's clock stood
            // still: the next event must not start at this one's timestamp, or the peer
            // takes it for a repeat of this one (RFC 4733 2.5.1.3).
            if next_timestamp == timestamp {
                self.stream.skip(step);
            }
            return self.step_digits(now);
        }
        if step >= DIGIT_PACKETS + END_PACKETS {
            return Ok(());
        }
        let end = step >= DIGIT_PACKETS;
        let duration = self.config.codec.frame_ticks() * (step.min(DIGIT_PACKETS - 1) + 1);
        let [d1, d2] = u16::try_from(duration).unwrap_or(u16::MAX).to_be_bytes();
        let payload = [event, (u8::from(end) << 7) | EVENT_VOLUME, d1, d2];
        let mut buf = self.spare.pop().unwrap_or_default();
        self.stream
            .packetize_other(events_pt, step == 0, timestamp, &payload, &mut buf)?;
        self.send_media(buf, now)?;
        self.stats.sent_events += 1;
        Ok(())
    }
}

//! Packet lengths in SDP (RFC 4566 6): what a peer asks for (`a=ptime`) and takes
//! (`a=maxptime`), and the Opus frame length we send it.

use ezk_sdp_types::{MediaDescription, SessionDescription};

use crate::codec::any::Codec;

/// The frame length we send `codec` in, by the peer's `ptime` and `maxptime`: 10 ms for Opus
/// where `wanted` and the peer neither asks for longer packets (`ptime` above 10) nor takes
/// none that short (`maxptime` below 10), or where its `maxptime` is below 20; else 20.
pub fn send_frame_ms(codec: Codec, ptime: Option<u32>, maxptime: Option<u32>, wanted: u8) -> u8 {
    if codec != Codec::Opus {
        return 20;
    }
    let takes_10 = maxptime.is_none_or(|max| max >= 10);
    let takes_20 = maxptime.is_none_or(|max| max >= 20);
    let asks_longer = ptime.is_some_and(|p| p > 10);
    if takes_10 && (!takes_20 || (wanted == 10 && !asks_longer)) {
        10
    } else {
        20
    }
}

/// A whole number of ms an attribute of the audio line (or the session) gives, e.g. `ptime`.
pub(super) fn ms_attribute(
    description: &SessionDescription,
    audio: &MediaDescription,
    name: &str,
) -> Option<u32> {
    audio
        .attributes
        .iter()
        .chain(&description.attributes)
        .find(|a| a.name.as_str().eq_ignore_ascii_case(name))
        .and_then(|a| a.value.as_ref()?.as_str().trim().parse::<f64>().ok())
        .filter(|ms| ms.is_finite() && *ms > 0.0 && *ms <= 10_000.0)
        .map(|ms| ms.round() as u32)
}

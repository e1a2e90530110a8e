//! Opus through libopus: decoding, encoding and Ogg Opus files (RFC 7845).

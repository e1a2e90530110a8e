//! The SILK layer of Opus read without decoding: the range decoder and the indices up to the NLSFs.

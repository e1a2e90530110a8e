//! LPC analysis of decoded 8 kHz audio: the features for codecs that carry no LSPs.

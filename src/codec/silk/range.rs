//! The range decoder of RFC 6716 section 4.1, for the symbols SILK codes with 8-bit inverse
//! cumulative distributions (`icdf` tables) and with single-bit log-probabilities.
//!
//! Past the end of its buffer the decoder reads zero bytes, as the RFC specifies; callers
//! compare [`RangeDecoder::tell`] with the buffer's size to notice an overrun.

/// Bits per input symbol.
const SYMBOL_BITS: u32 = 8;
/// Total bits of the state registers.
const CODE_BITS: u32 = 32;
/// Bits of the first byte that go into the initial value (the rest wait in `remainder`).
const CODE_EXTRA: u32 = (CODE_BITS - 2) % SYMBOL_BITS + 1;
const CODE_TOP: u32 = 1 << (CODE_BITS - 1);
/// The range is renormalised (another byte shifted in) while it is at or below this.
const CODE_BOTTOM: u32 = CODE_TOP >> SYMBOL_BITS;
const SYMBOL_MAX: u32 = (1 << SYMBOL_BITS) - 1;

#[derive(Debug, Clone)]
pub struct RangeDecoder<'a> {
    data: &'a [u8],
    offset: usize,
    range: u32,
    /// Distance from the top of the current interval to the coded value, as RFC 6716 keeps it.
    value: u32,
    /// The unused low bits of the last byte read.
    remainder: u32,
    /// Bits taken from the stream so far, with the offset that makes `tell` exact.
    bits_total: u32,
}

impl<'a> RangeDecoder<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        let mut decoder = Self {
            data,
            offset: 0,
            range: 1 << CODE_EXTRA,
            value: 0,
            remainder: 0,
            bits_total: CODE_BITS + 1 - ((CODE_BITS - CODE_EXTRA) / SYMBOL_BITS) * SYMBOL_BITS,
        };
        decoder.remainder = decoder.next_byte();
        decoder.value = decoder.range - 1 - (decoder.remainder >> (SYMBOL_BITS - CODE_EXTRA));
        decoder.normalize();
        decoder
    }

    #[inline(always)]
    fn next_byte(&mut self) -> u32 {
        match self.data.get(self.offset) {
            Some(&byte) => {
                self.offset += 1;
                u32::from(byte)
            }
            None => 0,
        }
    }

    #[inline(always)]
    fn normalize(&mut self) {
        while self.range <= CODE_BOTTOM {
            self.bits_total += SYMBOL_BITS;
            self.range <<= SYMBOL_BITS;
            let previous = self.remainder;
            self.remainder = self.next_byte();
            let symbol = ((previous << SYMBOL_BITS) | self.remainder) >> (SYMBOL_BITS - CODE_EXTRA);
            self.value =
                ((self.value << SYMBOL_BITS).wrapping_add(SYMBOL_MAX & !symbol)) & (CODE_TOP - 1);
        }
    }

    /// Decodes one symbol of the distribution whose inverse CDF (in 1/256) is `icdf`: entry k
    /// is 256 minus the cumulative frequency of symbols 0..=k. A table ends with 0; a table
    /// that does not is treated as if it did.
    #[inline]
    pub fn decode_icdf(&mut self, icdf: &[u8]) -> usize {
        let scale = self.range >> 8;
        let mut upper = self.range;
        let mut symbol = 0;
        let mut lower = 0;
        for (k, &entry) in icdf.iter().enumerate() {
            symbol = k;
            lower = scale * u32::from(entry);
            if self.value >= lower {
                break;
            }
            upper = lower;
            lower = 0;
            symbol = k + 1;
        }
        self.value = self.value.wrapping_sub(lower);
        self.range = upper.wrapping_sub(lower);
        self.normalize();
        symbol
    }

    /// [`RangeDecoder::decode_icdf`] for a decreasing table that ends with 0, without a
    /// branch on the data: the symbol is the number of entries whose interval lies above
    /// the value. Beside a decoder that keeps the branch predictor busy with its own work,
    /// this beats the search, whose exit is mispredicted most of the time. It pays for short
    /// tables only: every entry is compared.
    #[inline(always)]
    pub fn decode_icdf_counted<const N: usize>(&mut self, icdf: &[u8; N]) -> usize {
        let scale = self.range >> 8;
        let value = self.value;
        let symbol: usize = icdf
            .iter()
            .map(|&entry| usize::from(value < scale * u32::from(entry)))
            .sum();
        let lower = icdf
            .get(symbol)
            .map_or(0, |&entry| scale * u32::from(entry));
        let upper = match symbol.checked_sub(1).and_then(|k| icdf.get(k)) {
            Some(&entry) => scale * u32::from(entry),
            None => self.range,
        };
        self.value = value.wrapping_sub(lower);
        self.range = upper.wrapping_sub(lower);
        self.normalize();
        symbol
    }

    /// Decodes one bit whose probability of being 1 is 2^-`log_p`.
    pub fn decode_bit_logp(&mut self, log_p: u32) -> bool {
        let threshold = self.range >> log_p;
        let one = self.value < threshold;
        if one {
            self.range = threshold;
        } else {
            self.value -= threshold;
            self.range -= threshold;
        }
        self.normalize();
        one
    }

    /// Whole bits used so far, rounded up (RFC 6716 4.1.6's `ec_tell`).
    pub fn tell(&self) -> u32 {
        self.bits_total - (u32::BITS - self.range.leading_zeros())
    }

    /// The current range: after the last symbol of a frame this is the value libopus
    /// reports as its final range (`OPUS_GET_FINAL_RANGE`), a check of bit-exact decoding.
    pub fn range(&self) -> u32 {
        self.range
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal range encoder (RFC 6716 4.1's counterpart, written from the decoder's
    /// definition) so that the tests know which symbols a byte string carries.
    struct Encoder {
        low: u32,
        range: u32,
        carry_byte: Option<u32>,
        carries: u32,
        bits_total: u32,
        out: Vec<u8>,
    }

    impl Encoder {
        fn new() -> Self {
            Self {
                low: 0,
                range: CODE_TOP,
                carry_byte: None,
                carries: 0,
                bits_total: CODE_BITS + 1,
                out: Vec::new(),
            }
        }

        fn carry_out(&mut self, c: u32) {
            if c == SYMBOL_MAX {
                self.carries += 1;
                return;
            }
            let carry = c >> SYMBOL_BITS;
            if let Some(byte) = self.carry_byte {
                self.out.push((byte + carry) as u8);
            }
            for _ in 0..self.carries {
                self.out.push((SYMBOL_MAX + carry) as u8);
            }
            self.carries = 0;
            self.carry_byte = Some(c & SYMBOL_MAX);
        }

        fn normalize(&mut self) {
            let shift = CODE_BITS - SYMBOL_BITS - 1;
            while self.range <= CODE_BOTTOM {
                self.carry_out(self.low >> shift);
                self.low = (self.low << SYMBOL_BITS) & (CODE_TOP - 1);
                self.range <<= SYMBOL_BITS;
                self.bits_total += SYMBOL_BITS;
            }
        }

        fn encode_icdf(&mut self, symbol: usize, icdf: &[u8]) {
            let r = self.range >> 8;
            if symbol > 0 {
                self.low += self.range - r * u32::from(icdf[symbol - 1]);
                self.range = r * u32::from(icdf[symbol - 1] - icdf[symbol]);
            } else {
                self.range -= r * u32::from(icdf[symbol]);
            }
            self.normalize();
        }

        fn encode_bit_logp(&mut self, bit: bool, log_p: u32) {
            let s = self.range >> log_p;
            if bit {
                self.low += self.range - s;
                self.range = s;
            } else {
                self.range -= s;
            }
            self.normalize();
        }

        /// An Opus frame is as long as the encoder's `tell` in whole bytes; the bytes the
        /// flush leaves out are zeros.
        fn finish(mut self) -> Vec<u8> {
            let tell = self.bits_total - (u32::BITS - self.range.leading_zeros());
            // Flush enough bits of `low` that any continuation decodes the same symbols.
            let shift = CODE_BITS - SYMBOL_BITS - 1;
            let mut bits = CODE_BITS - (u32::BITS - self.range.leading_zeros());
            let mut mask = (CODE_TOP - 1) >> bits;
            let mut end = (self.low + mask) & !mask;
            if (end | mask) >= self.low + self.range {
                bits += 1;
                mask >>= 1;
                end = (self.low + mask) & !mask;
            }
            while bits > 0 {
                self.carry_out(end >> shift);
                end = (end << SYMBOL_BITS) & (CODE_TOP - 1);
                bits = bits.saturating_sub(SYMBOL_BITS);
            }
            if self.carry_byte.is_some() || self.carries > 0 {
                self.carry_out(0);
            }
            let length = (tell as usize).div_ceil(8).max(self.out.len());
            self.out.resize(length, 0);
            self.out
        }
    }

    const SKEWED: [u8; 4] = [200, 120, 7, 0];
    const UNIFORM8: [u8; 8] = [224, 192, 160, 128, 96, 64, 32, 0];

    #[derive(Debug, Clone, Copy)]
    enum Symbol {
        Icdf(usize, &'static [u8]),
        Bit(bool, u32),
    }

    fn round_trip(symbols: &[Symbol]) {
        let mut encoder = Encoder::new();
        for &s in symbols {
            match s {
                Symbol::Icdf(v, table) => encoder.encode_icdf(v, table),
                Symbol::Bit(b, log_p) => encoder.encode_bit_logp(b, log_p),
            }
        }
        let bytes = encoder.finish();
        let mut decoder = RangeDecoder::new(&bytes);
        for (i, &s) in symbols.iter().enumerate() {
            match s {
                Symbol::Icdf(v, table) => assert_eq!(decoder.decode_icdf(table), v, "symbol {i}"),
                Symbol::Bit(b, log_p) => assert_eq!(decoder.decode_bit_logp(log_p), b, "bit {i}"),
            }
        }
        assert!(decoder.tell() <= 8 * bytes.len() as u32);
    }

    #[test]
    fn empty_input_decodes_the_most_likely_symbols() {
        // All-zero input: the value sits at the top of every interval, i.e. symbol 0, and
        // the no-bit of a log-probability bit. One byte's worth is used up front.
        let mut decoder = RangeDecoder::new(&[]);
        assert_eq!(decoder.tell(), 1);
        assert_eq!(decoder.decode_icdf(&SKEWED), 0);
        assert!(!decoder.decode_bit_logp(1));
        assert_eq!(decoder.decode_icdf(&UNIFORM8), 0);
    }

    #[test]
    fn all_ones_input_decodes_the_last_symbols() {
        // 0xFF bytes: the value sits at the bottom of every interval.
        let bytes = [0xFFu8; 8];
        let mut decoder = RangeDecoder::new(&bytes);
        assert!(decoder.decode_bit_logp(1));
        assert_eq!(decoder.decode_icdf(&SKEWED), 3);
        assert_eq!(decoder.decode_icdf(&UNIFORM8), 7);
    }

    #[test]
    fn a_hand_made_byte_decodes_as_the_rfc_defines() {
        // RFC 6716 4.1.1: the first byte b0 = 0x80 gives val = 127 - (b0 >> 1) = 63 of a
        // range of 128; three renormalisations (4.1.2.1) each shift in 255 minus the next
        // input bits (zeros past the end), so val = 63 << 24 | 0xFF_FFFF = 2^30 - 1 of a
        // range of 2^31, with one bit used.
        let mut decoder = RangeDecoder::new(&[0x80]);
        assert_eq!(decoder.range(), 1 << 31);
        assert_eq!(decoder.value, 0x3FFF_FFFF);
        assert_eq!(decoder.tell(), 1);
        // 4.1.3.2: a bit with probability 1/2 is 1 when val < range >> 1.
        assert!(decoder.decode_bit_logp(1));
        // Now range 2^30, val unchanged; 4.1.3.3: the symbol is the first k with
        // val >= (range >> 8) * icdf[k], and 2^30 - 1 >= 2^22 * 224 already.
        assert_eq!(decoder.decode_icdf(&UNIFORM8), 0);
    }

    #[test]
    fn symbols_round_trip_through_the_reference_encoder_definition() {
        let mut symbols = Vec::new();
        let mut state = 0x1234_5678u32;
        for _ in 0..2000 {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let pick = state >> 24;
            symbols.push(match pick % 3 {
                0 => Symbol::Icdf((pick as usize / 3) % 4, &SKEWED),
                1 => Symbol::Icdf((pick as usize / 3) % 8, &UNIFORM8),
                _ => Symbol::Bit(pick & 8 != 0, 1 + pick % 12),
            });
        }
        round_trip(&symbols);
        round_trip(&[Symbol::Icdf(3, &SKEWED); 300]);
        round_trip(&[Symbol::Bit(true, 12); 50]);
    }

    #[test]
    fn counting_decodes_as_searching_does() {
        const RESIDUAL: [u8; 9] = [255, 248, 224, 171, 97, 30, 4, 1, 0];
        const BINARY: [u8; 2] = [120, 0];
        let mut state = 0x0BAD_5EEDu32;
        for _ in 0..300 {
            let bytes: Vec<u8> = (0..24)
                .map(|_| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (state >> 24) as u8
                })
                .collect();
            let mut searching = RangeDecoder::new(&bytes);
            let mut counting = searching.clone();
            for i in 0..60 {
                let (searched, counted) = match i % 4 {
                    0 => (
                        searching.decode_icdf(&SKEWED),
                        counting.decode_icdf_counted(&SKEWED),
                    ),
                    1 => (
                        searching.decode_icdf(&UNIFORM8),
                        counting.decode_icdf_counted(&UNIFORM8),
                    ),
                    2 => (
                        searching.decode_icdf(&RESIDUAL),
                        counting.decode_icdf_counted(&RESIDUAL),
                    ),
                    _ => (
                        searching.decode_icdf(&BINARY),
                        counting.decode_icdf_counted(&BINARY),
                    ),
                };
                assert_eq!(searched, counted, "symbol {i} of {bytes:?}");
                assert_eq!(
                    (searching.range, searching.value, searching.tell()),
                    (counting.range, counting.value, counting.tell())
                );
            }
        }
        // Values on and beside each interval's edge, where `<` and `<=` part.
        let start = RangeDecoder::new(&[0x5A, 0xC3, 0x99, 0x17]);
        for &entry in &RESIDUAL {
            let edge = (start.range >> 8) * u32::from(entry);
            for value in [edge.saturating_sub(1), edge, edge + 1] {
                let mut searching = start.clone();
                searching.value = value.min(start.range - 1);
                let mut counting = searching.clone();
                assert_eq!(
                    searching.decode_icdf(&RESIDUAL),
                    counting.decode_icdf_counted(&RESIDUAL),
                    "value {value}"
                );
                assert_eq!(
                    (searching.range, searching.value),
                    (counting.range, counting.value)
                );
            }
        }
    }

    #[test]
    fn tell_counts_the_bits_of_the_symbols() {
        // 64 uniform symbols of 3 bits are 192 bits; tell rounds up and includes the one bit
        // the decoder reserves at the start.
        let symbols = [Symbol::Icdf(5, &UNIFORM8); 64];
        let mut encoder = Encoder::new();
        for &s in &symbols {
            if let Symbol::Icdf(v, t) = s {
                encoder.encode_icdf(v, t);
            }
        }
        let bytes = encoder.finish();
        let mut decoder = RangeDecoder::new(&bytes);
        for _ in 0..64 {
            decoder.decode_icdf(&UNIFORM8);
        }
        assert_eq!(decoder.tell(), 193);
        assert_eq!(bytes.len(), 25);
    }
}

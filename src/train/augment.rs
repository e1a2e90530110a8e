//! Random draws for training (a small seeded generator, so runs repeat) and the vocal-tract
//! warp that makes one voice stand in for others.

use crate::vocab::{FrameFeatures, LSP_COUNT};

/// xorshift64*: small, fast and reproducible.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        // One splitmix64 step: a bijection, so different seeds start from different states.
        let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        Self(z.max(1))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    pub fn shuffle<T>(&mut self, items: &mut [T]) {
        for i in (1..items.len()).rev() {
            let j = (self.next_u64() % (i as u64 + 1)) as usize;
            items.swap(i, j);
        }
    }
}

/// Scales the LSPs of `frames` (one voice) by one random factor in `[1 - warp, 1 + warp]`,
/// kept increasing and inside (0, pi): the formants of a longer or shorter vocal tract.
pub fn warp_frames(frames: &mut [FrameFeatures], warp: f32, rng: &mut Rng) {
    const TOP: f32 = std::f32::consts::PI - 0.01;
    let factor = 1.0 + warp * (2.0 * rng.next_f32() - 1.0);
    for frame in frames {
        for (i, lsp) in frame.lsp.iter_mut().enumerate() {
            let ceiling = TOP - 0.01 * (LSP_COUNT - 1 - i) as f32;
            *lsp = (*lsp * factor).min(ceiling);
        }
    }
}

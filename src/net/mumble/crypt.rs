//! Mumble's UDP encryption: OCB2 with AES-128 (Rogaway's OCB2, as Mumble's CryptState uses it),
//! a 4-byte header (the low byte of the nonce, then 3 bytes of the tag), and the nonce tracking
//! that tolerates loss and reordering and refuses replays.
//!
//! OCB2 is broken as an authenticated cipher (Inoue and Minematsu, 2019: the XEX* attack on
//! its last two blocks). Servers since 1.3.1 guard against it, and so does this: the sender
//! never encrypts a second-to-last block whose first 15 bytes are zero as it is (it flips the
//! lowest bit of its first byte, which the receiver then hears, harmlessly), and the receiver
//! refuses a packet whose decrypted last block (padded with the pad) equals the offset its
//! forgery would need.

use aes::Aes128;
use aes::cipher::{BlockCipherDecrypt, BlockCipherEncrypt, KeyInit};

pub const BLOCK: usize = 16;
/// Bytes before the ciphertext: the nonce's low byte and 3 bytes of tag.
pub const HEADER: usize = 4;

type Block = [u8; BLOCK];

/// Doubling in GF(2^128) (OCB2's "times 2" of the offset).
fn times2(block: &mut Block) {
    let v = u128::from_be_bytes(*block);
    let carry = (v >> 127) as u8;
    *block = ((v << 1) ^ u128::from(carry * 0x87)).to_be_bytes();
}

fn times3(block: &mut Block) {
    let mut doubled = *block;
    times2(&mut doubled);
    xor_into(block, &doubled);
}

fn xor_into(dst: &mut Block, other: &Block) {
    for (d, o) in dst.iter_mut().zip(other) {
        *d ^= o;
    }
}

fn encrypt_block(cipher: &Aes128, block: &Block) -> Block {
    let mut b = (*block).into();
    cipher.encrypt_block(&mut b);
    b.into()
}

fn decrypt_block(cipher: &Aes128, block: &Block) -> Block {
    let mut b = (*block).into();
    cipher.decrypt_block(&mut b);
    b.into()
}

/// The pad of the last (partial) block of `len` bytes at offset `delta`.
fn last_pad(cipher: &Aes128, delta: &Block, len: usize) -> Block {
    let mut length = [0u8; BLOCK];
    length[8..].copy_from_slice(&((len as u64) * 8).to_be_bytes());
    xor_into(&mut length, delta);
    encrypt_block(cipher, &length)
}

/// OCB2 encryption of `plain` under `nonce`: the ciphertext (as long as `plain`) and the full
/// tag. A second-to-last block that the XEX* attack would need gets its lowest bit flipped.
pub fn ocb_encrypt(cipher: &Aes128, plain: &[u8], nonce: &Block) -> (Vec<u8>, Block) {
    ocb_encrypt_guarded(cipher, plain, nonce, true)
}

fn ocb_encrypt_guarded(
    cipher: &Aes128,
    plain: &[u8],
    nonce: &Block,
    guard: bool,
) -> (Vec<u8>, Block) {
    let mut out = Vec::with_capacity(plain.len());
    let mut delta = encrypt_block(cipher, nonce);
    let mut checksum = [0u8; BLOCK];
    let mut rest = plain;
    while rest.len() > BLOCK {
        let mut block: Block = [0; BLOCK];
        block.copy_from_slice(&rest[..BLOCK]);
        let second_to_last = rest.len() - BLOCK <= BLOCK;
        if guard && second_to_last && block[..BLOCK - 1].iter().all(|&b| b == 0) {
            block[0] ^= 1;
        }
        times2(&mut delta);
        let mut t = block;
        xor_into(&mut t, &delta);
        let mut c = encrypt_block(cipher, &t);
        xor_into(&mut c, &delta);
        out.extend_from_slice(&c);
        xor_into(&mut checksum, &block);
        rest = &rest[BLOCK..];
    }
    times2(&mut delta);
    let pad = last_pad(cipher, &delta, rest.len());
    let mut last = pad;
    last[..rest.len()].copy_from_slice(rest);
    xor_into(&mut checksum, &last);
    for (i, b) in rest.iter().enumerate() {
        out.push(b ^ pad[i]);
    }
    times3(&mut delta);
    xor_into(&mut checksum, &delta);
    (out, encrypt_block(cipher, &checksum))
}

/// OCB2 decryption: the plaintext and full tag, or `None` for a packet shaped like the XEX*
/// forgery.
pub fn ocb_decrypt(cipher: &Aes128, encrypted: &[u8], nonce: &Block) -> Option<(Vec<u8>, Block)> {
    let (plain, tag, forged) = ocb_decrypt_checked(cipher, encrypted, nonce);
    (!forged).then_some((plain, tag))
}

/// The plaintext, the tag, and whether the packet has the XEX* forgery's shape.
fn ocb_decrypt_checked(cipher: &Aes128, encrypted: &[u8], nonce: &Block) -> (Vec<u8>, Block, bool) {
    let mut out = Vec::with_capacity(encrypted.len());
    let mut delta = encrypt_block(cipher, nonce);
    let mut checksum = [0u8; BLOCK];
    let mut rest = encrypted;
    while rest.len() > BLOCK {
        let mut block: Block = [0; BLOCK];
        block.copy_from_slice(&rest[..BLOCK]);
        times2(&mut delta);
        xor_into(&mut block, &delta);
        let mut p = decrypt_block(cipher, &block);
        xor_into(&mut p, &delta);
        out.extend_from_slice(&p);
        xor_into(&mut checksum, &p);
        rest = &rest[BLOCK..];
    }
    times2(&mut delta);
    let pad = last_pad(cipher, &delta, rest.len());
    let mut last = [0u8; BLOCK];
    last[..rest.len()].copy_from_slice(rest);
    xor_into(&mut last, &pad);
    xor_into(&mut checksum, &last);
    out.extend_from_slice(&last[..rest.len()]);
    let forged = last[..BLOCK - 1] == delta[..BLOCK - 1];
    times3(&mut delta);
    xor_into(&mut checksum, &delta);
    (out, encrypt_block(cipher, &checksum), forged)
}

/// Why a datagram did not decrypt.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecryptError {
    #[error("shorter than its 4-byte header")]
    Short,
    #[error("a repeated or too old nonce")]
    Replay,
    #[error("its tag does not match")]
    Tag,
}

/// Counters of the receive direction, as Mumble's Ping reports them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CryptStats {
    pub good: u32,
    pub late: u32,
    pub lost: u32,
    pub resync: u32,
}

/// One UDP association's keys and nonces: ours for sending (encrypt), the server's for
/// receiving (decrypt).
#[derive(Clone)]
pub struct CryptState {
    cipher: Aes128,
    pub encrypt_iv: Block,
    pub decrypt_iv: Block,
    /// For each low nonce byte, the second byte of the last nonce accepted with it (replays).
    history: [u8; 256],
    pub stats: CryptStats,
}

impl std::fmt::Debug for CryptState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CryptState")
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

/// Increments a little-endian nonce from byte `from` on.
fn increment(iv: &mut Block, from: usize) {
    for b in &mut iv[from..] {
        *b = b.wrapping_add(1);
        if *b != 0 {
            break;
        }
    }
}

fn decrement(iv: &mut Block, from: usize) {
    for b in &mut iv[from..] {
        let was = *b;
        *b = b.wrapping_sub(1);
        if was != 0 {
            break;
        }
    }
}

impl CryptState {
    pub fn new(key: &Block, encrypt_iv: Block, decrypt_iv: Block) -> Self {
        Self {
            cipher: Aes128::new(&(*key).into()),
            encrypt_iv,
            decrypt_iv,
            history: [0; 256],
            stats: CryptStats::default(),
        }
    }

    /// Encrypts one datagram with the next nonce.
    pub fn encrypt(&mut self, plain: &[u8]) -> Vec<u8> {
        increment(&mut self.encrypt_iv, 0);
        let (body, tag) = ocb_encrypt(&self.cipher, plain, &self.encrypt_iv);
        let mut out = Vec::with_capacity(HEADER + body.len());
        out.push(self.encrypt_iv[0]);
        out.extend_from_slice(&tag[..3]);
        out.extend_from_slice(&body);
        out
    }

    /// Decrypts one datagram, moving the receive nonce on (a late packet within 30 leaves it).
    pub fn decrypt(&mut self, packet: &[u8]) -> Result<Vec<u8>, DecryptError> {
        if packet.len() < HEADER {
            return Err(DecryptError::Short);
        }
        let saved = self.decrypt_iv;
        let byte = packet[0];
        let current = self.decrypt_iv[0];
        let mut restore = false;
        let (mut late, mut lost) = (0u32, 0i64);
        if current.wrapping_add(1) == byte {
            if byte < current {
                increment(&mut self.decrypt_iv, 1);
            }
            self.decrypt_iv[0] = byte;
        } else {
            let mut diff = i32::from(byte) - i32::from(current);
            if diff > 128 {
                diff -= 256;
            } else if diff < -128 {
                diff += 256;
            }
            if byte < current && (-30..0).contains(&diff) {
                late = 1;
                lost = -1;
                self.decrypt_iv[0] = byte;
                restore = true;
            } else if byte > current && (-30..0).contains(&diff) {
                late = 1;
                lost = -1;
                self.decrypt_iv[0] = byte;
                decrement(&mut self.decrypt_iv, 1);
                restore = true;
            } else if byte > current && diff > 0 {
                lost = i64::from(byte) - i64::from(current) - 1;
                self.decrypt_iv[0] = byte;
            } else if byte < current && diff > 0 {
                lost = 256 - i64::from(current) + i64::from(byte) - 1;
                self.decrypt_iv[0] = byte;
                increment(&mut self.decrypt_iv, 1);
            } else {
                return Err(DecryptError::Replay);
            }
            if self.history[usize::from(self.decrypt_iv[0])] == self.decrypt_iv[1] {
                self.decrypt_iv = saved;
                return Err(DecryptError::Replay);
            }
        }
        let decrypted = ocb_decrypt(&self.cipher, &packet[HEADER..], &self.decrypt_iv);
        let Some((plain, tag)) = decrypted.filter(|(_, tag)| tag[..3] == packet[1..HEADER]) else {
            self.decrypt_iv = saved;
            return Err(DecryptError::Tag);
        };
        let _ = tag;
        self.history[usize::from(self.decrypt_iv[0])] = self.decrypt_iv[1];
        if restore {
            self.decrypt_iv = saved;
        }
        self.stats.good += 1;
        self.stats.late += late;
        self.stats.lost = self.stats.lost.saturating_add_signed(lost as i32);
        Ok(plain)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn seq16() -> Block {
        std::array::from_fn(|i| i as u8)
    }

    /// draft-krovetz-ocb-00's vectors (key and nonce 00..0f), as Mumble's TestCrypt uses them.
    #[test]
    fn ocb2_matches_the_draft_vectors() {
        let cipher = Aes128::new(&seq16().into());
        let (empty, tag) = ocb_encrypt(&cipher, &[], &seq16());
        assert!(empty.is_empty());
        assert_eq!(
            tag,
            [
                0xBF, 0x31, 0x08, 0x13, 0x07, 0x73, 0xAD, 0x5E, 0xC7, 0x0E, 0xC6, 0x9E, 0x78, 0x75,
                0xA7, 0xB0
            ]
        );
        let plain: Vec<u8> = (0..40).collect();
        let (crypted, tag) = ocb_encrypt(&cipher, &plain, &seq16());
        assert_eq!(
            tag,
            [
                0x9D, 0xB0, 0xCD, 0xF8, 0x80, 0xF7, 0x3E, 0x3E, 0x10, 0xD4, 0xEB, 0x32, 0x17, 0x76,
                0x66, 0x88
            ]
        );
        assert_eq!(
            crypted,
            [
                0xF7, 0x5D, 0x6B, 0xC8, 0xB4, 0xDC, 0x8D, 0x66, 0xB8, 0x36, 0xA2, 0xB0, 0x8B, 0x32,
                0xA6, 0x36, 0x9F, 0x1C, 0xD3, 0xC5, 0x22, 0x8D, 0x79, 0xFD, 0x6C, 0x26, 0x7F, 0x5F,
                0x6A, 0xA7, 0xB2, 0x31, 0xC7, 0xDF, 0xB9, 0xD5, 0x99, 0x51, 0xAE, 0x9C
            ]
        );
        let (back, tag2) = ocb_decrypt(&cipher, &crypted, &seq16()).unwrap();
        assert_eq!(back, plain);
        assert_eq!(tag, tag2);
    }

    fn pair() -> (CryptState, CryptState) {
        let key = seq16();
        let a = [0x55; 16];
        let b = [0xAA; 16];
        (CryptState::new(&key, a, b), CryptState::new(&key, b, a))
    }

    #[test]
    fn every_length_round_trips_and_a_flipped_bit_is_refused() {
        let (mut tx, mut rx) = pair();
        for len in 0..100usize {
            let plain: Vec<u8> = (0..len).map(|i| (i * 7 + 1) as u8).collect();
            let packet = tx.encrypt(&plain);
            let mut bad = packet.clone();
            if let Some(b) = bad.get_mut(HEADER + len / 2) {
                *b ^= 0x10;
                assert_eq!(rx.clone().decrypt(&bad), Err(DecryptError::Tag));
            }
            assert_eq!(rx.decrypt(&packet).unwrap(), plain);
        }
    }

    #[test]
    fn replays_are_refused_and_late_packets_accepted() {
        let (mut tx, mut rx) = pair();
        let first = tx.encrypt(b"one");
        let second = tx.encrypt(b"two");
        let third = tx.encrypt(b"three");
        assert_eq!(rx.decrypt(&first).unwrap(), b"one");
        assert_eq!(rx.decrypt(&third).unwrap(), b"three");
        assert_eq!(rx.stats.lost, 1);
        assert_eq!(rx.decrypt(&second).unwrap(), b"two");
        assert_eq!(rx.stats.late, 1);
        assert_eq!(rx.decrypt(&second), Err(DecryptError::Replay));
        assert_eq!(rx.decrypt(&third), Err(DecryptError::Replay));
    }

    #[test]
    fn the_nonce_wraps_and_loses_sync_past_a_full_round() {
        let (mut tx, mut rx) = pair();
        for _ in 0..300 {
            let p = tx.encrypt(b"x");
            assert!(rx.decrypt(&p).is_ok());
        }
        for _ in 0..257 {
            tx.encrypt(b"x");
        }
        assert!(rx.decrypt(&tx.encrypt(b"x")).is_err());
        // Resynchronised (CryptSetup with a nonce), it is heard again.
        rx.decrypt_iv = tx.encrypt_iv;
        assert!(rx.decrypt(&tx.encrypt(b"x")).is_ok());
    }

    /// The XEX* forgery (eprint 2019/311, section 9), as Mumble's TestCrypt stages it: a
    /// first block that encodes the length of a block, an arbitrary second one, the first
    /// ciphertext block cut off and its length byte flipped. Against an unguarded sender the
    /// forged tag is right and only the receiver's check refuses it; a guarded sender never
    /// hands out the block the forgery needs.
    #[test]
    fn the_xex_star_attack_is_countered() {
        let cipher = Aes128::new(&seq16().into());
        let nonce = [0x42; 16];
        let mut critical = [0u8; 2 * BLOCK];
        critical[BLOCK - 1] = (BLOCK * 8) as u8;
        critical[BLOCK..].fill(42);
        let forge = |crypted: &[u8]| {
            let mut forged = [0u8; BLOCK];
            forged.copy_from_slice(&crypted[..BLOCK]);
            forged[BLOCK - 1] ^= (BLOCK * 8) as u8;
            let tag: Block = std::array::from_fn(|i| critical[BLOCK + i] ^ crypted[BLOCK + i]);
            (forged, tag)
        };

        let (crypted, _) = ocb_encrypt_guarded(&cipher, &critical, &nonce, false);
        let (forged, forged_tag) = forge(&crypted);
        let (_, tag, shaped) = ocb_decrypt_checked(&cipher, &forged, &nonce);
        assert_eq!(tag, forged_tag, "the forgery's tag verifies");
        assert!(shaped);
        assert!(ocb_decrypt(&cipher, &forged, &nonce).is_none());

        let (crypted, _) = ocb_encrypt(&cipher, &critical, &nonce);
        let (back, _) = ocb_decrypt(&cipher, &crypted, &nonce).unwrap();
        assert_eq!(
            back[0], 1,
            "the sender flipped the critical block's lowest bit"
        );
        assert_eq!(&back[1..], &critical[1..]);
        let (forged, forged_tag) = forge(&crypted);
        let accepted = ocb_decrypt(&cipher, &forged, &nonce).is_some_and(|(_, t)| t == forged_tag);
        assert!(!accepted);
    }

    proptest! {
        #[test]
        fn any_datagram_decrypts_or_errs(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let (_, mut rx) = pair();
            let _ = rx.decrypt(&bytes);
        }

        #[test]
        fn round_trips(plain in proptest::collection::vec(any::<u8>(), 0..300)) {
            let (mut tx, mut rx) = pair();
            let packet = tx.encrypt(&plain);
            let back = rx.decrypt(&packet).unwrap();
            prop_assert_eq!(back.len(), plain.len());
        }
    }
}

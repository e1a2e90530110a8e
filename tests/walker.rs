//! The pure-Rust bitstream walker against the reference libspeex (speex-sys): same frames,
//! same modes, and LSPs bit-identical to the decoder's own `old_qlsp` after every frame.

#![allow(unsafe_code)]

use std::ffi::{c_char, c_int, c_void};
use std::mem::offset_of;
use std::path::{Path, PathBuf};
use std::ptr;
use std::sync::OnceLock;

use lipcall::codec::speex::bitstream::{BitstreamError, Frame, Lsp, Walker};
use proptest::prelude::*;
use proptest::test_runner::FileFailurePersistence;
use speex_sys::{
    SPEEX_GET_FRAME_SIZE, SPEEX_GET_MODE, SPEEX_SET_DTX, SPEEX_SET_MODE, SPEEX_SET_QUALITY,
    SPEEX_SET_VAD, SPEEX_SET_VBR, SPEEX_SET_VBR_QUALITY, SpeexBits, SpeexMode, speex_bits_destroy,
    speex_bits_init, speex_bits_pack, speex_bits_read_from, speex_bits_reset, speex_bits_write,
    speex_decode_int, speex_decoder_ctl, speex_decoder_destroy, speex_decoder_init,
    speex_encode_int, speex_encoder_ctl, speex_encoder_destroy, speex_encoder_init, speex_nb_mode,
    speex_uwb_mode, speex_wb_mode,
};

/// Modes the narrowband encoder uses at qualities 0..=10 (modes.c).
const QUALITY_MODES: [u8; 11] = [1, 8, 2, 3, 3, 4, 4, 5, 5, 6, 7];

const NB_PITCH_END: usize = 144;
const NB_DEC_BUFFER: usize = 160 + 2 * NB_PITCH_END + 40 + 12;
/// Where nb_decode points `exc` inside `excBuf`; used to check the mirror's layout.
const EXC_OFFSET: usize = 2 * NB_PITCH_END + 40 + 6;

/// The leading fields of libspeex's narrowband `DecState` (nb_celp.h), as built by speex-sys:
/// FLOATING_POINT, neither VAR_ARRAYS nor USE_ALLOCA (so `stack` is a real field), up to and
/// including `old_qlsp`. The decoder state pointer is a `DecState *` because
/// `speex_decoder_init(&speex_nb_mode)` returns `nb_decoder_init`'s allocation.
#[repr(C)]
struct DecStateHead {
    mode: *const SpeexMode,
    first: c_int,
    count_lost: c_int,
    sampling_rate: i32,
    last_ol_gain: f32,
    stack: *mut c_char,
    exc_buf: [f32; NB_DEC_BUFFER],
    exc: *mut f32,
    old_qlsp: [f32; 10],
}

fn ctl_value(
    ctl: unsafe extern "C" fn(*mut c_void, c_int, *mut c_void) -> c_int,
    state: *mut c_void,
    request: i32,
    value: i32,
) -> i32 {
    let mut value = value;
    // SAFETY: every request used here reads or writes one spx_int32_t.
    let ret = unsafe { ctl(state, request, (&raw mut value).cast()) };
    assert_eq!(ret, 0, "ctl request {request}");
    value
}

struct Encoder {
    state: *mut c_void,
    bits: SpeexBits,
    frame_size: usize,
}

impl Encoder {
    fn new(mode: *const SpeexMode) -> Self {
        // SAFETY: plain libspeex initialisation; SpeexBits is plain data filled by init.
        unsafe {
            let state = speex_encoder_init(mode);
            assert!(!state.is_null());
            let mut bits = std::mem::zeroed::<SpeexBits>();
            speex_bits_init(&mut bits);
            let frame_size = ctl_value(speex_encoder_ctl, state, SPEEX_GET_FRAME_SIZE, 0);
            Self {
                state,
                bits,
                frame_size: frame_size as usize,
            }
        }
    }

    fn set(&mut self, request: i32, value: i32) {
        ctl_value(speex_encoder_ctl, self.state, request, value);
    }

    fn set_float(&mut self, request: i32, value: f32) {
        let mut value = value;
        // SAFETY: the request reads one float.
        let ret = unsafe { speex_encoder_ctl(self.state, request, (&raw mut value).cast()) };
        assert_eq!(ret, 0);
    }

    fn encode(&mut self, pcm: &[i16]) {
        let mut frame = pcm.to_vec();
        frame.resize(self.frame_size, 0);
        // SAFETY: `frame` holds frame_size samples, as the encoder reads.
        unsafe { speex_encode_int(self.state, frame.as_mut_ptr(), &mut self.bits) };
    }

    /// Appends raw bits (in chunks of at most 24) to the stream being built.
    fn pack(&mut self, value: u64, count: u32) {
        let mut left = count;
        while left > 0 {
            let n = left.min(24);
            let chunk = (value >> (left - n)) & ((1 << n) - 1);
            // SAFETY: n <= 24, so the chunk fits a positive c_int.
            unsafe { speex_bits_pack(&mut self.bits, chunk as c_int, n as c_int) };
            left -= n;
        }
    }

    /// Ends the packet the way applications do: speex_bits_write pads with a terminator.
    fn take_packet(&mut self) -> Vec<u8> {
        let mut out = vec![0u8; 4000];
        // SAFETY: out has room for max_len bytes.
        let n = unsafe { speex_bits_write(&mut self.bits, out.as_mut_ptr().cast(), 4000) };
        unsafe { speex_bits_reset(&mut self.bits) };
        out.truncate(n as usize);
        out
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        // SAFETY: both were created in new and are destroyed once.
        unsafe {
            speex_bits_destroy(&mut self.bits);
            speex_encoder_destroy(self.state);
        }
    }
}

/// What the reference decoder did with one packet.
#[derive(Debug)]
struct Decoded {
    /// (mode, old_qlsp) after each decoded frame.
    frames: Vec<(u8, Lsp)>,
    /// The return value that ended the packet: -1 end of stream, -2 corrupt.
    end: i32,
}

struct Decoder {
    state: *mut c_void,
    bits: SpeexBits,
}

impl Decoder {
    fn new() -> Self {
        // SAFETY: plain libspeex initialisation.
        let decoder = unsafe {
            let state = speex_decoder_init(&raw const speex_nb_mode);
            assert!(!state.is_null());
            let mut bits = std::mem::zeroed::<SpeexBits>();
            speex_bits_init(&mut bits);
            Self { state, bits }
        };
        let head = decoder.head();
        assert!(ptr::eq(head.mode, &raw const speex_nb_mode));
        assert_eq!((head.first, head.count_lost), (1, 0));
        assert_eq!(head.sampling_rate, 8000);
        assert!(!head.stack.is_null());
        assert_eq!(head.old_qlsp, [0.0; 10], "calloc'd state");
        decoder
    }

    fn head(&self) -> &DecStateHead {
        // SAFETY: the state is a DecState (see DecStateHead), allocated and zeroed by
        // nb_decoder_init, and only read while no libspeex call runs.
        unsafe { &*self.state.cast::<DecStateHead>() }
    }

    fn old_qlsp(&self) -> Lsp {
        let head = self.head();
        // The layout check: nb_decode set `exc` to excBuf + EXC_OFFSET, as seen from C.
        let exc_buf = self.state as usize + offset_of!(DecStateHead, exc_buf);
        assert_eq!(
            head.exc as usize,
            exc_buf + EXC_OFFSET * size_of::<f32>(),
            "DecState mirror out of step"
        );
        head.old_qlsp
    }

    fn decode(&mut self, packet: &[u8]) -> Decoded {
        let mut out = [0i16; 160];
        let mut frames = Vec::new();
        // SAFETY: the packet slice is valid for its length; out holds a whole frame.
        unsafe {
            speex_bits_read_from(
                &mut self.bits,
                packet.as_ptr().cast(),
                packet.len() as c_int,
            )
        };
        loop {
            let ret = unsafe { speex_decode_int(self.state, &mut self.bits, out.as_mut_ptr()) };
            if ret != 0 {
                return Decoded { frames, end: ret };
            }
            let mode = ctl_value(speex_decoder_ctl, self.state, SPEEX_GET_MODE, -1);
            frames.push((mode as u8, self.old_qlsp()));
        }
    }

    /// A lost packet: the decoder conceals one frame.
    fn lose_frame(&mut self) {
        let mut out = [0i16; 160];
        // SAFETY: a null SpeexBits is the documented way to signal a lost frame.
        let ret = unsafe { speex_decode_int(self.state, ptr::null_mut(), out.as_mut_ptr()) };
        assert_eq!(ret, 0);
    }
}

impl Drop for Decoder {
    fn drop(&mut self) {
        // SAFETY: both were created in new and are destroyed once.
        unsafe {
            speex_bits_destroy(&mut self.bits);
            speex_decoder_destroy(self.state);
        }
    }
}

fn bits_of(lsp: &Lsp) -> [u32; 10] {
    lsp.map(f32::to_bits)
}

fn assert_ordered(lsp: &Lsp) {
    assert!(lsp[0] > 0.0 && lsp[9] < std::f32::consts::PI, "{lsp:?}");
    assert!(lsp.windows(2).all(|w| w[0] < w[1]), "{lsp:?}");
}

/// Walks `packet` and checks every frame against what the decoder did with it. Returns the
/// walker's frames (or its error and the frames before it).
fn check_packet(
    walker: &mut Walker,
    decoder: &mut Decoder,
    packet: &[u8],
) -> (Vec<Frame>, Option<BitstreamError>) {
    let decoded = decoder.decode(packet);
    let mut frames = Vec::new();
    let mut error = None;
    for result in walker.frames(packet) {
        match result {
            Ok(frame) => frames.push(frame),
            Err(e) => error = Some(e),
        }
    }
    let truncated = matches!(error, Some(BitstreamError::Truncated { .. }));
    if truncated {
        // Past the end the decoder reads zeros; it agrees only up to the truncation.
        assert!(decoded.frames.len() >= frames.len());
    } else {
        assert_eq!(
            decoded.frames.len(),
            frames.len(),
            "frame count, packet {packet:02x?}"
        );
        let expected_end = if error.is_some() { -2 } else { -1 };
        assert_eq!(decoded.end, expected_end, "{error:?}, packet {packet:02x?}");
    }
    for (frame, (mode, old_qlsp)) in frames.iter().zip(&decoded.frames) {
        assert_eq!(frame.mode(), *mode);
        let held = frame.lsp().copied().unwrap_or([0.0; 10]);
        assert_eq!(
            bits_of(&held),
            bits_of(old_qlsp),
            "{frame:?} vs {old_qlsp:?}"
        );
    }
    (frames, error)
}

fn timit_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/timit-sample")
}

/// A few TIMIT utterances at 16 kHz (empty if the corpus is not beside the repository).
fn timit_16k() -> Vec<Vec<i16>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(timit_dir())
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path().join("sa1.wav"))
        .filter(|p| p.exists())
        .collect();
    paths.sort();
    paths
        .iter()
        .take(3)
        .map(|p| {
            let mut reader = hound::WavReader::open(p).expect("TIMIT wav");
            reader
                .samples::<i16>()
                .map(|s| s.expect("sample"))
                .collect()
        })
        .collect()
}

/// A vowel-like test signal: a gliding glottal pulse train through three moving formant
/// resonators, with a little noise and two silent gaps.
fn synthetic(rate: f32, seconds: f32) -> Vec<i16> {
    let n = (rate * seconds) as usize;
    let mut seed = 12345u32;
    let mut noise = move || {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (seed >> 8) as f32 / (1 << 24) as f32 - 0.5
    };
    let mut phase = 0.0f32;
    let mut state = [[0.0f32; 2]; 3];
    (0..n)
        .map(|i| {
            let t = i as f32 / rate;
            let f0 = 110.0 + 60.0 * (t * 1.3).sin();
            phase += f0 / rate;
            let mut x = if phase >= 1.0 {
                phase -= 1.0;
                1.0
            } else {
                0.0
            } + 0.02 * noise();
            let formants = [
                500.0 + 300.0 * (t * 2.1).sin(),
                1500.0 + 700.0 * (t * 1.7).cos(),
                2500.0 + 300.0 * (t * 0.9).sin(),
            ];
            for (f, s) in formants.iter().zip(&mut state) {
                let r = 0.97f32;
                let w = 2.0 * std::f32::consts::PI * f / rate;
                let y = x + 2.0 * r * w.cos() * s[0] - r * r * s[1];
                s[1] = s[0];
                s[0] = y;
                x = y * (1.0 - r);
            }
            let gate = if (0.8..1.1).contains(&t) || (2.0..2.5).contains(&t) {
                0.0
            } else {
                1.0
            };
            (x * 60_000.0 * gate).clamp(-32_000.0, 32_000.0) as i16
        })
        .collect()
}

/// Crude 2:1 decimation: average pairs of samples.
fn halve(signal: &[i16]) -> Vec<i16> {
    signal
        .chunks(2)
        .map(|c| ((i32::from(c[0]) + i32::from(*c.last().unwrap())) / 2) as i16)
        .collect()
}

/// Crude 1:2 upsampling: repeat each sample.
fn double(signal: &[i16]) -> Vec<i16> {
    signal.iter().flat_map(|&s| [s, s]).collect()
}

/// Narrowband test signals: the synthetic one and, when present, real speech.
fn nb_signals() -> Vec<Vec<i16>> {
    let mut signals = vec![synthetic(8000.0, 3.0)];
    signals.extend(timit_16k().iter().map(|s| halve(s)));
    signals
}

/// Encodes `signal` into packets of 1, 2, 3, ... up to 5 frames, calling `before_frame`
/// before each frame so a test can change settings or insert bits.
fn encode_packets(
    encoder: &mut Encoder,
    signal: &[i16],
    mut before_frame: impl FnMut(&mut Encoder, usize),
) -> Vec<(usize, Vec<u8>)> {
    let mut packets = Vec::new();
    let frames: Vec<&[i16]> = signal.chunks(encoder.frame_size).collect();
    let mut next = 0;
    let mut per_packet = 1;
    while next < frames.len() {
        let count = per_packet.min(frames.len() - next);
        for i in 0..count {
            before_frame(encoder, next + i);
            encoder.encode(frames[next + i]);
        }
        packets.push((count, encoder.take_packet()));
        next += count;
        per_packet = per_packet % 5 + 1;
    }
    packets
}

#[test]
fn every_quality_matches_the_decoder_bit_for_bit() {
    for (s, signal) in nb_signals().iter().enumerate() {
        for (quality, &mode) in QUALITY_MODES.iter().enumerate() {
            let mut encoder = Encoder::new(&raw const speex_nb_mode);
            encoder.set(SPEEX_SET_QUALITY, quality as i32);
            let packets = encode_packets(&mut encoder, signal, |_, _| {});
            let mut walker = Walker::new();
            let mut decoder = Decoder::new();
            for (p, (count, packet)) in packets.iter().enumerate() {
                // Every seventh packet is lost: neither the walker nor old_qlsp move.
                if p % 7 == 6 {
                    let before = decoder.old_qlsp();
                    for _ in 0..*count {
                        decoder.lose_frame();
                    }
                    assert_eq!(bits_of(&before), bits_of(&decoder.old_qlsp()));
                    let held = walker.held_lsp().copied().unwrap_or([0.0; 10]);
                    assert_eq!(bits_of(&held), bits_of(&before));
                    continue;
                }
                let (frames, error) = check_packet(&mut walker, &mut decoder, packet);
                assert_eq!(error, None, "signal {s} quality {quality}");
                assert_eq!(frames.len(), *count, "signal {s} quality {quality}");
                for frame in &frames {
                    assert_eq!(frame.mode(), mode, "signal {s} quality {quality}");
                    assert_ordered(frame.lsp().unwrap());
                }
            }
        }
    }
}

#[test]
fn forced_modes_including_silence_match_the_decoder() {
    let schedule = [0u8, 0, 3, 0, 5, 1, 8, 2, 0, 4, 6, 7, 7, 1, 0];
    let signal = &nb_signals()[0];
    let mut encoder = Encoder::new(&raw const speex_nb_mode);
    let packets = encode_packets(&mut encoder, signal, |e, i| {
        e.set(SPEEX_SET_MODE, i32::from(schedule[i % schedule.len()]));
    });
    let mut walker = Walker::new();
    let mut decoder = Decoder::new();
    let mut modes = Vec::new();
    for (_, packet) in &packets {
        let (frames, error) = check_packet(&mut walker, &mut decoder, packet);
        assert_eq!(error, None);
        modes.extend(frames.iter().map(Frame::mode));
    }
    let expected: Vec<u8> = (0..modes.len())
        .map(|i| schedule[i % schedule.len()])
        .collect();
    assert_eq!(modes, expected);
    // The very first frames are silence: the decoder still holds its zeroed state.
    let first = Walker::new().walk_packet(&packets[0].1).unwrap();
    assert_eq!(first, [Frame::Silence { held_lsp: None }]);
}

#[test]
fn vbr_vad_and_dtx_streams_match_the_decoder() {
    let mut seen = [0usize; 9];
    for signal in nb_signals() {
        for quality in [0.0f32, 4.0, 8.0, 10.0] {
            let mut encoder = Encoder::new(&raw const speex_nb_mode);
            encoder.set(SPEEX_SET_VBR, 1);
            encoder.set(SPEEX_SET_VAD, 1);
            encoder.set(SPEEX_SET_DTX, 1);
            encoder.set_float(SPEEX_SET_VBR_QUALITY, quality);
            let mut walker = Walker::new();
            let mut decoder = Decoder::new();
            for (count, packet) in encode_packets(&mut encoder, &signal, |_, _| {}) {
                let (frames, error) = check_packet(&mut walker, &mut decoder, &packet);
                assert_eq!((frames.len(), error), (count, None));
                for frame in frames {
                    seen[usize::from(frame.mode())] += 1;
                }
            }
        }
    }
    eprintln!("VBR frames per mode: {seen:?}");
    assert!(seen[0] > 0, "DTX should send some mode-0 frames");
}

/// Splits a u64 of `count` random bits off a simple generator.
fn random_bits(seed: &mut u64, count: u32) -> u64 {
    *seed = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    match count {
        0 => 0,
        64 => *seed,
        _ => *seed >> (64 - count),
    }
}

#[test]
fn inband_requests_user_messages_and_wideband_layers_are_skipped_like_the_decoder() {
    let signal = &nb_signals()[0];
    let mut seed = 7u64;
    let mut encoder = Encoder::new(&raw const speex_nb_mode);
    encoder.set(SPEEX_SET_QUALITY, 5);
    let packets = encode_packets(&mut encoder, signal, |e, i| match i % 6 {
        0 => {
            let code = (i / 6 % 16) as u64;
            let payload = [1, 1, 4, 4, 4, 4, 4, 4, 8, 8, 16, 16, 32, 32, 64, 64][code as usize];
            e.pack(0, 1);
            e.pack(14, 4);
            e.pack(code, 4);
            e.pack(random_bits(&mut seed, payload), payload);
        }
        1 => {
            // The decoder's user-message skip: 4-bit length n, then 5 + 8n bits.
            let n = (i / 6 % 16) as u64;
            e.pack(0, 1);
            e.pack(13, 4);
            e.pack(n, 4);
            for _ in 0..n {
                e.pack(random_bits(&mut seed, 8), 8);
            }
            e.pack(random_bits(&mut seed, 5), 5);
        }
        2 | 3 => {
            // One or two wideband layers of random content.
            for layer in 0..(i % 6 - 1) {
                let submode = 1 + ((i / 6 + layer) % 4) as u64;
                let size = [0, 36, 112, 192, 352][submode as usize] - 4;
                e.pack(1, 1);
                e.pack(submode, 3);
                for _ in 0..size / 32 {
                    e.pack(random_bits(&mut seed, 32), 32);
                }
                e.pack(random_bits(&mut seed, size % 32), size % 32);
            }
        }
        _ => {}
    });
    let mut walker = Walker::new();
    let mut decoder = Decoder::new();
    for (count, packet) in &packets {
        let (frames, error) = check_packet(&mut walker, &mut decoder, packet);
        assert_eq!((frames.len(), error), (*count, None));
    }
}

#[test]
fn wideband_and_ultra_wideband_streams_decode_as_narrowband() {
    let mut wide = vec![synthetic(16_000.0, 2.0)];
    wide.extend(timit_16k().into_iter().take(1));
    for (mode, upsample) in [
        (&raw const speex_wb_mode, false),
        (&raw const speex_uwb_mode, true),
    ] {
        for signal in &wide {
            let signal = if upsample {
                double(signal)
            } else {
                signal.clone()
            };
            for quality in 0..=10 {
                let mut encoder = Encoder::new(mode);
                encoder.set(SPEEX_SET_QUALITY, quality);
                let mut walker = Walker::new();
                let mut decoder = Decoder::new();
                for (count, packet) in encode_packets(&mut encoder, &signal, |_, _| {}) {
                    let (frames, error) = check_packet(&mut walker, &mut decoder, &packet);
                    if upsample && quality == 0 {
                        // Ultra-wideband quality 0 sends its top layer as submode 0, whose
                        // size the narrowband decoder's skip table lacks: after the first
                        // narrowband frame it gives up on the packet.
                        let expected = BitstreamError::InvalidWidebandSubmode {
                            frame: 1,
                            submode: 0,
                        };
                        assert_eq!((frames.len(), error), (1, Some(expected)));
                    } else {
                        assert_eq!((frames.len(), error), (count, None), "quality {quality}");
                    }
                }
            }
        }
    }
}

#[test]
fn corrupt_streams_fail_in_both() {
    let signal = &nb_signals()[0];
    let mut encoder = Encoder::new(&raw const speex_nb_mode);
    encoder.set(SPEEX_SET_QUALITY, 8);
    encoder.encode(&signal[..160]);
    let good = encoder.take_packet();
    // (prefix bits, count): a wideband layer of submode 0, 5, 6 or 7, and modes 9 to 12.
    let prefixes = [
        (0b1000, 4),
        (0b1101, 4),
        (0b1110, 4),
        (0b1111, 4),
        (0b01001, 5),
        (0b01010, 5),
        (0b01011, 5),
        (0b01100, 5),
    ];
    for (prefix, count) in prefixes {
        for frames_before in [0, 1] {
            let mut walker = Walker::new();
            let mut decoder = Decoder::new();
            for _ in 0..frames_before {
                encoder.encode(&signal[160..320]);
            }
            encoder.pack(prefix, count);
            encoder.pack(0, 32);
            let packet = encoder.take_packet();
            let (frames, error) = check_packet(&mut walker, &mut decoder, &packet);
            assert_eq!(frames.len(), frames_before);
            assert!(error.is_some());
            check_packet(&mut walker, &mut decoder, &good);
        }
    }
}

/// Real packets of every mode to mutate.
fn corpus() -> &'static [Vec<u8>] {
    static CORPUS: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    CORPUS.get_or_init(|| {
        let signal = synthetic(8000.0, 1.0);
        let mut packets = Vec::new();
        for quality in 0..=10 {
            let mut encoder = Encoder::new(&raw const speex_nb_mode);
            encoder.set(SPEEX_SET_QUALITY, quality);
            packets.extend(
                encode_packets(&mut encoder, &signal[4000..], |_, _| {})
                    .into_iter()
                    .map(|(_, p)| p),
            );
        }
        packets
    })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 512,
        failure_persistence: Some(Box::new(FileFailurePersistence::Off)),
        ..ProptestConfig::default()
    })]

    /// Mutated real packets: the walker never panics, and wherever it does not report a
    /// truncation it agrees with the decoder frame for frame.
    #[test]
    fn mutated_packets_agree_with_the_decoder(
        pick in any::<prop::sample::Index>(),
        flips in prop::collection::vec(any::<prop::sample::Index>(), 0..6),
        cut in any::<prop::sample::Index>(),
        should_cut in any::<bool>(),
        tail in prop::collection::vec(any::<u8>(), 0..4),
    ) {
        let corpus = corpus();
        let mut packet = corpus[pick.index(corpus.len())].clone();
        for flip in flips {
            let bit = flip.index(packet.len() * 8);
            packet[bit / 8] ^= 0x80 >> (bit % 8);
        }
        if should_cut {
            packet.truncate(cut.index(packet.len() + 1));
        }
        packet.extend(tail);
        check_packet(&mut Walker::new(), &mut Decoder::new(), &packet);
    }

    #[test]
    fn random_bytes_never_panic_and_match_the_decoder(
        packet in prop::collection::vec(any::<u8>(), 0..200),
    ) {
        check_packet(&mut Walker::new(), &mut Decoder::new(), &packet);
    }
}

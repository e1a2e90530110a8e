//! One remote stream's decoder, whatever its codec: payloads in, 20 ms frames out, each with
//! its audio at the codec's own rate (48 kHz Opus, 8 kHz G.711), the 8 kHz signal the features
//! come from, the features the lip-sync network eats, and concealment for what is missing.
//!
//! The features stay what they were when everything ran at 8 kHz: Opus is decoded twice, at
//! 8 kHz for the features (libopus decodes to it directly, as the offline paths do) and at
//! 48 kHz for the ear, so that no resampler's delay or ripple moves a feature row.
//!
//! Speex decodes frame by frame as before: its packets hold whole 20 ms frames, and the LSPs
//! come from its bitstream walker ([`FrameTracker`]). Opus and G.711 payloads may last any
//! whole number of 2.5 ms (Opus) or samples (G.711: GStreamer's `rtppcmupay` sends 173.5 ms),
//! so they are decoded whole into a queue of samples, placed where their timestamps say within
//! the frame being played; a frame the queue cannot fill is completed by concealment. Their
//! features come from [`FeatureSource`]: Opus SILK frames' NLSFs, read by the walker and mapped
//! onto narrowband LSPs, or an LPC analysis of the decoded audio (G.711, CELT-only Opus).
//!
//! Loss: Speex and Opus conceal with their decoders (Opus recovers a lost 20 ms from the next
//! packet's in-band FEC where that packet carries it); G.711 repeats the last pitch period and
//! fades out over 60 ms, in the manner of G.711 Appendix I. A concealed frame keeps the last
//! frame's LSPs while its energy falls, so the mouth closes.

use super::any::Codec;
use super::g711::Law;
use super::g722;
use super::lpc::LpcAnalyser;
use super::opus::features::CodedRuns;
use super::silk::{self, SilkWalker};
use super::speex::features::FrameTracker;
use super::{opus, speex};
use crate::vocab::{FRAME_SIZE, FeatureFamily, LSP_COUNT, SAMPLE_RATE};
use crate::vocab::{FrameAudio, FrameFeatures, energy_db, flat_lsp};

/// Decoded samples a stream may hold ahead: the longest payload (a 1500-byte datagram of G.711,
/// or 120 ms of Opus) behind at most two frames of leftovers.
const QUEUE_CAPACITY: usize = 2048;
/// G.711 concealment fades to silence over this many samples (60 ms).
const G711_FADE: usize = 480;
/// Pitch periods the G.711 concealment looks for: 57 to 400 Hz.
const PITCH_RANGE: std::ops::RangeInclusive<usize> = 20..=140;
/// History the G.711 concealment repeats from.
const HISTORY: usize = 2 * FRAME_SIZE;

/// How a frame came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameOrigin {
    /// Decoded from received payloads (partly concealed where they left a gap).
    Decoded,
    /// Nothing was received for it: the codec's concealment.
    Concealed,
    /// Lost, and rebuilt from the FEC copy the next Opus packet carried.
    Recovered,
}

/// 20 ms of decoded audio with its features.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedFrame {
    /// What the ear hears, at the codec's rate.
    pub audio: FrameAudio,
    /// The 8 kHz signal the features were computed from (narrowband: the lip-sync side's).
    pub pcm: [i16; FRAME_SIZE],
    pub features: FrameFeatures,
    pub origin: FrameOrigin,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecoderError {
    #[error(transparent)]
    Speex(#[from] speex::codec::CodecError),
    #[error(transparent)]
    Opus(#[from] opus::codec::CodecError),
}

/// A stream's decoder: [`StreamDecoder::packet`] for each payload that starts in the frame about
/// to be played, then [`StreamDecoder::frame`]; [`StreamDecoder::lost`] for a frame with nothing.
pub struct StreamDecoder {
    codec: Codec,
    inner: Inner,
    errors: u64,
}

impl std::fmt::Debug for StreamDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StreamDecoder")
            .field("codec", &self.codec)
            .field("errors", &self.errors)
            .finish_non_exhaustive()
    }
}

enum Inner {
    Speex(Box<SpeexStream>),
    Queued(Box<QueuedStream>),
}

struct SpeexStream {
    /// Narrowband, also of a wideband stream (its narrowband layer): the features' signal.
    decoder: speex::codec::Decoder,
    /// The wideband decoder of a wideband stream, for the ear.
    wide: Option<speex::codec::Decoder>,
    tracker: FrameTracker,
    /// The packet just given could not be loaded: its first frame is concealed.
    failed: bool,
}

/// Where the feature rows of a queued codec come from: Opus SILK and hybrid frames carry NLSFs
/// in their bitstream ([`SilkTrack`]); G.711 audio and CELT-only Opus frames are analysed as the
/// Speex encoder would analyse them.
struct FeatureSource {
    analyser: LpcAnalyser,
    /// LSPs of the last frame with received audio, kept through concealment.
    held: ([f32; LSP_COUNT], FeatureFamily),
    silk: Option<Box<SilkTrack>>,
}

impl FeatureSource {
    fn analysis() -> Self {
        FeatureSource {
            analyser: LpcAnalyser::new(),
            held: (flat_lsp(), FeatureFamily::Analysis),
            silk: None,
        }
    }

    fn opus() -> Self {
        FeatureSource {
            silk: Some(Box::new(SilkTrack::new())),
            ..Self::analysis()
        }
    }

    /// The row of a frame; `coded` is what its payload's SILK layer said, if anything.
    fn features(
        &mut self,
        pcm: &[i16; FRAME_SIZE],
        mode: Option<u8>,
        origin: FrameOrigin,
        coded: Option<[f32; LSP_COUNT]>,
    ) -> FrameFeatures {
        match (origin, coded) {
            // Frames with NLSFs skip the analysis: it would double their cost.
            (FrameOrigin::Decoded, Some(lsp)) => {
                self.held = (lsp, FeatureFamily::Nlsf);
                FrameFeatures {
                    mode,
                    lsp,
                    energy_db: energy_db(pcm),
                    family: FeatureFamily::Nlsf,
                }
            }
            (FrameOrigin::Decoded | FrameOrigin::Recovered, _) => {
                let analysis = self.analyser.analyse(pcm);
                self.held = (analysis.lsp, FeatureFamily::Analysis);
                analysis.features(mode)
            }
            (FrameOrigin::Concealed, _) => {
                // The analyser hears concealed audio too, so that its history stays continuous.
                let _ = self.analyser.analyse(pcm);
                FrameFeatures {
                    mode: None,
                    lsp: self.held.0,
                    energy_db: energy_db(pcm),
                    family: self.held.1,
                }
            }
        }
    }
}

/// Runs of queued samples at most; more (2.5 ms CELT frames in a long payload) merge.
const MAX_RUNS: usize = 96;

/// What the SILK layer of each queued Opus payload coded, sample for sample beside the queue:
/// runs of samples with the narrowband LSPs of their SILK frame (none for CELT-only frames and
/// concealment).
struct SilkTrack {
    walker: SilkWalker,
    frames: Vec<silk::Frame>,
    /// The coded spans, assigned to 20 ms frames as `stream_features` assigns a file's.
    runs: CodedRuns<([f32; LSP_COUNT], u8)>,
}

impl SilkTrack {
    fn new() -> Self {
        Self {
            walker: SilkWalker::new(),
            frames: Vec::with_capacity(8),
            runs: CodedRuns::with_capacity(MAX_RUNS),
        }
    }

    /// A payload decoded to `samples` samples at 8 kHz.
    fn payload(&mut self, payload: &[u8], samples: usize) {
        self.frames.clear();
        if self
            .walker
            .walk_packet_into(payload, &mut self.frames)
            .is_err()
        {
            self.walker.reset();
            self.runs.push(None, samples);
            return;
        }
        self.runs.push_packet(&self.frames, samples, SAMPLE_RATE);
    }

    /// Concealed samples.
    fn gap(&mut self, samples: usize) {
        self.walker.packet_lost();
        self.runs.push(None, samples);
    }

    /// Keeps the first `len` samples.
    fn truncate(&mut self, len: usize) {
        self.runs.truncate(len);
    }

    /// Takes `samples` samples off the front: the LSPs of the coded run that covers most of them.
    fn take(&mut self, samples: usize) -> Option<[f32; LSP_COUNT]> {
        self.runs.take(samples).map(|(lsp, _)| lsp)
    }
}

enum QueuedCodec {
    /// The same packets decoded at 8 kHz (features) and at 48 kHz (audio).
    Opus {
        narrow: opus::codec::Decoder,
        wide: opus::codec::Decoder,
    },
    G711 {
        law: Law,
        plc: Box<Plc>,
    },
    /// The lower sub-band alone at 8 kHz (features), and both through the QMF at 16 kHz.
    G722 {
        low: Box<g722::LowBandDecoder>,
        full: Box<g722::WidebandDecoder>,
        plc: Box<Plc>,
        wide_plc: Box<Plc>,
    },
}

struct QueuedStream {
    codec: QueuedCodec,
    /// The 8 kHz signal the features come from.
    queue: Vec<i16>,
    /// The audio at the codec's rate: `scale` samples for each of `queue`, always.
    wide: Vec<i16>,
    scale: usize,
    /// Mode of the last payload decoded: Opus's TOC configuration, G.711's payload type.
    mode: Option<u8>,
    features: FeatureSource,
    scratch: [i16; opus::codec::MAX_PACKET_SAMPLES],
    wide_scratch: Vec<i16>,
}

impl StreamDecoder {
    /// A decoder for `codec`; `enhancer` is Speex's perceptual enhancer (speexdec's default).
    pub fn new(codec: Codec, enhancer: bool) -> Result<Self, DecoderError> {
        let queued = |codec, features, rate: u32| {
            let scale = (rate / SAMPLE_RATE) as usize;
            Inner::Queued(Box::new(QueuedStream {
                codec,
                queue: Vec::with_capacity(QUEUE_CAPACITY),
                wide: Vec::with_capacity(QUEUE_CAPACITY * scale),
                scale,
                mode: None,
                features,
                scratch: [0; opus::codec::MAX_PACKET_SAMPLES],
                wide_scratch: vec![0; opus::codec::MAX_PACKET_SAMPLES * scale],
            }))
        };
        let inner = match codec {
            Codec::Speex | Codec::SpeexWb => Inner::Speex(Box::new(SpeexStream {
                decoder: speex::codec::Decoder::new(enhancer)?,
                wide: match codec {
                    Codec::SpeexWb => Some(speex::codec::Decoder::with_band(
                        enhancer,
                        speex::codec::Band::Wide,
                    )?),
                    _ => None,
                },
                tracker: FrameTracker::new(),
                failed: false,
            })),
            Codec::Opus => queued(
                QueuedCodec::Opus {
                    narrow: opus::codec::Decoder::new()?,
                    wide: opus::codec::Decoder::with_rate(codec.audio_rate())?,
                },
                FeatureSource::opus(),
                codec.audio_rate(),
            ),
            Codec::Pcmu | Codec::Pcma => {
                let law = codec.law().unwrap_or(Law::Mu);
                queued(
                    QueuedCodec::G711 {
                        law,
                        plc: Box::new(Plc::new(1)),
                    },
                    FeatureSource::analysis(),
                    codec.audio_rate(),
                )
            }
            Codec::G722 => queued(
                QueuedCodec::G722 {
                    low: Box::default(),
                    full: Box::default(),
                    plc: Box::new(Plc::new(1)),
                    wide_plc: Box::new(Plc::new(2)),
                },
                FeatureSource::analysis(),
                codec.audio_rate(),
            ),
        };
        Ok(Self {
            codec,
            inner,
            errors: 0,
        })
    }

    pub fn codec(&self) -> Codec {
        self.codec
    }

    /// Payloads the codec refused (each concealed instead).
    pub fn errors(&self) -> u64 {
        self.errors
    }

    /// A payload that starts `offset` ticks of the codec's RTP clock into the frame about to be
    /// played (0 on the 20 ms grid). Speex payloads always start a frame.
    pub fn packet(&mut self, payload: &[u8], offset: u32) {
        match &mut self.inner {
            Inner::Speex(s) => {
                s.failed = s.decoder.load(payload).is_err();
                if let Some(wide) = &mut s.wide {
                    s.failed |= wide.load(payload).is_err();
                }
                // A packet the walker cannot read still decodes; its rows keep held LSPs.
                let _ = s.tracker.start_packet(payload);
                self.errors += u64::from(s.failed);
            }
            Inner::Queued(q) => {
                let offset = self.codec.ticks_to_samples(offset).min(FRAME_SIZE);
                if !q.decode(payload, offset) {
                    self.errors += 1;
                }
            }
        }
    }

    /// The next 20 ms: the current payload's next frame, completed by concealment where the
    /// payloads fall short.
    pub fn frame(&mut self) -> DecodedFrame {
        match &mut self.inner {
            Inner::Speex(s) => {
                if std::mem::take(&mut s.failed) {
                    return s.conceal();
                }
                let mut pcm = [0i16; FRAME_SIZE];
                let decoded = matches!(
                    s.decoder.decode_next(&mut pcm),
                    Ok(speex::codec::FrameOutcome::Decoded)
                );
                if decoded {
                    let features = s.tracker.decoded(&pcm);
                    return DecodedFrame {
                        audio: s.wide_audio(&pcm, false),
                        pcm,
                        features,
                        origin: FrameOrigin::Decoded,
                    };
                }
                self.errors += 1;
                s.conceal()
            }
            Inner::Queued(q) => q.frame(),
        }
    }

    /// A frame nothing was received for. `next` is the payload that follows it, if it is
    /// already here: Opus rebuilds the frame from the FEC copy that payload may carry.
    pub fn lost(&mut self, next: Option<&[u8]>) -> DecodedFrame {
        match &mut self.inner {
            Inner::Speex(s) => s.conceal(),
            Inner::Queued(q) => {
                if q.queue.is_empty()
                    && let (QueuedCodec::Opus { narrow, wide }, Some(next)) = (&mut q.codec, next)
                    && opus::fec::carries_fec(next)
                {
                    let mut pcm = [0i16; FRAME_SIZE];
                    if narrow.decode_fec(next, &mut pcm).is_ok() {
                        let mut audio = FrameAudio::silence(wide.rate());
                        if wide.decode_fec(next, audio.samples_mut()).is_err() {
                            audio = FrameAudio::silence(wide.rate());
                        }
                        let mode = next.first().map(|toc| toc >> 3);
                        let features =
                            q.features
                                .features(&pcm, mode, FrameOrigin::Recovered, None);
                        return DecodedFrame {
                            audio,
                            pcm,
                            features,
                            origin: FrameOrigin::Recovered,
                        };
                    }
                }
                q.frame()
            }
        }
    }
}

impl SpeexStream {
    /// The frame for the ear: the narrowband one, or the wideband decoder's of the same
    /// packet (its concealment where `conceal`, or where it fails).
    fn wide_audio(&mut self, pcm: &[i16; FRAME_SIZE], conceal: bool) -> FrameAudio {
        let Some(wide) = &mut self.wide else {
            return FrameAudio::narrowband(pcm);
        };
        let mut audio = FrameAudio::silence(wide.band().rate());
        let decoded = !conceal
            && matches!(
                wide.decode_next_into(audio.samples_mut()),
                Ok(speex::codec::FrameOutcome::Decoded)
            );
        if !decoded {
            let _ = wide.conceal_into(audio.samples_mut());
        }
        audio
    }

    fn conceal(&mut self) -> DecodedFrame {
        let mut pcm = [0i16; FRAME_SIZE];
        self.decoder.conceal(&mut pcm);
        let features = self.tracker.concealed(&pcm);
        DecodedFrame {
            audio: self.wide_audio(&pcm, true),
            pcm,
            features,
            origin: FrameOrigin::Concealed,
        }
    }
}

impl QueuedStream {
    /// Queues a payload's samples `offset` samples into the frame about to be played. A gap
    /// before it is concealed. An overlap of up to a frame is played rather than cut (GStreamer
    /// stamps its first Opus packet 6.5 ms shorter than it is, the encoder's look-ahead; cutting
    /// would splice the audio): the stream then runs that much later. Beyond a frame the
    /// newer payload wins. False if the payload could not be decoded.
    fn decode(&mut self, payload: &[u8], offset: usize) -> bool {
        if self.queue.len() > offset + FRAME_SIZE {
            self.queue.truncate(offset);
            self.wide.truncate(offset * self.scale);
            if let Some(track) = &mut self.features.silk {
                track.truncate(offset);
            }
        } else if self.queue.len() < offset {
            self.conceal_into_queue(offset - self.queue.len());
        }
        let start = self.queue.len();
        match &mut self.codec {
            QueuedCodec::Opus { narrow, wide } => {
                let Ok(n) = narrow.decode(payload, &mut self.scratch) else {
                    return false;
                };
                if start + n > QUEUE_CAPACITY {
                    return false;
                }
                self.queue.extend_from_slice(&self.scratch[..n]);
                let m = n * self.scale;
                if wide.decode(payload, &mut self.wide_scratch).is_err() {
                    self.wide_scratch[..m].fill(0);
                }
                self.wide.extend_from_slice(&self.wide_scratch[..m]);
                if let Some(track) = &mut self.features.silk {
                    track.payload(payload, n);
                }
                self.mode = payload.first().map(|toc| toc >> 3);
            }
            QueuedCodec::G711 { law, plc } => {
                let n = payload.len().min(QUEUE_CAPACITY - start);
                if n == 0 {
                    return false;
                }
                self.queue.resize(start + n, 0);
                law.decode_into(&payload[..n], &mut self.queue[start..]);
                plc.heard(&self.queue[start..]);
                self.wide.extend_from_slice(&self.queue[start..]);
                self.mode = Some(law.payload_type());
            }
            QueuedCodec::G722 {
                low,
                full,
                plc,
                wide_plc,
            } => {
                let n = payload.len().min(QUEUE_CAPACITY - start);
                if n == 0 {
                    return false;
                }
                self.queue.resize(start + n, 0);
                low.decode_into(&payload[..n], &mut self.queue[start..]);
                plc.heard(&self.queue[start..]);
                let wide_start = self.wide.len();
                self.wide.resize(wide_start + 2 * n, 0);
                full.decode_into(&payload[..n], &mut self.wide[wide_start..]);
                wide_plc.heard(&self.wide[wide_start..]);
                self.mode = Some(g722::PAYLOAD_TYPE);
            }
        }
        true
    }

    /// Appends `n` concealed samples.
    fn conceal_into_queue(&mut self, n: usize) {
        let start = self.queue.len();
        let n = n.min(QUEUE_CAPACITY - start);
        self.queue.resize(start + n, 0);
        let wide_start = self.wide.len();
        self.wide.resize(wide_start + n * self.scale, 0);
        if let Some(track) = &mut self.features.silk {
            track.gap(n);
        }
        let out = &mut self.queue[start..];
        let wide_out = &mut self.wide[wide_start..];
        match &mut self.codec {
            QueuedCodec::Opus { narrow, wide } => {
                // libopus conceals whole 2.5 ms steps (20 samples at 8 kHz).
                let steps = n.div_ceil(20) * 20;
                let scratch = &mut self.scratch[..steps.min(opus::codec::MAX_PACKET_SAMPLES)];
                if narrow.conceal(scratch).is_ok() {
                    let m = out.len().min(scratch.len());
                    out[..m].copy_from_slice(&scratch[..m]);
                }
                let scratch = &mut self.wide_scratch[..scratch.len() * self.scale];
                if wide.conceal(scratch).is_ok() {
                    let m = wide_out.len().min(scratch.len());
                    wide_out[..m].copy_from_slice(&scratch[..m]);
                }
            }
            QueuedCodec::G711 { plc, .. } => {
                plc.conceal(out);
                wide_out.copy_from_slice(out);
            }
            QueuedCodec::G722 { plc, wide_plc, .. } => {
                plc.conceal(out);
                wide_plc.conceal(wide_out);
            }
        }
    }

    fn frame(&mut self) -> DecodedFrame {
        let had = self.queue.len().min(FRAME_SIZE);
        if had < FRAME_SIZE {
            self.conceal_into_queue(FRAME_SIZE - had);
        }
        let mut pcm = [0i16; FRAME_SIZE];
        let n = self.queue.len().min(FRAME_SIZE);
        pcm[..n].copy_from_slice(&self.queue[..n]);
        self.queue.drain(..n);
        let wide_n = (n * self.scale).min(self.wide.len());
        let audio = FrameAudio::from_slice(self.scale as u32 * SAMPLE_RATE, &self.wide[..wide_n]);
        self.wide.drain(..wide_n);
        let coded = self.features.silk.as_mut().and_then(|t| t.take(n));
        let origin = if had > 0 {
            FrameOrigin::Decoded
        } else {
            FrameOrigin::Concealed
        };
        let features = self.features.features(&pcm, self.mode, origin, coded);
        DecodedFrame {
            audio,
            pcm,
            features,
            origin,
        }
    }
}

/// G.711 and G.722 have no concealment of their own: repeat the last pitch period of what was
/// heard, fading to silence over 60 ms. `scale` is the rate over 8 kHz (2 for G.722's 16 kHz).
struct Plc {
    history: Vec<i16>,
    scale: usize,
    period: usize,
    /// Samples concealed since the last heard ones.
    concealed: usize,
}

impl Plc {
    fn new(scale: usize) -> Self {
        Self {
            history: vec![0; HISTORY * scale],
            scale,
            period: FRAME_SIZE * scale,
            concealed: 0,
        }
    }

    fn heard(&mut self, samples: &[i16]) {
        let len = self.history.len();
        let n = samples.len().min(len);
        self.history.copy_within(n.., 0);
        self.history[len - n..].copy_from_slice(&samples[samples.len() - n..]);
        self.concealed = 0;
    }

    /// The lag of the strongest normalised autocorrelation over the last frame.
    fn pitch(&self) -> usize {
        let (len, frame) = (self.history.len(), FRAME_SIZE * self.scale);
        let recent = &self.history[len - frame..];
        let mut best = (0.0f64, frame);
        let lags = PITCH_RANGE.start() * self.scale..=PITCH_RANGE.end() * self.scale;
        for lag in lags {
            let earlier = &self.history[len - frame - lag..len - lag];
            let (mut xy, mut yy) = (0.0f64, 0.0f64);
            for (&x, &y) in recent.iter().zip(earlier) {
                xy += f64::from(x) * f64::from(y);
                yy += f64::from(y) * f64::from(y);
            }
            if yy > 0.0 {
                let score = xy / yy.sqrt();
                if score > best.0 {
                    best = (score, lag);
                }
            }
        }
        best.1
    }

    fn conceal(&mut self, out: &mut [i16]) {
        if self.concealed == 0 {
            self.period = self.pitch();
        }
        let base = self.history.len() - self.period;
        let fade = G711_FADE * self.scale;
        for o in out.iter_mut() {
            let gain = 1.0 - self.concealed as f32 / fade as f32;
            *o = if gain > 0.0 {
                let s = self.history[base + self.concealed % self.period];
                (f32::from(s) * gain) as i16
            } else {
                0
            };
            self.concealed += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::any::{EncoderSettings, FrameEncoder, MAX_FRAME_PAYLOAD};
    use super::*;
    use crate::codec::opus::features::narrowband_lsp;

    fn speech_like(frames: usize) -> Vec<[i16; FRAME_SIZE]> {
        speech_like_at(frames, SAMPLE_RATE)
            .iter()
            .map(|f| f[..].try_into().unwrap())
            .collect()
    }

    /// 20 ms frames at `rate` of a buzz with two formants (and, above 8 kHz, a 6 kHz hiss).
    fn speech_like_at(frames: usize, rate: u32) -> Vec<Vec<i16>> {
        let n = rate as usize / 50;
        (0..frames)
            .map(|f| {
                (0..n)
                    .map(|i| {
                        let t = (f * n + i) as f32 / rate as f32;
                        let env = (std::f32::consts::PI * t * 2.0).sin().abs();
                        let mut s = 0.0;
                        for h in 1..20 {
                            let fr = 140.0 * h as f32;
                            let amp = 1.0 / (1.0 + ((fr - 700.0) / 250.0).powi(2))
                                + 0.6 / (1.0 + ((fr - 1500.0) / 300.0).powi(2));
                            s += amp * (2.0 * std::f32::consts::PI * fr * t).sin();
                        }
                        if rate > 8000 {
                            s += 0.3 * (2.0 * std::f32::consts::PI * 6000.0 * t).sin();
                        }
                        (5000.0 * env * s) as i16
                    })
                    .collect()
            })
            .collect()
    }

    /// `frames` frames of [`speech_like_at`] the encoder's rate, encoded.
    fn encode(codec: Codec, frames: usize) -> Vec<Vec<u8>> {
        let mut enc = FrameEncoder::new(codec, &EncoderSettings::default()).unwrap();
        let mut out = [0u8; MAX_FRAME_PAYLOAD];
        speech_like_at(frames, enc.input_rate())
            .iter()
            .filter_map(|f| {
                enc.encode(f, &mut out)
                    .unwrap()
                    .map(|(n, _)| out[..n].to_vec())
            })
            .collect()
    }

    fn energy(pcm: &[i16]) -> f64 {
        pcm.iter().map(|&s| f64::from(s).powi(2)).sum()
    }

    #[test]
    fn every_codec_decodes_frame_by_frame_with_features() {
        let input = speech_like(100);
        for codec in Codec::ALL {
            let packets = encode(codec, input.len());
            assert_eq!(packets.len(), 100, "{codec}");
            let mut dec = StreamDecoder::new(codec, true).unwrap();
            let mut out = Vec::new();
            for p in &packets {
                dec.packet(p, 0);
                let f = dec.frame();
                assert_eq!(f.origin, FrameOrigin::Decoded, "{codec}");
                assert!(f.features.mode.is_some(), "{codec}");
                assert!(f.features.lsp.windows(2).all(|w| w[0] < w[1]), "{codec}");
                out.extend_from_slice(&f.pcm);
            }
            assert_eq!(dec.errors(), 0);
            // Sound came out, about as loud as went in.
            let ratio = energy(&out) / energy(input.as_flattened());
            assert!((0.3..3.0).contains(&ratio), "{codec}: {ratio}");
        }
    }

    /// Energy above 4 kHz over all energy, of 20 ms frames at `rate` (a first difference as a
    /// crude high-pass is enough to tell a band that is there from one that is not).
    fn upper_share(frames: &[Vec<i16>]) -> f64 {
        let all: f64 = frames.iter().map(|f| energy(f)).sum();
        let diff: f64 = frames
            .iter()
            .map(|f| {
                f.windows(2)
                    .map(|w| (f64::from(w[1]) - f64::from(w[0])).powi(2))
                    .sum::<f64>()
            })
            .sum();
        diff / all.max(1.0)
    }

    #[test]
    fn the_ear_gets_each_codecs_own_band_and_the_features_the_8_khz_signal() {
        for (codec, rate) in [
            (Codec::Opus, 48_000),
            (Codec::G722, 16_000),
            (Codec::Pcmu, 8000),
            (Codec::Speex, 8000),
            (Codec::SpeexWb, 16_000),
        ] {
            let settings = EncoderSettings::wideband(opus::codec::Bandwidth::Fullband);
            let mut enc = FrameEncoder::new(codec, &settings).unwrap();
            let input = speech_like_at(60, enc.input_rate());
            let mut dec = StreamDecoder::new(codec, true).unwrap();
            let mut wide = Vec::new();
            let mut out = [0u8; MAX_FRAME_PAYLOAD];
            for f in &input {
                let (n, _) = enc.encode(f, &mut out).unwrap().unwrap();
                dec.packet(&out[..n], 0);
                let frame = dec.frame();
                assert_eq!(frame.audio.rate(), rate, "{codec}");
                assert_eq!(frame.audio.samples().len(), rate as usize / 50);
                // The 8 kHz signal is what the features were computed from.
                assert!((energy_db(&frame.pcm) - frame.features.energy_db).abs() < 0.01);
                wide.push(frame.audio.samples().to_vec());
            }
            let ratio = energy(&wide.concat()[rate as usize / 5..])
                / energy(&input.concat()[rate as usize / 5..]);
            assert!((0.3..3.0).contains(&ratio), "{codec}: {ratio}");
            if rate > 8000 {
                // The 6 kHz hiss went in and came out.
                let (theirs, ours) = (upper_share(&input[10..]), upper_share(&wide[10..]));
                assert!(ours > 0.5 * theirs, "{codec}: {ours} vs {theirs}");
            }
        }
        // Speex wideband's rows are those of its narrowband layer, as a narrowband decoder
        // (which steps over the wideband layer) makes of the same packets.
        let packets = encode(Codec::SpeexWb, 40);
        let mut wide = StreamDecoder::new(Codec::SpeexWb, true).unwrap();
        let mut narrow = StreamDecoder::new(Codec::Speex, true).unwrap();
        for p in &packets {
            wide.packet(p, 0);
            narrow.packet(p, 0);
            let (w, n) = (wide.frame(), narrow.frame());
            assert_eq!(w.features, n.features);
            assert_eq!(w.pcm, n.pcm);
            assert_eq!(w.audio.rate(), 16_000);
        }
        // G.722's features are those of its lower band alone, as the offline path computes.
        let input = speech_like_at(30, 16_000);
        let mut enc = g722::WidebandEncoder::new();
        let mut low = g722::LowBandDecoder::new();
        let mut dec = StreamDecoder::new(Codec::G722, true).unwrap();
        for f in &input {
            let payload = enc.encode_frame(f[..].try_into().unwrap());
            dec.packet(&payload, 0);
            assert_eq!(dec.frame().pcm, low.decode_frame(&payload));
        }
    }

    #[test]
    fn opus_rows_carry_the_lsps_its_silk_layer_coded() {
        // Each 20 ms packet is one SILK frame: its row holds exactly that frame's NLSFs mapped,
        // whether the packets arrive on the 20 ms grid or one 40 ms payload at a time.
        let input = speech_like(40);
        let packets = encode(Codec::Opus, input.len());
        let mut walker = SilkWalker::new();
        let expected: Vec<[f32; LSP_COUNT]> = packets
            .iter()
            .map(|p| {
                let frames = walker.walk_packet(p).unwrap();
                let silk = frames[0].silk().expect("a SILK frame");
                narrowband_lsp(&silk.nlsf, silk.internal_rate_hz).unwrap()
            })
            .collect();
        let mut dec = StreamDecoder::new(Codec::Opus, true).unwrap();
        for (p, lsp) in packets.iter().zip(&expected) {
            dec.packet(p, 0);
            let row = dec.frame();
            assert_eq!(row.origin, FrameOrigin::Decoded);
            assert_eq!(row.features.lsp, *lsp);
        }
        // Two packets queued before either is played: rows still pair with their packets.
        let mut dec = StreamDecoder::new(Codec::Opus, true).unwrap();
        for pair in packets.chunks_exact(2).zip(expected.chunks_exact(2)) {
            let (p, lsp) = pair;
            dec.packet(&p[0], 0);
            dec.packet(&p[1], FRAME_SIZE as u32 * 6);
            assert_eq!(dec.frame().features.lsp, lsp[0]);
            assert_eq!(dec.frame().features.lsp, lsp[1]);
        }
        // A lost frame keeps the last coded LSPs.
        let lost = dec.lost(None);
        assert_eq!(lost.features.lsp, *expected.last().unwrap());
    }

    #[test]
    fn a_call_and_a_file_assign_the_same_nlsfs_to_each_frame() {
        // The same Opus packets played by the receiver and read as a file (from sample 0, as a
        // call hears them): every 20 ms row has the same LSPs, or an analysis on both sides.
        let input = speech_like(60);
        let packets = encode(Codec::Opus, input.len());
        let mut dec = StreamDecoder::new(Codec::Opus, true).unwrap();
        let mut live = Vec::new();
        let mut pcm = Vec::new();
        for p in &packets {
            dec.packet(p, 0);
            let row = dec.frame();
            pcm.extend_from_slice(&row.pcm);
            live.push(row.features);
        }
        let ogg = opus::stream::encode(input.as_flattened(), Default::default()).unwrap();
        let mut file = opus::stream::decode(&ogg).unwrap();
        file.pcm = pcm;
        file.packets = packets
            .iter()
            .enumerate()
            .map(|(n, p)| opus::stream::DecodedPacket {
                data: p.clone(),
                samples: FRAME_SIZE,
                pcm_offset: (n * FRAME_SIZE) as i64,
                corrupt: false,
            })
            .collect();
        let offline = opus::features::stream_features(&file);
        assert_eq!(offline.len(), live.len());
        for (n, (a, b)) in live.iter().zip(&offline).enumerate() {
            assert_eq!(a.family, b.family, "row {n}");
            assert_eq!(a.lsp, b.lsp, "row {n}");
        }
        assert!(live.iter().any(|f| f.family == FeatureFamily::Nlsf));
    }

    #[test]
    fn concealment_keeps_the_lsps_and_fades() {
        let input = speech_like(60);
        for codec in Codec::ALL {
            let packets = encode(codec, input.len());
            let mut dec = StreamDecoder::new(codec, true).unwrap();
            let mut last = None;
            for p in &packets[..25] {
                dec.packet(p, 0);
                last = Some(dec.frame());
            }
            let last = last.unwrap();
            let mut energies = Vec::new();
            for _ in 0..10 {
                let f = dec.lost(None);
                assert_eq!(f.origin, FrameOrigin::Concealed, "{codec}");
                assert_eq!(f.features.mode, None);
                assert_eq!(f.features.lsp, last.features.lsp, "{codec}");
                energies.push(f.features.energy_db);
            }
            assert!(
                energies[9] < last.features.energy_db - 20.0,
                "{codec}: {energies:?} after {}",
                last.features.energy_db
            );
            // Decoding resumes.
            dec.packet(&packets[35], 0);
            assert_eq!(dec.frame().origin, FrameOrigin::Decoded);
        }
    }

    #[test]
    fn opus_rebuilds_a_lost_frame_from_the_next_packets_fec() {
        let input = speech_like(50);
        let packets = encode(Codec::Opus, input.len());
        let lost = (20..49)
            .find(|&i| opus::fec::carries_fec(&packets[i + 1]))
            .expect("FEC at 20 kb/s");
        let run = |use_fec: bool| {
            let mut dec = StreamDecoder::new(Codec::Opus, true).unwrap();
            let mut frames = Vec::new();
            for (i, p) in packets.iter().enumerate() {
                if i == lost {
                    let f = dec.lost(use_fec.then_some(&packets[lost + 1][..]));
                    frames.push(f);
                    continue;
                }
                dec.packet(p, 0);
                frames.push(dec.frame());
            }
            frames
        };
        let clean: Vec<_> = {
            let mut dec = StreamDecoder::new(Codec::Opus, true).unwrap();
            packets
                .iter()
                .map(|p| {
                    dec.packet(p, 0);
                    dec.frame()
                })
                .collect()
        };
        let fec = run(true);
        let plc = run(false);
        assert_eq!(fec[lost].origin, FrameOrigin::Recovered);
        assert!(fec[lost].features.mode.is_some());
        assert_eq!(plc[lost].origin, FrameOrigin::Concealed);
        let err = |f: &DecodedFrame| {
            f.pcm
                .iter()
                .zip(&clean[lost].pcm)
                .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                .sum::<f64>()
        };
        assert!(err(&fec[lost]) < err(&plc[lost]), "FEC no better than PLC");
    }

    #[test]
    fn g711_payloads_of_any_length_play_on_the_grid() {
        let input = speech_like(40);
        let flat: Vec<i16> = input.as_flattened().to_vec();
        let law = Law::Mu;
        let reference: Vec<i16> = flat
            .iter()
            .map(|&s| law.decode_sample(law.encode_sample(s)))
            .collect();
        // GStreamer's default PCMU packets: 1388 and 660 samples, taking turns.
        let mut dec = StreamDecoder::new(Codec::Pcmu, true).unwrap();
        let mut at = 0usize;
        let mut sizes = [1388usize, 660].into_iter().cycle();
        let mut played = Vec::new();
        let mut pending: Vec<(usize, Vec<u8>)> = Vec::new();
        while at < flat.len() {
            let n = sizes.next().unwrap().min(flat.len() - at);
            pending.push((
                at,
                flat[at..at + n]
                    .iter()
                    .map(|&s| law.encode_sample(s))
                    .collect(),
            ));
            at += n;
        }
        // Each 20 ms slot: the payloads starting in it, at their offsets.
        for slot in 0..flat.len() / FRAME_SIZE {
            let lo = slot * FRAME_SIZE;
            for (start, p) in pending
                .iter()
                .filter(|(s, _)| (lo..lo + FRAME_SIZE).contains(s))
            {
                dec.packet(p, (start - lo) as u32);
            }
            played.extend_from_slice(&dec.frame().pcm);
        }
        assert_eq!(played, reference[..played.len()]);
        assert_eq!(dec.errors(), 0);
        // A payload arriving 10 ms into a frame after a loss is placed there, the gap concealed.
        let mut dec = StreamDecoder::new(Codec::Pcma, true).unwrap();
        dec.packet(&[0xd5; 160], 0);
        dec.frame();
        dec.packet(&[0x55; 240], 80);
        let f = dec.frame();
        assert_eq!(f.origin, FrameOrigin::Decoded);
        assert_eq!(f.pcm[80..], [Law::A.decode_sample(0x55); 80]);
        assert_eq!(dec.frame().pcm[..160], [Law::A.decode_sample(0x55); 160]);
        assert_eq!(dec.lost(None).origin, FrameOrigin::Concealed);
    }

    #[test]
    fn garbage_is_an_error_then_concealed_never_a_panic() {
        for codec in Codec::ALL {
            let mut dec = StreamDecoder::new(codec, true).unwrap();
            for junk in [&[][..], &[0xff; 3], &[0x0b, 48], &[0u8; 1500]] {
                dec.packet(junk, 0);
                let played = dec.frame();
                dec.packet(junk, u32::MAX);
                let lost = dec.lost(Some(junk));
                for f in [played, lost] {
                    // Whatever came in, 20 ms at the codec's own rate came out.
                    assert_eq!(f.audio.rate(), codec.audio_rate(), "{codec}");
                    assert!(f.features.lsp.iter().all(|v| v.is_finite()));
                }
            }
        }
    }
}

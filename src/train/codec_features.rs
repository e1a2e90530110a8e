//! The production feature source: training audio goes through the real codec, exactly as a
//! receiver hears it. Each WAV is read and resampled to 8 kHz once (kept in memory), then Speex
//! encoded at a setting, decoded, and the decoder's LSPs + energy are read per 20 ms frame.
//!
//! Augmentation: the training speakers' utterances are seen at several codec settings, so the
//! network does not learn one bit rate's quantisation. Evaluation uses one fixed setting
//! ([`EVALUATION_QUALITY`]) and reports [`LOW_QUALITY`] beside it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::audio::wav;
use crate::codec::speex::codec::EncoderConfig;
use crate::codec::speex::features::FrameFeatures;
use crate::codec::speex::stream;
use crate::train::corpus::{BoxError, CorpusError, PreparedUtterance, Utterance, prepare};

/// The quality every reported score uses unless said otherwise (speexenc's default).
pub const EVALUATION_QUALITY: u8 = 8;
/// The low quality reported beside it (mode 3, 8 kbit/s).
pub const LOW_QUALITY: u8 = 3;

/// Codec settings the training utterances are augmented with: CBR qualities 3 to 10 and VBR.
pub fn augmentation_settings() -> Vec<EncoderConfig> {
    let cbr = (3..=10).map(|quality| EncoderConfig {
        quality,
        ..EncoderConfig::default()
    });
    let vbr = [4, 8].map(|quality| EncoderConfig {
        quality,
        vbr: true,
        ..EncoderConfig::default()
    });
    cbr.chain(vbr).collect()
}

/// A CBR setting at `quality` with speexenc's other defaults.
pub fn quality(quality: u8) -> EncoderConfig {
    EncoderConfig {
        quality,
        ..EncoderConfig::default()
    }
}

/// Features of one WAV file as a receiver sees them after a Speex round trip at `config`.
pub fn codec_features(path: &Path, config: EncoderConfig) -> Result<Vec<FrameFeatures>, BoxError> {
    let pcm = wav::read_narrowband(path)?;
    features_of_pcm(&pcm, config)
}

fn features_of_pcm(pcm: &[i16], config: EncoderConfig) -> Result<Vec<FrameFeatures>, BoxError> {
    Ok(stream::round_trip(pcm, config)?.features)
}

/// Codec features with the 8 kHz audio of every file read once and kept.
#[derive(Debug, Default)]
pub struct CodecFeatures {
    audio: Mutex<HashMap<PathBuf, Arc<Vec<i16>>>>,
}

impl CodecFeatures {
    pub fn new() -> Self {
        Self::default()
    }

    fn pcm(&self, path: &Path) -> Result<Arc<Vec<i16>>, BoxError> {
        let mut audio = self.audio.lock().map_err(|_| "audio cache poisoned")?;
        if let Some(pcm) = audio.get(path) {
            return Ok(Arc::clone(pcm));
        }
        let pcm = Arc::new(wav::read_narrowband(path)?);
        audio.insert(path.to_path_buf(), Arc::clone(&pcm));
        Ok(pcm)
    }

    /// The features of `path` at `config`.
    pub fn features(
        &self,
        path: &Path,
        config: EncoderConfig,
    ) -> Result<Vec<FrameFeatures>, BoxError> {
        features_of_pcm(&self.pcm(path)?, config)
    }

    /// Prepares `utterances` at one setting.
    pub fn prepare(
        &self,
        utterances: &[&Utterance],
        config: EncoderConfig,
    ) -> Result<Vec<PreparedUtterance>, CorpusError> {
        prepare(utterances, &|path: &Path| self.features(path, config))
    }

    /// Prepares each utterance at `versions` of `settings` (rotating through them, so every
    /// setting is used about equally often): `versions` times as many training utterances.
    pub fn prepare_augmented(
        &self,
        utterances: &[&Utterance],
        settings: &[EncoderConfig],
        versions: usize,
        on_done: &dyn Fn(),
    ) -> Result<Vec<PreparedUtterance>, CorpusError> {
        let versions = versions.clamp(1, settings.len().max(1));
        let mut out = Vec::with_capacity(utterances.len() * versions);
        for (i, utt) in utterances.iter().enumerate() {
            for k in 0..versions {
                let config = settings
                    .get((i * versions + k) % settings.len().max(1))
                    .copied()
                    .unwrap_or_default();
                out.extend(self.prepare(std::slice::from_ref(utt), config)?);
                on_done();
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::corpus::Corpus;
    use crate::train::corpus::tests::timit_root;

    #[test]
    fn codec_features_line_up_with_the_targets() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let utt = &corpus.speaker("dr4-maeb0").unwrap().utterances[0];
        let codec = CodecFeatures::new();
        let prepared = codec.prepare(&[utt], quality(8)).unwrap();
        let (_, samples) = crate::train::corpus::wav_length(&utt.wav).unwrap();
        let frames = samples as usize / 320;
        assert!(prepared[0].features.len().abs_diff(frames) <= 1);
        assert!(prepared[0].features.iter().all(|f| f.mode.is_some()));
        let low = codec.prepare(&[utt], quality(3)).unwrap();
        assert_eq!(low[0].features.len(), prepared[0].features.len());
        assert_ne!(low[0].features, prepared[0].features);
        let augmented = codec
            .prepare_augmented(&[utt, utt], &augmentation_settings(), 3, &|| {})
            .unwrap();
        assert_eq!(augmented.len(), 6);
        assert!(codec_features(Path::new("/nonexistent.wav"), quality(8)).is_err());
    }
}

//! TIMIT-style corpora: `<root>/<speaker>/<utt>.wav` (16 kHz, 16-bit) with `<utt>.phn` lines
//! `start_sample end_sample phone`, the per-frame viseme targets derived from them, and the
//! split of speakers into training, validation and test.

use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::lipsync::coarticulation::{FRAME_SECONDS, TimedTarget, frame_targets};
use crate::lipsync::phones::{CueClass, UnknownPhone, is_bilabial, phone_target};
use crate::vocab::FrameFeatures;
use crate::vocab::FullWeights;

/// Error type a feature extractor may return.
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// The codec boundary: decoder features (one per 20 ms frame, frame n starting at n * 20 ms)
/// of the utterance in a WAV file. The production pipeline passes a Speex encode/decode here.
pub type FeatureFn<'a> = dyn Fn(&Path) -> Result<Vec<FrameFeatures>, BoxError> + 'a;

#[derive(Debug, thiserror::Error)]
pub enum CorpusError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    WavFile(#[from] crate::audio::wav::WavError),
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("{path}: {samples} samples at {rate} Hz is shorter than one 20 ms frame")]
    AudioTooShort {
        path: PathBuf,
        samples: u32,
        rate: u32,
    },
    #[error("{path}:{line}: {message}")]
    BadPhoneLine {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}:{line}: {source}")]
    UnknownPhone {
        path: PathBuf,
        line: usize,
        source: UnknownPhone,
    },
    #[error("{path}: no utterances (expected <speaker>/<utt>.wav with <utt>.phn beside it)")]
    Empty { path: PathBuf },
    #[error("speaker {0:?} is not in the corpus")]
    UnknownSpeaker(String),
    #[error("the speaker split leaves the {0} set empty")]
    EmptySplit(&'static str),
    #[error("features of {path}: {source}")]
    Features { path: PathBuf, source: BoxError },
}

/// One recording with its phone labels.
#[derive(Debug, Clone, PartialEq)]
pub struct Utterance {
    pub speaker: String,
    pub id: String,
    pub wav: PathBuf,
    pub phn: PathBuf,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Speaker {
    pub name: String,
    pub utterances: Vec<Utterance>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Corpus {
    pub root: PathBuf,
    pub speakers: Vec<Speaker>,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CorpusError + '_ {
    move |source| CorpusError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn sorted_entries(dir: &Path) -> Result<Vec<PathBuf>, CorpusError> {
    let mut entries = std::fs::read_dir(dir)
        .map_err(io(dir))?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(io(dir))?;
    entries.sort();
    Ok(entries)
}

impl Corpus {
    /// Lists every speaker folder and every `.wav` that has a `.phn` beside it.
    pub fn open(root: &Path) -> Result<Self, CorpusError> {
        let mut speakers = Vec::new();
        for dir in sorted_entries(root)? {
            if !dir.is_dir() {
                continue;
            }
            let name = dir
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            let utterances: Vec<Utterance> = sorted_entries(&dir)?
                .into_iter()
                .filter(|p| p.extension().is_some_and(|e| e == "wav"))
                .filter_map(|wav| {
                    let phn = wav.with_extension("phn");
                    phn.is_file().then(|| Utterance {
                        speaker: name.clone(),
                        id: wav
                            .file_stem()
                            .unwrap_or_default()
                            .to_string_lossy()
                            .into_owned(),
                        wav,
                        phn,
                    })
                })
                .collect();
            if !utterances.is_empty() {
                speakers.push(Speaker { name, utterances });
            }
        }
        if speakers.is_empty() {
            return Err(CorpusError::Empty {
                path: root.to_path_buf(),
            });
        }
        Ok(Self {
            root: root.to_path_buf(),
            speakers,
        })
    }

    pub fn speaker(&self, name: &str) -> Result<&Speaker, CorpusError> {
        self.speakers
            .iter()
            .find(|s| s.name == name)
            .ok_or_else(|| CorpusError::UnknownSpeaker(name.to_string()))
    }

    /// All utterances of the named speakers, in order.
    pub fn utterances_of(&self, speakers: &[String]) -> Result<Vec<&Utterance>, CorpusError> {
        let mut all = Vec::new();
        for name in speakers {
            all.extend(self.speaker(name)?.utterances.iter());
        }
        Ok(all)
    }
}

/// Which speakers train, which steer early stopping, and which are kept for the final test.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpeakerSplit {
    pub train: Vec<String>,
    pub validation: Vec<String>,
    pub test: Vec<String>,
}

impl SpeakerSplit {
    /// The project's fixed split of the 12-speaker TIMIT sample by dialect region:
    /// TEST = dr5 and dr6 (4 speakers, never used for any tuning), VALIDATION = dr4 (2 speakers,
    /// early stopping and model choice), TRAIN = dr1 to dr3 (6 speakers). Each role has as many
    /// women as men.
    pub fn standard(corpus: &Corpus) -> Result<Self, CorpusError> {
        let region = |prefixes: &[&str]| -> Vec<String> {
            corpus
                .speakers
                .iter()
                .filter(|s| prefixes.iter().any(|p| s.name.starts_with(p)))
                .map(|s| s.name.clone())
                .collect()
        };
        let split = Self {
            train: region(&["dr1-", "dr2-", "dr3-"]),
            validation: region(&["dr4-"]),
            test: region(&["dr5-", "dr6-"]),
        };
        for (role, speakers) in [
            ("training", &split.train),
            ("validation", &split.validation),
            ("test", &split.test),
        ] {
            if speakers.is_empty() {
                return Err(CorpusError::EmptySplit(role));
            }
        }
        Ok(split)
    }
}

/// One labelled phone, in samples.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PhoneSegment {
    pub start: u64,
    pub end: u64,
    pub phone: String,
}

/// Reads a TIMIT `.phn` file.
pub fn read_phones(path: &Path) -> Result<Vec<PhoneSegment>, CorpusError> {
    let text = crate::input::read_to_string(path, crate::input::MAX_INPUT_BYTES)?;
    parse_phones(&text).map_err(|(line, message)| CorpusError::BadPhoneLine {
        path: path.to_path_buf(),
        line,
        message,
    })
}

fn parse_phones(text: &str) -> Result<Vec<PhoneSegment>, (usize, String)> {
    let mut segments: Vec<PhoneSegment> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.is_empty() {
            continue;
        }
        let [start, end, phone] = fields[..] else {
            return Err((i + 1, format!("expected `start end phone`, found {line:?}")));
        };
        let parse = |s: &str| {
            s.parse::<u64>()
                .map_err(|_| (i + 1, format!("bad sample number {s:?}")))
        };
        let (start, end) = (parse(start)?, parse(end)?);
        if end < start {
            return Err((
                i + 1,
                format!("segment ends ({end}) before it starts ({start})"),
            ));
        }
        segments.push(PhoneSegment {
            start,
            end,
            phone: phone.to_string(),
        });
    }
    Ok(segments)
}

/// Sample rate and length of a WAV file, from its header.
pub fn wav_length(path: &Path) -> Result<(u32, u32), CorpusError> {
    let reader = crate::audio::wav::open(path)?;
    let rate = reader.spec().sample_rate;
    let samples = reader.duration();
    if rate == 0 || (samples as f64) < rate as f64 * FRAME_SECONDS {
        return Err(CorpusError::AudioTooShort {
            path: path.to_path_buf(),
            samples,
            rate,
        });
    }
    Ok((rate, samples))
}

/// Phone-derived targets of an utterance, one per 20 ms frame.
#[derive(Debug, Clone, PartialEq)]
pub struct UtteranceTargets {
    /// Coarticulated weights over the 15 visemes.
    pub weights: Vec<FullWeights>,
    /// Frames overlapping each /p b m/ segment (runs of bilabial phones and their closures).
    pub bilabial_segments: Vec<Range<usize>>,
    /// Frames where closed lips are expected or harmless: bilabials and silences, widened by
    /// [`CLOSURE_MARGIN_FRAMES`] on each side. A closure anywhere else is a false closure.
    pub closure_allowed: Vec<bool>,
    /// Frames of each open-vowel, rounded and /f v/ segment long enough to be scored (with the
    /// class's slack on each side), for the per-segment cue scores.
    pub cue_segments: Vec<(CueClass, Range<usize>)>,
    /// Frames within [`CLOSURE_MARGIN_FRAMES`] of an /f v/: the lower lip under the teeth
    /// anywhere else is a false /f v/.
    pub labiodental_allowed: Vec<bool>,
}

/// Frames around a bilabial or a silence in which the lips may still be closing or opening.
pub const CLOSURE_MARGIN_FRAMES: usize = 2;

impl UtteranceTargets {
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// Keeps the first `frames` frames.
    pub fn truncate(&mut self, frames: usize) {
        self.weights.truncate(frames);
        self.closure_allowed.truncate(frames);
        for seg in &mut self.bilabial_segments {
            seg.end = seg.end.min(frames);
        }
        self.bilabial_segments.retain(|s| !s.is_empty());
        for (_, seg) in &mut self.cue_segments {
            seg.end = seg.end.min(frames);
        }
        self.cue_segments.retain(|(_, s)| !s.is_empty());
        self.labiodental_allowed.truncate(frames);
    }

    /// Whether frame `n` lies in a bilabial segment.
    pub fn in_bilabial(&self, n: usize) -> bool {
        self.bilabial_segments.iter().any(|s| s.contains(&n))
    }
}

/// Targets from timed phones of an utterance `samples` long at `rate` Hz.
pub fn targets_from_phones(
    phones: &[PhoneSegment],
    rate: u32,
    samples: u32,
) -> Result<UtteranceTargets, (usize, UnknownPhone)> {
    let seconds = |s: u64| s as f64 / rate as f64;
    let frame_count = (seconds(samples as u64) / FRAME_SECONDS).floor() as usize;
    let timed = phones
        .iter()
        .enumerate()
        .map(|(i, p)| {
            Ok(TimedTarget {
                start_s: seconds(p.start),
                end_s: seconds(p.end),
                target: phone_target(&p.phone).map_err(|e| (i + 1, e))?,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let first_frame = |s: u64| ((seconds(s) / FRAME_SECONDS).floor() as usize).min(frame_count);
    let end_frame = |s: u64| ((seconds(s) / FRAME_SECONDS).ceil() as usize).min(frame_count);

    let mut bilabial_segments: Vec<Range<usize>> = Vec::new();
    let mut run: Option<(u64, u64)> = None;
    for p in phones.iter().map(Some).chain([None]) {
        match (p, run) {
            (Some(p), Some((start, end))) if is_bilabial(&p.phone) && p.start <= end => {
                run = Some((start, p.end.max(end)))
            }
            (p, current) => {
                if let Some((start, end)) = current {
                    let frames = first_frame(start)..end_frame(end);
                    if !frames.is_empty() {
                        bilabial_segments.push(frames);
                    }
                }
                run = p
                    .filter(|p| is_bilabial(&p.phone))
                    .map(|p| (p.start, p.end));
            }
        }
    }
    let mut closure_allowed = vec![false; frame_count];
    let mut labiodental_allowed = vec![false; frame_count];
    for p in phones
        .iter()
        .filter(|p| CueClass::of(&p.phone) == Some(CueClass::Labiodental))
    {
        let from = first_frame(p.start).saturating_sub(CLOSURE_MARGIN_FRAMES);
        let to = (end_frame(p.end) + CLOSURE_MARGIN_FRAMES).min(frame_count);
        labiodental_allowed[from..to].fill(true);
    }
    for p in phones {
        let silent = matches!(p.phone.as_str(), "h#" | "pau" | "epi");
        if silent || is_bilabial(&p.phone) {
            let from = first_frame(p.start).saturating_sub(CLOSURE_MARGIN_FRAMES);
            let to = (end_frame(p.end) + CLOSURE_MARGIN_FRAMES).min(frame_count);
            closure_allowed[from..to].fill(true);
        }
    }
    let cue_segments = phones
        .iter()
        .filter_map(|p| {
            let class = CueClass::of(&p.phone)?;
            if seconds(p.end) - seconds(p.start) < class.min_seconds() - 1e-9 {
                return None;
            }
            let slack = class.slack_frames();
            let frames = first_frame(p.start).saturating_sub(slack)
                ..(end_frame(p.end) + slack).min(frame_count);
            (!frames.is_empty()).then_some((class, frames))
        })
        .collect();
    Ok(UtteranceTargets {
        weights: frame_targets(&timed, frame_count),
        bilabial_segments,
        closure_allowed,
        cue_segments,
        labiodental_allowed,
    })
}

/// Targets of a corpus utterance.
pub fn utterance_targets(utt: &Utterance) -> Result<UtteranceTargets, CorpusError> {
    let (rate, samples) = wav_length(&utt.wav)?;
    let phones = read_phones(&utt.phn)?;
    targets_from_phones(&phones, rate, samples).map_err(|(line, source)| {
        CorpusError::UnknownPhone {
            path: utt.phn.clone(),
            line,
            source,
        }
    })
}

/// Decoder features and targets of one utterance, cut to the same number of frames.
#[derive(Debug, Clone)]
pub struct PreparedUtterance {
    pub speaker: String,
    pub id: String,
    pub features: Vec<FrameFeatures>,
    pub targets: UtteranceTargets,
    /// Loss weight of its frames in training (per corpus: hand labels count fully,
    /// automatic alignments less).
    pub weight: f32,
}

pub fn prepare(
    utterances: &[&Utterance],
    features: &FeatureFn,
) -> Result<Vec<PreparedUtterance>, CorpusError> {
    utterances
        .iter()
        .map(|utt| {
            let mut targets = utterance_targets(utt)?;
            let mut frames = features(&utt.wav).map_err(|source| CorpusError::Features {
                path: utt.wav.clone(),
                source,
            })?;
            let n = frames.len().min(targets.len());
            frames.truncate(n);
            targets.truncate(n);
            Ok(PreparedUtterance {
                speaker: utt.speaker.clone(),
                id: utt.id.clone(),
                features: frames,
                targets,
                weight: 1.0,
            })
        })
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::vocab::Viseme;

    pub(crate) fn timit_root() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/timit-sample")
    }

    #[test]
    fn standard_split_uses_every_speaker_once() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        assert_eq!(corpus.speakers.len(), 12);
        assert!(corpus.speakers.iter().all(|s| s.utterances.len() == 10));
        let split = SpeakerSplit::standard(&corpus).unwrap();
        assert_eq!(
            (split.train.len(), split.validation.len(), split.test.len()),
            (6, 2, 4)
        );
        let mut all: Vec<&String> = split
            .train
            .iter()
            .chain(&split.validation)
            .chain(&split.test)
            .collect();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), 12);
        assert!(corpus.utterances_of(&["nobody".into()]).is_err());
    }

    #[test]
    fn real_timit_files_parse_into_targets() {
        let corpus = Corpus::open(&timit_root()).unwrap();
        let utt = corpus
            .speaker("dr1-fvmh0")
            .unwrap()
            .utterances
            .iter()
            .find(|u| u.id == "sa1")
            .unwrap();
        let phones = read_phones(&utt.phn).unwrap();
        assert_eq!(
            phones[0],
            PhoneSegment {
                start: 0,
                end: 7812,
                phone: "h#".into()
            }
        );
        let targets = utterance_targets(utt).unwrap();
        let (rate, samples) = wav_length(&utt.wav).unwrap();
        assert_eq!(rate, 16000);
        assert_eq!(targets.len(), samples as usize / 320);
        assert_eq!(targets.closure_allowed.len(), targets.len());
        // "She had your dark suit in greasy wash water all year" has no /p b m/ ...
        // but every TIMIT target is convex and starts in silence.
        assert!(targets.weights[0][Viseme::Sil.index()] > 0.9);
        for w in &targets.weights {
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-4);
        }
        // sa2 "Don't ask me to carry an oily rag like that": one /m/.
        let sa2 = corpus
            .speaker("dr1-fvmh0")
            .unwrap()
            .utterances
            .iter()
            .find(|u| u.id == "sa2")
            .unwrap();
        let targets = utterance_targets(sa2).unwrap();
        assert_eq!(targets.bilabial_segments.len(), 1);
        let seg = targets.bilabial_segments[0].clone();
        let peak = seg
            .map(|n| targets.weights[n][Viseme::PP.index()])
            .fold(0.0, f32::max);
        assert!(peak > 0.9, "{peak}");
    }

    #[test]
    fn bilabial_runs_merge_and_bad_phone_files_are_errors() {
        let phones = parse_phones("0 3200 h#\n3200 4800 aa\n4800 5600 pcl\n5600 6000 p\n6000 8000 aa\n8000 9600 m\n9600 12800 h#\n").unwrap();
        let targets = targets_from_phones(&phones, 16000, 12800).unwrap();
        // pcl+p = 0.30..0.375 s = frames 15..19; m = 0.5..0.6 s = frames 25..30.
        assert_eq!(targets.bilabial_segments, vec![15..19, 25..30]);
        assert!(targets.closure_allowed[13] && !targets.closure_allowed[21]);
        assert!(parse_phones("0 10\n").is_err());
        assert!(parse_phones("10 0 aa\n").is_err());
        assert!(parse_phones("a 10 aa\n").is_err());
        let unknown = parse_phones("0 3200 zz\n").unwrap();
        assert!(targets_from_phones(&unknown, 16000, 3200).is_err());
    }

    #[test]
    fn missing_or_short_audio_is_an_error() {
        let dir = std::env::temp_dir().join(format!("lipcall-short-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("short.wav");
        let spec = hound::WavSpec {
            channels: 1,
            sample_rate: 16000,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut writer = hound::WavWriter::create(&path, spec).unwrap();
        for _ in 0..100 {
            writer.write_sample(0i16).unwrap();
        }
        writer.finalize().unwrap();
        assert!(matches!(
            wav_length(&path),
            Err(CorpusError::AudioTooShort { samples: 100, .. })
        ));
        assert!(matches!(
            wav_length(&dir.join("none.wav")),
            Err(CorpusError::WavFile(_))
        ));
        assert!(matches!(Corpus::open(&dir), Err(CorpusError::Empty { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

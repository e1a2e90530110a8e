//! CMU AN4 as a training corpus: its audio stays where the corpus lives
//! (`<audio root>/wav/an4_clstk/<speaker>/<utt>.wav` for AN4's 74 training speakers,
//! `wav/an4test_clstk/...` for its 10 test speakers) and its phone labels, made by forced
//! alignment (`tools/align_an4.py`), live in the repository under
//! `tools/alignments/an4/<speaker>/<utt>.phn`. [`open_aligned`] pairs the two into the
//! project's [`Corpus`].
//!
//! Speakers are named `an4-<speaker>` so that they never collide with TIMIT's `dr<N>-<speaker>`.
//! The labels are machine-made (about 76 % of boundaries within 20 ms of hand labels, see
//! `tools/alignments/an4/README.md`): fit for training, not for testing.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::corpus::{Corpus, CorpusError, Speaker, Utterance};

/// The folders under `<audio root>/wav`, and whether they hold AN4's test speakers.
pub const AUDIO_PARTS: [(&str, bool); 2] = [("an4_clstk", false), ("an4test_clstk", true)];

/// Prefix of every AN4 speaker name in a [`Corpus`].
pub const SPEAKER_PREFIX: &str = "an4-";

/// The alignments committed with the project.
pub fn default_labels_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/alignments/an4")
}

/// Where the project's environment keeps the AN4 audio (read-only, outside the repository).
pub fn default_audio_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/an4")
}

/// What pairing the audio with the labels found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AlignmentStats {
    /// WAVs with a label file: the utterances of the corpus.
    pub paired: usize,
    /// WAVs without one (the aligner skipped them), as `<speaker>/<utt>`; left out.
    pub unlabelled: Vec<String>,
    /// Speakers (prefixed names) of AN4's own test set, `wav/an4test_clstk`, that are in the
    /// corpus.
    pub test_speakers: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum An4Error {
    #[error(
        "{path}: no AN4 audio (expected wav/an4_clstk/<speaker>/<utt>.wav or wav/an4test_clstk/...)"
    )]
    NoAudio { path: PathBuf },
    #[error("{path}: the AN4 labels folder is missing (tools/align_an4.py makes it)")]
    NoLabels { path: PathBuf },
    #[error(
        "{labels}: a corpus folder without alignments: none of the {wavs} WAVs under {audio} has a <speaker>/<utt>.phn here"
    )]
    NoAlignments {
        audio: PathBuf,
        labels: PathBuf,
        wavs: usize,
    },
    #[error(transparent)]
    Corpus(#[from] CorpusError),
}

fn sorted_entries(dir: &Path) -> Result<Vec<PathBuf>, CorpusError> {
    let io = |source| CorpusError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut entries = std::fs::read_dir(dir)
        .map_err(io)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(io)?;
    entries.sort();
    Ok(entries)
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned()
}

/// Opens AN4 with its audio under `audio_root` (`wav/an4_clstk`, `wav/an4test_clstk`) and its
/// labels under `labels_root` (`<speaker>/<utt>.phn`). WAVs without labels are counted in the
/// stats and left out; speakers without any labelled WAV are left out. The corpus's `root` is
/// `audio_root`; speakers are sorted by name, utterances by file name.
pub fn open_aligned(
    audio_root: &Path,
    labels_root: &Path,
) -> Result<(Corpus, AlignmentStats), An4Error> {
    if !labels_root.is_dir() {
        return Err(An4Error::NoLabels {
            path: labels_root.to_path_buf(),
        });
    }
    let mut by_speaker: BTreeMap<String, Vec<Utterance>> = BTreeMap::new();
    let mut stats = AlignmentStats::default();
    let mut wavs = 0;
    for (part, is_test) in AUDIO_PARTS {
        let part_dir = audio_root.join("wav").join(part);
        if !part_dir.is_dir() {
            continue;
        }
        for dir in sorted_entries(&part_dir)? {
            if !dir.is_dir() {
                continue;
            }
            let speaker = file_name(&dir);
            let name = format!("{SPEAKER_PREFIX}{speaker}");
            for wav in sorted_entries(&dir)? {
                if wav.extension().is_none_or(|e| e != "wav") {
                    continue;
                }
                wavs += 1;
                let id = wav
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned();
                let phn = labels_root.join(&speaker).join(format!("{id}.phn"));
                if !phn.is_file() {
                    stats.unlabelled.push(format!("{speaker}/{id}"));
                    continue;
                }
                stats.paired += 1;
                if is_test && !stats.test_speakers.contains(&name) {
                    stats.test_speakers.push(name.clone());
                }
                by_speaker.entry(name.clone()).or_default().push(Utterance {
                    speaker: name.clone(),
                    id,
                    wav,
                    phn,
                });
            }
        }
    }
    if wavs == 0 {
        return Err(An4Error::NoAudio {
            path: audio_root.to_path_buf(),
        });
    }
    if stats.paired == 0 {
        return Err(An4Error::NoAlignments {
            audio: audio_root.to_path_buf(),
            labels: labels_root.to_path_buf(),
            wavs,
        });
    }
    stats.test_speakers.sort();
    let speakers = by_speaker
        .into_iter()
        .map(|(name, utterances)| Speaker { name, utterances })
        .collect();
    let corpus = Corpus {
        root: audio_root.to_path_buf(),
        speakers,
    };
    Ok((corpus, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::phones::phone_target;
    use crate::train::corpus::{read_phones, wav_length};

    fn touch(path: &Path) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, b"").unwrap();
    }

    /// Audio of two training speakers and one test speaker; labels for some of it.
    fn fixture() -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let audio = dir.path().join("audio/wav");
        for wav in [
            "an4_clstk/fabc/an1-fabc-b.wav",
            "an4_clstk/fabc/an2-fabc-b.wav",
            "an4_clstk/fabc/notes.txt",
            "an4_clstk/mxyz/cen1-mxyz-b.wav",
            "an4test_clstk/ftst/an9-ftst-b.wav",
        ] {
            touch(&audio.join(wav));
        }
        for phn in [
            "fabc/an2-fabc-b.phn",
            "fabc/an7-fabc-b.phn", // no WAV: ignored
            "ftst/an9-ftst-b.phn",
        ] {
            touch(&dir.path().join("labels").join(phn));
        }
        dir
    }

    #[test]
    fn pairs_audio_with_labels_and_counts_the_rest() {
        let dir = fixture();
        let (audio, labels) = (dir.path().join("audio"), dir.path().join("labels"));
        let (corpus, stats) = open_aligned(&audio, &labels).unwrap();
        assert_eq!(corpus.root, audio);
        let names: Vec<&str> = corpus.speakers.iter().map(|s| s.name.as_str()).collect();
        // mxyz has no labelled WAV at all: left out.
        assert_eq!(names, ["an4-fabc", "an4-ftst"]);
        let fabc = corpus.speaker("an4-fabc").unwrap();
        assert_eq!(
            fabc.utterances,
            vec![Utterance {
                speaker: "an4-fabc".into(),
                id: "an2-fabc-b".into(),
                wav: audio.join("wav/an4_clstk/fabc/an2-fabc-b.wav"),
                phn: labels.join("fabc/an2-fabc-b.phn"),
            }]
        );
        assert_eq!(
            corpus.speaker("an4-ftst").unwrap().utterances[0].wav,
            audio.join("wav/an4test_clstk/ftst/an9-ftst-b.wav")
        );
        assert_eq!(
            stats,
            AlignmentStats {
                paired: 2,
                unlabelled: vec!["fabc/an1-fabc-b".into(), "mxyz/cen1-mxyz-b".into()],
                test_speakers: vec!["an4-ftst".into()],
            }
        );
    }

    #[test]
    fn folders_without_labels_or_audio_are_errors() {
        let dir = fixture();
        let audio = dir.path().join("audio");
        let missing = dir.path().join("no-such-labels");
        let err = open_aligned(&audio, &missing).unwrap_err();
        assert!(matches!(&err, An4Error::NoLabels { path } if *path == missing));

        let empty = dir.path().join("empty-labels");
        std::fs::create_dir(&empty).unwrap();
        let err = open_aligned(&audio, &empty).unwrap_err();
        assert!(
            matches!(err, An4Error::NoAlignments { wavs: 4, .. }),
            "{err:?}"
        );
        assert!(
            err.to_string()
                .contains("a corpus folder without alignments")
        );

        let labels = dir.path().join("labels");
        let err = open_aligned(&dir.path().join("no-audio"), &labels).unwrap_err();
        assert!(matches!(err, An4Error::NoAudio { .. }), "{err:?}");
    }

    #[test]
    fn committed_alignments_are_timit_phones_covering_the_audio() {
        let audio = default_audio_root();
        if !audio.join("wav").is_dir() {
            assert!(
                std::env::var_os("CI").is_none(),
                "no AN4 audio at {}: CI must provide it",
                audio.display()
            );
            println!("skipped: no AN4 audio at {}", audio.display());
            return;
        }
        let (corpus, stats) = open_aligned(&audio, &default_labels_root()).unwrap();
        assert_eq!(corpus.speakers.len(), 84);
        assert_eq!(stats.paired, 1078);
        assert!(stats.unlabelled.is_empty(), "{:?}", stats.unlabelled);
        assert_eq!(stats.test_speakers.len(), 10);
        // A training utterance, the one aligned on the padded second try (its audio stops
        // mid-word), and a test-set utterance.
        for (speaker, id) in [
            ("an4-fash", "an251-fash-b"),
            ("an4-fash", "cen7-fash-b"),
            ("an4-fcaw", "an406-fcaw-b"),
        ] {
            let utt = corpus
                .speaker(speaker)
                .unwrap()
                .utterances
                .iter()
                .find(|u| u.id == id)
                .unwrap();
            let phones = read_phones(&utt.phn).unwrap();
            let (rate, samples) = wav_length(&utt.wav).unwrap();
            assert_eq!(rate, 16000);
            assert!(phones.len() >= 3, "{id}: {phones:?}");
            assert_eq!(phones[0].start, 0, "{id}");
            assert_eq!(phones.last().unwrap().end, u64::from(samples), "{id}");
            for pair in phones.windows(2) {
                assert_eq!(pair[0].end, pair[1].start, "{id}: {pair:?}");
            }
            for p in &phones {
                assert!(p.end > p.start, "{id}: {p:?}");
                assert!(phone_target(&p.phone).is_ok(), "{id}: {p:?}");
            }
        }
    }
}

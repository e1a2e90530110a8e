//! What `receive` writes, streamed while it plays: OUT.wav (all peers mixed), FEATURES.csv and
//! WEIGHTS.csv (one file per peer), and the signals that end a receive cleanly.
//!
//! Every file is created before the call starts (a path that cannot be written fails then, not
//! after the call), written as frames play, and made whole about once a second (the WAV's
//! header counts what was written), so even a killed receive leaves files that read.

use std::collections::{HashMap, HashSet};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};

use crate::call::csv;
use crate::vocab::FrameFeatures;
use crate::vocab::SAMPLE_RATE;

/// One 20 ms tick of the output timeline.
pub(crate) const TICK: Duration = Duration::from_millis(20);

/// Ticks between the points where every file is made whole on disk.
const SYNC_TICKS: usize = 50;

/// Set by SIGINT or SIGTERM. A second signal while it is set ends the process at once.
static STOP: OnceLock<std::io::Result<Arc<AtomicBool>>> = OnceLock::new();

/// The flag SIGINT and SIGTERM set (installed on first use): the receive loop ends at its next
/// tick and its files are finished.
pub(crate) fn stop_flag() -> Result<Arc<AtomicBool>> {
    let installed = STOP.get_or_init(|| {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let flag = Arc::new(AtomicBool::new(false));
        for signal in [SIGINT, SIGTERM] {
            // The shutdown first: it sees the flag before this signal sets it.
            signal_hook::flag::register_conditional_shutdown(signal, 130, Arc::clone(&flag))?;
            signal_hook::flag::register(signal, Arc::clone(&flag))?;
        }
        Ok(flag)
    });
    match installed {
        Ok(flag) => Ok(Arc::clone(flag)),
        Err(e) => Err(anyhow::anyhow!("cannot handle SIGINT/SIGTERM: {e}")),
    }
}

/// Whether a signal asked the receive to end.
pub(crate) fn stopped(flag: &AtomicBool) -> bool {
    flag.load(Ordering::Relaxed)
}

type Csv = BufWriter<File>;

fn create(path: &Path) -> Result<Csv> {
    let file = File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(BufWriter::new(file))
}

/// One peer's CSV files.
struct PeerFiles {
    features: Option<(PathBuf, Csv)>,
    weights: Option<(PathBuf, Csv)>,
}

/// The outputs of one receive, written as it plays.
pub(crate) struct Recorder {
    wav: Option<(PathBuf, hound::WavWriter<BufWriter<File>>)>,
    /// The mix's rate: asked for, or the first audible streams' own (fixed then).
    rate: Option<u32>,
    /// The rate OUT.wav's header says so far.
    wav_rate: u32,
    features: Option<PathBuf>,
    weights: Option<PathBuf>,
    /// WEIGHTS.csv's header after `frame,time_s`.
    viseme_names: Vec<String>,
    /// The files the first peer takes (created up front, so that a receive nobody called still
    /// leaves them, header only).
    first: Option<PeerFiles>,
    /// The peer that took them.
    first_ssrc: Option<u32>,
    peers: HashMap<u32, PeerFiles>,
    /// Peers gone whose files were closed: one who comes back appends to its own.
    released: HashSet<u32>,
    /// Silent ticks after the last audible one: written only when audio follows (the WAV ends
    /// with the last audio played).
    pending_silence: usize,
    /// Ticks written to the WAV.
    ticks: usize,
    since_sync: usize,
}

fn time_of(frame: usize) -> f64 {
    frame as f64 * TICK.as_secs_f64()
}

impl Recorder {
    /// Creates the files now: OUT.wav, and the first peer's FEATURES.csv and WEIGHTS.csv (with
    /// `viseme_names` as its columns).
    /// OUT.wav is at `rate` if given, else at the rate of the streams first heard (8 kHz if
    /// none is).
    pub(crate) fn create(
        wav: Option<&Path>,
        rate: Option<u32>,
        features: Option<&Path>,
        weights: Option<&Path>,
        viseme_names: Vec<String>,
    ) -> Result<Self> {
        let wav_rate = rate.unwrap_or(SAMPLE_RATE);
        let wav = match wav {
            Some(path) => Some((path.to_path_buf(), wav_writer(path, wav_rate)?)),
            None => None,
        };
        let mut recorder = Self {
            wav,
            rate,
            wav_rate,
            features: features.map(Path::to_path_buf),
            weights: weights.map(Path::to_path_buf),
            viseme_names,
            first: None,
            first_ssrc: None,
            peers: HashMap::new(),
            released: HashSet::new(),
            pending_silence: 0,
            ticks: 0,
            since_sync: 0,
        };
        recorder.first = Some(recorder.peer_files(None)?);
        recorder.sync()?;
        Ok(recorder)
    }

    /// A peer's files: the first peer's at the paths given, a later one's at
    /// `NAME-<ssrc>.csv` beside them.
    fn peer_files(&self, ssrc: Option<u32>) -> Result<PeerFiles> {
        let target = |path: &PathBuf| match ssrc {
            Some(ssrc) => peer_path(path, ssrc),
            None => path.clone(),
        };
        let features = match &self.features {
            Some(path) => {
                let path = target(path);
                let mut out = create(&path)?;
                csv::features_header(&mut out)
                    .with_context(|| format!("writing {}", path.display()))?;
                Some((path, out))
            }
            None => None,
        };
        let weights = match &self.weights {
            Some(path) => {
                let path = target(path);
                let mut out = create(&path)?;
                csv::weights_header(&mut out, &self.viseme_names)
                    .with_context(|| format!("writing {}", path.display()))?;
                Some((path, out))
            }
            None => None,
        };
        Ok(PeerFiles { features, weights })
    }

    fn peer(&mut self, ssrc: u32) -> Result<&mut PeerFiles> {
        if !self.peers.contains_key(&ssrc) {
            let files = if self.released.contains(&ssrc) {
                self.reopen(ssrc)?
            } else {
                match self.first.take() {
                    Some(files) => {
                        self.first_ssrc = Some(ssrc);
                        files
                    }
                    None => self.peer_files(Some(ssrc))?,
                }
            };
            self.peers.insert(ssrc, files);
        }
        self.peers
            .get_mut(&ssrc)
            .context("a peer's files were just made")
    }

    /// A peer gone from the call: its files are finished and closed (a flood of short-lived
    /// SSRCs must not hold a file each for the rest of the call).
    pub(crate) fn release(&mut self, ssrc: u32) -> Result<()> {
        let Some(mut files) = self.peers.remove(&ssrc) else {
            return Ok(());
        };
        for (path, out) in files.features.iter_mut().chain(files.weights.iter_mut()) {
            out.flush()
                .with_context(|| format!("writing {}", path.display()))?;
        }
        self.released.insert(ssrc);
        Ok(())
    }

    /// The files of a peer released before, opened again to go on where they ended.
    fn reopen(&self, ssrc: u32) -> Result<PeerFiles> {
        let target = |path: &PathBuf| {
            if self.first_ssrc == Some(ssrc) {
                path.clone()
            } else {
                peer_path(path, ssrc)
            }
        };
        let append = |path: &Option<PathBuf>| -> Result<Option<(PathBuf, Csv)>> {
            let Some(path) = path.as_ref().map(target) else {
                return Ok(None);
            };
            let file = File::options()
                .append(true)
                .open(&path)
                .with_context(|| format!("cannot write {}", path.display()))?;
            Ok(Some((path, BufWriter::new(file))))
        };
        Ok(PeerFiles {
            features: append(&self.features)?,
            weights: append(&self.weights)?,
        })
    }

    /// Whether the mix is written anywhere.
    pub(crate) fn wants_audio(&self) -> bool {
        self.wav.is_some()
    }

    /// The rate the mix is written at: the one asked for, or fixed now to `heard`, the rate of
    /// the streams of the first audible tick (OUT.wav, still empty, is made anew at it).
    pub(crate) fn mix_rate(&mut self, heard: u32) -> Result<u32> {
        if let Some(rate) = self.rate {
            return Ok(rate);
        }
        self.rate = Some(heard);
        if let Some((path, _)) = &self.wav {
            eprintln!(
                "lipcall: {} at {heard} Hz, the rate of the stream first heard",
                path.display()
            );
        }
        if heard != self.wav_rate {
            if let Some((path, old)) = self.wav.take() {
                // Finished first: its header must not land on the new file.
                let _ = old.finalize();
                self.wav = Some((path.clone(), wav_writer(&path, heard)?));
            }
            self.wav_rate = heard;
        }
        Ok(heard)
    }

    /// The next tick of the mix, 20 ms at [`Recorder::mix_rate`]; `audible`: some peer played
    /// in it.
    pub(crate) fn audio(&mut self, mix: &[i16], audible: bool) -> Result<()> {
        if !audible {
            self.pending_silence += 1;
            return Ok(());
        }
        let silence = std::mem::take(&mut self.pending_silence);
        let tick = self.wav_rate as usize / 50;
        if let Some((path, wav)) = &mut self.wav {
            let samples = std::iter::repeat_n(0, silence * tick).chain(mix.iter().copied());
            for s in samples {
                wav.write_sample(s)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        self.ticks += silence + 1;
        self.since_sync += silence + 1;
        if self.since_sync >= SYNC_TICKS {
            self.since_sync = 0;
            self.sync()?;
        }
        Ok(())
    }

    /// A peer's feature row for output tick `frame`.
    pub(crate) fn features(
        &mut self,
        ssrc: u32,
        frame: usize,
        features: &FrameFeatures,
    ) -> Result<()> {
        if self.features.is_none() {
            return Ok(());
        }
        let Some((path, out)) = &mut self.peer(ssrc)?.features else {
            return Ok(());
        };
        csv::features_row(out, frame, time_of(frame), features)
            .with_context(|| format!("writing {}", path.display()))
    }

    /// A peer's weights for output tick `frame` (empty: none came for it).
    pub(crate) fn weights(&mut self, ssrc: u32, frame: usize, weights: &[f32]) -> Result<()> {
        if self.weights.is_none() {
            return Ok(());
        }
        let Some((path, out)) = &mut self.peer(ssrc)?.weights else {
            return Ok(());
        };
        csv::weights_row(out, frame, time_of(frame), weights)
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Seconds of audio written (what was played, up to its last audible tick).
    pub(crate) fn seconds(&self) -> f64 {
        time_of(self.ticks)
    }

    /// Everything written so far made whole on disk: the WAV's header updated, CSVs flushed.
    fn sync(&mut self) -> Result<()> {
        if let Some((path, wav)) = &mut self.wav {
            wav.flush()
                .with_context(|| format!("writing {}", path.display()))?;
        }
        let files = self.first.iter_mut().chain(self.peers.values_mut());
        for files in files {
            for (path, out) in files.features.iter_mut().chain(files.weights.iter_mut()) {
                out.flush()
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        Ok(())
    }

    /// Finishes every file (the trailing silence is left out).
    pub(crate) fn finish(mut self) -> Result<()> {
        self.sync()?;
        if let Some((path, wav)) = self.wav.take() {
            wav.finalize()
                .with_context(|| format!("writing {}", path.display()))?;
        }
        Ok(())
    }
}

fn wav_writer(path: &Path, rate: u32) -> Result<hound::WavWriter<BufWriter<File>>> {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    hound::WavWriter::create(path, spec).with_context(|| format!("cannot write {}", path.display()))
}

/// FEATURES.csv of a second or later peer: `NAME-<ssrc>.csv` beside the first.
fn peer_path(path: &Path, ssrc: u32) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!("{stem}-{ssrc:08x}.csv"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vocab::FRAME_SIZE;

    fn read(path: &Path) -> String {
        std::fs::read_to_string(path).unwrap()
    }

    #[test]
    fn trailing_silence_is_left_out_and_inner_silence_kept() {
        let dir = tempfile::tempdir().unwrap();
        let wav = dir.path().join("out.wav");
        let mut rec = Recorder::create(Some(&wav), None, None, None, Vec::new()).unwrap();
        let loud = [1000i16; FRAME_SIZE];
        let quiet = [0i16; FRAME_SIZE];
        rec.audio(&loud, true).unwrap();
        rec.audio(&quiet, false).unwrap();
        rec.audio(&loud, true).unwrap();
        rec.audio(&quiet, false).unwrap();
        rec.audio(&quiet, false).unwrap();
        rec.finish().unwrap();
        let samples: Vec<i16> = hound::WavReader::open(&wav)
            .unwrap()
            .into_samples()
            .map(Result::unwrap)
            .collect();
        assert_eq!(samples.len(), 3 * FRAME_SIZE);
        assert!(samples[FRAME_SIZE..2 * FRAME_SIZE].iter().all(|&s| s == 0));
        assert_eq!(samples[2 * FRAME_SIZE], 1000);
    }

    #[test]
    fn the_first_peer_takes_the_paths_given_and_later_ones_their_own() {
        let dir = tempfile::tempdir().unwrap();
        let features = dir.path().join("f.csv");
        let weights = dir.path().join("w.csv");
        let names = vec!["sil".to_string(), "aa".to_string()];
        let mut rec = Recorder::create(None, None, Some(&features), Some(&weights), names).unwrap();
        // Created (header only) before anyone called.
        assert_eq!(read(&features).lines().count(), 1);
        assert_eq!(read(&weights), "frame,time_s,sil,aa\n");
        let row = FrameFeatures {
            mode: None,
            lsp: [0.5; 10],
            energy_db: 40.0,
            family: crate::vocab::FeatureFamily::Bitstream,
        };
        rec.features(7, 0, &row).unwrap();
        rec.weights(7, 0, &[0.25, 0.75]).unwrap();
        rec.features(9, 1, &row).unwrap();
        rec.finish().unwrap();
        assert_eq!(read(&features).lines().count(), 2);
        assert!(read(&weights).ends_with("0,0.000,0.2500,0.7500\n"));
        let second = read(&dir.path().join("f-00000009.csv"));
        assert!(second.lines().nth(1).unwrap().starts_with("1,0.020,"));
        assert_eq!(read(&dir.path().join("w-00000009.csv")).lines().count(), 1);
    }

    #[test]
    fn a_released_peer_that_comes_back_goes_on_in_its_own_file() {
        let dir = tempfile::tempdir().unwrap();
        let weights = dir.path().join("w.csv");
        let mut r = Recorder::create(None, None, None, Some(&weights), vec!["aa".into()]).unwrap();
        r.weights(7, 0, &[0.5]).unwrap();
        r.weights(9, 0, &[0.25]).unwrap();
        r.release(7).unwrap();
        r.release(9).unwrap();
        assert!(r.peers.is_empty());
        r.weights(9, 3, &[0.75]).unwrap();
        r.weights(7, 3, &[1.0]).unwrap();
        r.finish().unwrap();
        let first = read(&weights);
        assert_eq!(first.lines().count(), 3, "{first}");
        assert_eq!(first.matches("frame,").count(), 1, "{first}");
        let later = read(&peer_path(&weights, 9));
        assert_eq!(later.lines().count(), 3, "{later}");
        assert_eq!(later.matches("frame,").count(), 1, "{later}");
    }

    #[test]
    fn a_missing_directory_fails_before_anything_plays() {
        let dir = tempfile::tempdir().unwrap();
        let wav = dir.path().join("no/such/dir/out.wav");
        let err = Recorder::create(Some(&wav), None, None, None, Vec::new())
            .err()
            .unwrap();
        assert!(format!("{err:#}").contains("cannot write"), "{err:#}");
    }
}

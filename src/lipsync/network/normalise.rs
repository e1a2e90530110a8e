//! The input normalisation: each feature scaled onto [-1, 1] ([`InputScaling`]), the causal
//! per-speaker LSP normalisation ([`SpeakerNorm`]) and the energy-derived inputs ([`Dynamics`]).

use crate::vocab::FrameFeatures;
use crate::vocab::LSP_COUNT;

/// Features per frame: 10 LSPs and the energy.
pub const FEATURES_PER_FRAME: usize = LSP_COUNT + 1;

/// Per input: `scaled = clamp((x - offset) * scale, -1, 1)`.
#[derive(Debug, Clone, PartialEq)]
pub struct InputScaling {
    pub offset: [f32; FEATURES_PER_FRAME],
    pub scale: [f32; FEATURES_PER_FRAME],
}

impl InputScaling {
    /// LSPs from [0, pi] and the energy from `[energy_low_db, energy_high_db]` onto [-1, 1].
    pub fn new(energy_low_db: f32, energy_high_db: f32) -> Self {
        let half_pi = std::f32::consts::FRAC_PI_2;
        let mut offset = [half_pi; FEATURES_PER_FRAME];
        let mut scale = [1.0 / half_pi; FEATURES_PER_FRAME];
        offset[10] = 0.5 * (energy_low_db + energy_high_db);
        scale[10] = 2.0 / (energy_high_db - energy_low_db).max(1e-3);
        Self { offset, scale }
    }

    /// Writes the 11 scaled inputs of one frame into `out`.
    pub fn apply(&self, features: &FrameFeatures, out: &mut [f32]) {
        let raw = features
            .lsp
            .iter()
            .chain(std::iter::once(&features.energy_db));
        for (i, (o, &x)) in out.iter_mut().zip(raw).enumerate() {
            let scaled = (x - self.offset[i]) * self.scale[i];
            // NaN from a broken frame must not poison the history.
            *o = if scaled.is_nan() {
                0.0
            } else {
                scaled.clamp(-1.0, 1.0)
            };
        }
    }

    /// Energy in dB that maps to the scaled value `s` in [-1, 1].
    pub fn energy_db_at(&self, s: f32) -> f32 {
        self.offset[10] + s / self.scale[10]
    }
}

/// Stateful, causal inputs derived from the energy (model file version 2). A running peak
/// follows the loudest recent frame and falls by `peak_decay_db` per frame, so the energy
/// relative to it is independent of the talker's level and the codec's gain; the dip of a stop
/// closure shows in it and in the frame-to-frame energy change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dynamics {
    pub peak_decay_db: f32,
    /// Past frames beyond `context` whose peak-relative energy is fed as well.
    pub energy_context: usize,
}

/// The running peak never falls below this, so leading silence reads as quiet, not as loud.
pub const PEAK_FLOOR_DB: f32 = -55.0;
/// Peak-relative energy: 0 dB maps to 1, -40 dB to -1.
const RELATIVE_SPAN_DB: f32 = 20.0;
/// Energy change per frame: +-15 dB maps to +-1.
pub(super) const DELTA_SPAN_DB: f32 = 15.0;
pub(super) const MAX_ENERGY_CONTEXT: usize = 64;

/// Values fed per frame: 11 raw, 13 with dynamics.
pub fn frame_width(dynamics: Option<Dynamics>) -> usize {
    FEATURES_PER_FRAME + if dynamics.is_some() { 2 } else { 0 }
}

/// Causal per-speaker normalisation: a voice's LSPs sit higher or lower (vocal tract length,
/// microphone, codec) as a whole. The receiver follows the speaker's mean LSPs over speech
/// frames and moves every frame by the difference to the training speakers' mean, so a new voice
/// settles within a few seconds of speech.
#[derive(Debug, Clone, PartialEq)]
pub struct SpeakerNorm {
    /// Speech frames the running mean spans once settled.
    pub frames: u32,
    /// The training speakers' mean LSPs, where every speaker starts.
    pub prior: [f32; LSP_COUNT],
}

/// The prior counts as this many speech frames of the speaker's own.
pub(super) const NORM_PRIOR_FRAMES: u32 = 25;
/// Frames this far below the running peak (or below the floor) are not speech.
pub(super) const NORM_SPEECH_BELOW_PEAK_DB: f32 = 25.0;
pub(super) const MAX_NORM_FRAMES: u32 = 100_000;

pub(super) fn scale_relative(relative_db: f32) -> f32 {
    ((relative_db + RELATIVE_SPAN_DB) / RELATIVE_SPAN_DB).clamp(-1.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lipsync::network::Model;
    use crate::lipsync::network::fixtures::frame;
    use crate::vocab::VisemeSet;

    #[test]
    fn dynamics_track_the_energy_and_closure_snap_closes() {
        let mut model = Model::zeros_with(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            1,
            Some(Dynamics {
                peak_decay_db: 0.5,
                energy_context: 2,
            }),
            2,
        );
        assert_eq!(model.inputs(), 13 * 2 + 2);
        let mut state = model.new_state();
        let mut w = [0.0; 3];
        model.step(&mut state, &frame(-20.0), &mut w);
        // At the peak: relative energy 0 dB -> 1; a 20 dB rise clamps at +1.
        assert_eq!(&state.input()[11..13], &[1.0, 1.0]);
        model.step(&mut state, &frame(-40.0), &mut w);
        let relative = (-40.0 - (-20.5) + 20.0) / 20.0;
        assert!((state.input()[11] - relative).abs() < 1e-6);
        assert!((state.input()[12] + 1.0).abs() < 1e-6);
        // The older peak-relative energies follow the full frames.
        model.step(&mut state, &frame(-40.0), &mut w);
        assert_eq!(state.input()[26], 1.0);
        // Snap: uniform output (1/3) snaps at 0.3, not at 0.5.
        model.closure_snap = 0.5;
        model.step(&mut state, &frame(-40.0), &mut w);
        assert!((w[0] - 1.0 / 3.0).abs() < 1e-6);
        model.closure_snap = 0.3;
        model.step(&mut state, &frame(-40.0), &mut w);
        assert_eq!(w, [1.0, 0.0, 0.0]);
        assert_eq!(Model::from_text(&model.to_text()).unwrap(), model);
        assert_eq!(model.viseme_names(), ["PP", "aa", "I"]);
    }

    #[test]
    fn speaker_normalisation_takes_out_a_voices_offset_within_seconds() {
        let dynamics = Some(Dynamics {
            peak_decay_db: 0.15,
            energy_context: 0,
        });
        let mut model = Model::zeros_with(
            VisemeSet::reduced(3).unwrap(),
            InputScaling::new(-70.0, -10.0),
            0,
            dynamics,
            2,
        );
        let prior = FrameFeatures::silent().lsp;
        model.speaker_norm = Some(SpeakerNorm { frames: 150, prior });
        let voice = |shift: f32, n: usize| {
            let mut f = FrameFeatures::silent();
            f.energy_db = -25.0;
            for (i, l) in f.lsp.iter_mut().enumerate() {
                *l += shift + 0.05 * ((n + i) % 3) as f32;
            }
            f
        };
        let run = |model: &Model, shift: f32, frames: usize| {
            let mut state = model.new_state();
            for n in 0..frames {
                model.push_frame(&mut state, &voice(shift, n));
            }
            state.input()[..LSP_COUNT].to_vec()
        };
        let gap = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        // Three seconds of speech: the lower voice's inputs meet the prior voice's.
        assert!(gap(&run(&model, 0.0, 150), &run(&model, -0.08, 150)) < 0.01);
        // Without it they stay apart.
        let mut plain = model.clone();
        plain.speaker_norm = None;
        assert!(gap(&run(&plain, 0.0, 150), &run(&plain, -0.08, 150)) > 0.05);
        // Silence does not move the mean.
        let mut state = model.new_state();
        let mut quiet = voice(-0.3, 0);
        quiet.energy_db = -90.0;
        for _ in 0..100 {
            model.push_frame(&mut state, &quiet);
        }
        assert_eq!(state.lsp_mean, prior);
    }

    #[test]
    fn scaling_clamps_and_ignores_nan() {
        let scaling = InputScaling::new(-70.0, -10.0);
        let mut out = [0.0; 11];
        let mut f = frame(0.0);
        f.lsp[1] = f32::NAN;
        scaling.apply(&f, &mut out);
        assert_eq!(out[10], 1.0);
        assert_eq!(out[1], 0.0);
        assert!((scaling.energy_db_at(0.0) + 40.0).abs() < 1e-5);
    }
}

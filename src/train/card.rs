//! What a trained model says about itself: the notes in its file (data, licences, the loss and
//! how it was chosen) and the model card written beside a cross-validated one.

use std::path::Path;

use crate::lipsync::network::Model;
use crate::train::config::TrainConfig;
use crate::train::crossval::CrossValidation;
use crate::train::trainer::TrainReport;
use crate::vocab::FeatureFamily;

/// The first notes of a trained model file: where its weights come from.
pub fn provenance_notes(versions: usize, features_tail: &str) -> Vec<String> {
    vec![
        "Derived from the TIMIT corpus sample (Copyright 1993 Linguistic Data Consortium, \
         CC BY-NC-SA); see assets/models/README.md."
            .into(),
        format!(
            "features: codec round trips, training at {versions} rotating settings of Speex \
             qualities 3..10 and VBR 4/8, Opus (SILK NLSFs, 8 and 16 kHz input, 12-32 kb/s), \
             G.711 and G.722 (LPC analysis){features_tail}"
        ),
    ]
}

/// The loss and augmentation settings, for the model file's notes (the optional ones only
/// when used).
pub fn loss_note(config: &TrainConfig) -> String {
    let mut note = format!(
        "closure weight {}, sharp closures {}, openness weight {}",
        config.closure_weight, config.sharp_closures, config.openness_weight
    );
    for (name, value) in [
        ("width weight", config.width_weight),
        ("rounding weight", config.rounding_weight),
        ("segment closure weight", config.segment_closure_weight),
        ("warp", config.warp),
        ("weight decay", config.weight_decay),
    ] {
        if value != 0.0 {
            note.push_str(&format!(", {name} {value}"));
        }
    }
    if config.labiodental_weight != 1.0 {
        note.push_str(&format!(", /f v/ weight {}", config.labiodental_weight));
    }
    note
}

/// The notes of the final model of a cross-validation, trained on every non-test speaker at
/// `versions` codec settings (and on AN4 when `an4_weight` is positive).
pub fn cross_validated_notes(
    config: &TrainConfig,
    report: &TrainReport,
    cv: &CrossValidation,
    versions: usize,
    an4_weight: f32,
) -> Vec<String> {
    let mut notes = provenance_notes(versions, "");
    if an4_weight > 0.0 {
        notes.push(format!(
            "and from CMU AN4 (Copyright 1991 Carnegie Mellon University, free for any use; \
             labels by forced alignment, tools/align_an4.py), frames weighted {an4_weight}"
        ));
    }
    notes.extend([
        format!("training speakers: {}", report.split.train.join(" ")),
        format!(
            "cross-validated by dialect region: pooled held-out openness r {:.3}, /p b m/ closed \
             {:.1}%, false closures {:.1}%",
            cv.pooled.openness_r,
            100.0 * cv.pooled.closure_share(),
            100.0 * cv.pooled.false_closure_rate
        ),
        format!(
            "seed {}, {}, epochs {}, closure snap {}, sharpness {}{}",
            config.seed,
            loss_note(config),
            cv.epochs,
            cv.closure_snap,
            report.model.sharpness,
            if report.model.sharpen_open_shapes_only {
                " (open shapes)"
            } else {
                ""
            }
        ),
    ]);
    notes
}

/// Where a cross-validated model's data and file are, for its card.
#[derive(Debug, Clone, Copy)]
pub struct CardSources<'a> {
    pub model_file: &'a Path,
    pub corpus: &'a Path,
    pub an4_audio: &'a Path,
    /// 0: no AN4.
    pub an4_weight: f32,
    /// The GRID data step's output and the loss weight of a video frame, when s1's measured
    /// lips were trained on.
    pub grid: Option<(&'a Path, f32)>,
}

/// What a user of the weights needs to know: shape, data and licences, how it was chosen and
/// how it scores out of sample.
pub fn model_card(sources: &CardSources, model: &Model, cv: &CrossValidation) -> String {
    let mut card = String::new();
    let mut line = |text: String| {
        card.push_str(&text);
        card.push('\n');
    };
    line(format!("# Model card: {}", sources.model_file.display()));
    line(String::new());
    line("## The network".into());
    line(format!(
        "- visemes: {} | inputs {} (context {}, look-ahead {} frame(s) = {} ms that the receiver's \
         buffers hide) | hidden {} tanh | {} multiply-adds per frame (budget 400)",
        model.visemes,
        model.inputs(),
        model.context,
        model.lookahead,
        20 * model.lookahead,
        model.hidden,
        model.multiply_adds()
    ));
    line(format!(
        "- per-speaker LSP normalisation: {}",
        match &model.speaker_norm {
            Some(n) => format!("running mean over about {} speech frames", n.frames),
            None => "off".into(),
        }
    ));
    line(format!(
        "- output sharpness {}{} (the logits times this before the softmax; tuned with the \
         closure snap on the pooled folds)",
        model.sharpness,
        if model.sharpen_open_shapes_only {
            ", the open shapes only"
        } else {
            ""
        }
    ));
    line(format!(
        "- closure snap {} (tuned on the pooled folds); {} for SILK NLSFs and {} for LPC \
         analysis (each matched on the folds to the closures of Speex's LSPs)",
        model.closure_snap,
        model.closure_snap_of(FeatureFamily::Nlsf),
        model.closure_snap_of(FeatureFamily::Analysis)
    ));
    line(String::new());
    line("## Data and licences".into());
    line(format!(
        "- TIMIT corpus sample ({}), hand-labelled phones: Copyright 1993 Linguistic Data \
         Consortium, CC BY-NC-SA. Weights derived from it carry the non-commercial term.",
        sources.corpus.display()
    ));
    if sources.an4_weight > 0.0 {
        line(format!(
            "- CMU AN4 ({}), 84 speakers, phone labels by forced alignment \
             (tools/alignments/an4, about 76 % of boundaries within 20 ms of hand labels): \
             Copyright 1991 Carnegie Mellon University, free for any use with its notice. \
             Frames weighted {} against TIMIT's.",
            sources.an4_audio.display(),
            sources.an4_weight
        ));
    }
    if let Some((root, weight)) = sources.grid {
        line(format!(
            "- GRID audiovisual corpus ({}), speaker s1's lips tracked in video (MediaPipe face \
             mesh), every tenth clip held out, video frames weighted {weight}: Cooke, Barker, \
             Cunningham and Shao, J. Acoust. Soc. Am. 120 (5), 2421-2424, 2006; CC BY 4.0 \
             (attribution). The 9 other-speaker clips are for validation only.",
            root.display()
        ));
    }
    line("- TIMIT dr5 and dr6 (4 speakers) are never used for training or any choice.".into());
    line(String::new());
    line(
        "## Scores (cross-validated by dialect region, Speex quality 8, held-out speakers)".into(),
    );
    line(String::new());
    line("```".into());
    line(cv.to_string());
    line("```".into());
    card
}

//! TIMIT phones to visemes.
//!
//! | TIMIT phones | viseme | note |
//! |---|---|---|
//! | h# pau epi | sil | silence, lips lightly together |
//! | p b m em pcl bcl | PP | the stop closures are where the lips are shut |
//! | f v | FF | |
//! | th dh | TH | |
//! | t d dx tcl dcl | DD | |
//! | k g ng eng kcl gcl | kk | |
//! | ch jh sh zh | CH | |
//! | s z | SS | |
//! | n en nx l el | nn | |
//! | r er axr | RR | r-coloured vowels keep the rounded r lips |
//! | aa ae ah | aa | open vowels |
//! | eh ax ax-h | E | schwa is a half-open, relaxed mouth |
//! | ih ix iy y | I | |
//! | ao | O | |
//! | uh uw ux w | U | w is fully rounded |
//! | ey ay aw ow oy | two halves | diphthongs: E>I, aa>I, aa>U, O>U, O>I |
//! | hh hv q | (none) | take their shape from the neighbours through coarticulation |
//!
//! TIMIT's stress digits (lexicon only) are not accepted; phone files never carry them.

use crate::vocab::Viseme;

/// What a phone asks of the mouth.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhoneTarget {
    /// One viseme for the whole segment.
    Single(Viseme),
    /// A diphthong: the first half aims at one viseme, the second at another.
    Glide(Viseme, Viseme),
    /// No shape of its own (h, glottal stop): the neighbours decide.
    Transparent,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown TIMIT phone {phone:?}")]
pub struct UnknownPhone {
    pub phone: String,
}

/// The viseme target of a TIMIT phone.
pub fn phone_target(phone: &str) -> Result<PhoneTarget, UnknownPhone> {
    use PhoneTarget::{Glide, Single, Transparent};
    use Viseme::*;
    let target = match phone {
        "h#" | "pau" | "epi" => Single(Sil),
        "p" | "b" | "m" | "em" | "pcl" | "bcl" => Single(PP),
        "f" | "v" => Single(FF),
        "th" | "dh" => Single(TH),
        "t" | "d" | "dx" | "tcl" | "dcl" => Single(DD),
        "k" | "g" | "ng" | "eng" | "kcl" | "gcl" => Single(Kk),
        "ch" | "jh" | "sh" | "zh" => Single(CH),
        "s" | "z" => Single(SS),
        "n" | "en" | "nx" | "l" | "el" => Single(Nn),
        "r" | "er" | "axr" => Single(RR),
        "aa" | "ae" | "ah" => Single(Aa),
        "eh" | "ax" | "ax-h" => Single(E),
        "ih" | "ix" | "iy" | "y" => Single(I),
        "ao" => Single(O),
        "uh" | "uw" | "ux" | "w" => Single(U),
        "ey" => Glide(E, I),
        "ay" => Glide(Aa, I),
        "aw" => Glide(Aa, U),
        "ow" => Glide(O, U),
        "oy" => Glide(O, I),
        "hh" | "hv" | "q" => Transparent,
        _ => {
            return Err(UnknownPhone {
                phone: phone.to_string(),
            });
        }
    };
    Ok(target)
}

/// Phones during which the lips are shut: /p b m/, their closures and the syllabic m.
pub fn is_bilabial(phone: &str) -> bool {
    matches!(phone, "p" | "b" | "m" | "em" | "pcl" | "bcl")
}

/// Phone classes whose segments the evaluation checks one by one: does the mouth show them?
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CueClass {
    /// /aa ae ah ax ay aw/: the mouth should open wide.
    OpenVowel,
    /// /uw ux uh ow oy ao w/: the lips should round.
    Rounded,
    /// /f v/: the lower lip should go under the upper teeth.
    Labiodental,
}

impl CueClass {
    pub const ALL: [CueClass; 3] = [
        CueClass::OpenVowel,
        CueClass::Rounded,
        CueClass::Labiodental,
    ];

    /// The class of a phone, if it has one.
    pub fn of(phone: &str) -> Option<Self> {
        match phone {
            "aa" | "ae" | "ah" | "ax" | "ay" | "aw" => Some(CueClass::OpenVowel),
            "uw" | "ux" | "uh" | "ow" | "oy" | "ao" | "w" => Some(CueClass::Rounded),
            "f" | "v" => Some(CueClass::Labiodental),
            _ => None,
        }
    }

    /// Segments shorter than this are not scored (too short to see).
    pub fn min_seconds(self) -> f64 {
        match self {
            CueClass::OpenVowel | CueClass::Rounded => 0.06,
            CueClass::Labiodental => 0.04,
        }
    }

    /// Frames of slack on each side of a segment (the /f v/ lip can lead or lag by 20 ms).
    pub fn slack_frames(self) -> usize {
        match self {
            CueClass::OpenVowel | CueClass::Rounded => 0,
            CueClass::Labiodental => 1,
        }
    }

    pub fn index(self) -> usize {
        self as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TIMIT_PHONES: &str = "b d g p t k dx q jh ch s sh z zh f th v dh m n ng em en eng nx \
        l r w y hh hv el iy ih eh ey ae aa aw ay ah ao oy ow uh uw ux er ax ix axr ax-h \
        pau epi h# bcl dcl gcl pcl tcl kcl";

    #[test]
    fn every_timit_phone_has_a_target() {
        for phone in TIMIT_PHONES.split_whitespace() {
            assert!(phone_target(phone).is_ok(), "{phone}");
        }
    }

    #[test]
    fn unknown_phones_are_errors() {
        assert_eq!(phone_target("xx"), Err(UnknownPhone { phone: "xx".into() }));
        assert!(phone_target("aa1").is_err());
    }

    #[test]
    fn bilabials_map_to_pp() {
        for phone in ["p", "b", "m", "em", "pcl", "bcl"] {
            assert!(is_bilabial(phone));
            assert_eq!(phone_target(phone), Ok(PhoneTarget::Single(Viseme::PP)));
        }
        assert!(!is_bilabial("f"));
    }

    #[test]
    fn cue_classes_are_timit_phones() {
        for phone in TIMIT_PHONES.split_whitespace() {
            if let Some(class) = CueClass::of(phone) {
                assert!(phone_target(phone).is_ok());
                assert!(class.min_seconds() >= 0.04);
            }
        }
        assert_eq!(CueClass::of("w"), Some(CueClass::Rounded));
        assert_eq!(CueClass::of("v"), Some(CueClass::Labiodental));
        assert_eq!(CueClass::of("iy"), None);
    }
}

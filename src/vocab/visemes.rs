//! The 15 Oculus / MPEG-4 visemes, the weights over them that drive a head, and the reduced
//! sets (2 to 6 shapes) of the paper's Table I.

use std::fmt;
use std::str::FromStr;

/// Number of visemes in the full set.
pub const VISEME_COUNT: usize = 15;

/// The 15 names, in the order of [`Viseme::ALL`] (the order of every weight vector and of a
/// head's morph target slots).
pub const VISEME_NAMES: [&str; VISEME_COUNT] = [
    "sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "I", "O", "U",
];

/// Weights over all 15 visemes, indexed by `Viseme as usize`.
pub type FullWeights = [f32; VISEME_COUNT];

/// One viseme of the Oculus / MPEG-4 set. `Sil` is the neutral, closed shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Viseme {
    Sil,
    PP,
    FF,
    TH,
    DD,
    Kk,
    CH,
    SS,
    Nn,
    RR,
    Aa,
    E,
    I,
    O,
    U,
}

impl Viseme {
    /// All visemes in their canonical order.
    pub const ALL: [Viseme; VISEME_COUNT] = [
        Viseme::Sil,
        Viseme::PP,
        Viseme::FF,
        Viseme::TH,
        Viseme::DD,
        Viseme::Kk,
        Viseme::CH,
        Viseme::SS,
        Viseme::Nn,
        Viseme::RR,
        Viseme::Aa,
        Viseme::E,
        Viseme::I,
        Viseme::O,
        Viseme::U,
    ];

    /// The name used in files and on the command line (`sil PP FF TH DD kk CH SS nn RR aa E I O U`).
    pub const fn name(self) -> &'static str {
        VISEME_NAMES[self as usize]
    }

    /// The viseme of a name, spelt exactly as in [`VISEME_NAMES`].
    pub fn from_name(name: &str) -> Option<Self> {
        VISEME_NAMES
            .iter()
            .position(|v| *v == name)
            .map(|i| Self::ALL[i])
    }

    pub fn index(self) -> usize {
        self as usize
    }

    /// One-hot weights on this viseme.
    pub fn one_hot(self) -> FullWeights {
        let mut weights = [0.0; VISEME_COUNT];
        weights[self.index()] = 1.0;
        weights
    }
}

impl fmt::Display for Viseme {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One weight per viseme, in [`VISEME_NAMES`] order. Convex weights are expected
/// (non-negative, sum 1); the renderer blends whatever it is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisemeWeights(pub [f32; VISEME_COUNT]);

impl Default for VisemeWeights {
    fn default() -> Self {
        Self::neutral()
    }
}

impl VisemeWeights {
    /// All weight on `sil`: the neutral face.
    pub fn neutral() -> Self {
        Self::one_hot(0)
    }

    /// All weight on viseme `index` (clamped into range).
    pub fn one_hot(index: usize) -> Self {
        let mut w = [0.0; VISEME_COUNT];
        w[index.min(VISEME_COUNT - 1)] = 1.0;
        Self(w)
    }

    /// All weight on the named viseme.
    pub fn single(name: &str) -> Option<Self> {
        Viseme::from_name(name).map(|v| Self(v.one_hot()))
    }

    /// Builds weights from (name, weight) pairs of a possibly reduced viseme set.
    pub fn from_named<'a>(
        pairs: impl IntoIterator<Item = (&'a str, f32)>,
    ) -> Result<Self, VisemeError> {
        let mut w = [0.0; VISEME_COUNT];
        for (name, value) in pairs {
            w[name.parse::<Viseme>()?.index()] += value;
        }
        Ok(Self(w))
    }

    /// Linear interpolation; convex inputs give a convex result.
    pub fn lerp(&self, other: &Self, t: f32) -> Self {
        let mut w = [0.0; VISEME_COUNT];
        for (i, out) in w.iter_mut().enumerate() {
            *out = self.0[i] + (other.0[i] - self.0[i]) * t;
        }
        Self(w)
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum VisemeError {
    #[error("unknown viseme {0:?} (expected one of: sil PP FF TH DD kk CH SS nn RR aa E I O U)")]
    UnknownName(String),
    #[error("a viseme set needs {min} to {max} shapes, got {got}")]
    BadSize { got: usize, min: usize, max: usize },
    #[error("viseme {0} appears twice in the set")]
    Duplicate(Viseme),
}

impl FromStr for Viseme {
    type Err = VisemeError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Viseme::from_name(name).ok_or_else(|| VisemeError::UnknownName(name.to_string()))
    }
}

/// The order in which the reduced sets grow, after the paper's Table I:
/// closed, open "a", spread "i", rounded, "e", "f".
///
/// The paper's 4th shape is written as a rounded vowel symbol used at word starts. Our
/// point model makes `sil` and `PP` nearly the same shape, so a separate neutral would add
/// nothing; the rounded `O` is the degree of freedom that is missing after PP/aa/I (lip width
/// narrowing and protrusion), and it is what the Hungarian front-rounded vowel looks like.
pub const REDUCED_ORDER: [Viseme; 6] = [
    Viseme::PP,
    Viseme::Aa,
    Viseme::I,
    Viseme::O,
    Viseme::E,
    Viseme::FF,
];

/// An ordered set of visemes whose convex weights drive a head.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct VisemeSet {
    members: Vec<Viseme>,
}

impl VisemeSet {
    pub const MIN_SIZE: usize = 2;

    /// A set of distinct visemes, 2 to 15 of them.
    pub fn new(members: Vec<Viseme>) -> Result<Self, VisemeError> {
        if members.len() < Self::MIN_SIZE || members.len() > VISEME_COUNT {
            return Err(VisemeError::BadSize {
                got: members.len(),
                min: Self::MIN_SIZE,
                max: VISEME_COUNT,
            });
        }
        for (i, v) in members.iter().enumerate() {
            if members[..i].contains(v) {
                return Err(VisemeError::Duplicate(*v));
            }
        }
        Ok(Self { members })
    }

    /// The paper's reduced set of `size` shapes (2..=6), or all 15 for `size == 15`.
    pub fn reduced(size: usize) -> Result<Self, VisemeError> {
        match size {
            2..=6 => Self::new(REDUCED_ORDER[..size].to_vec()),
            VISEME_COUNT => Ok(Self::full()),
            _ => Err(VisemeError::BadSize {
                got: size,
                min: Self::MIN_SIZE,
                max: REDUCED_ORDER.len(),
            }),
        }
    }

    pub fn full() -> Self {
        Self {
            members: Viseme::ALL.to_vec(),
        }
    }

    /// Parses `--visemes`: either a count (`4`) or a comma-separated list of names (`PP,aa,I`).
    pub fn parse(arg: &str) -> Result<Self, VisemeError> {
        let arg = arg.trim();
        if let Ok(size) = arg.parse::<usize>() {
            return Self::reduced(size);
        }
        let members = arg
            .split(',')
            .map(|name| name.trim().parse::<Viseme>())
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(members)
    }

    pub fn members(&self) -> &[Viseme] {
        &self.members
    }

    pub fn len(&self) -> usize {
        self.members.len()
    }

    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    pub fn position(&self, viseme: Viseme) -> Option<usize> {
        self.members.iter().position(|&v| v == viseme)
    }

    /// Spreads weights over this set back onto the 15 visemes.
    pub fn to_full(&self, weights: &[f32]) -> FullWeights {
        let mut full = [0.0; VISEME_COUNT];
        for (v, w) in self.members.iter().zip(weights) {
            full[v.index()] += w;
        }
        full
    }
}

impl fmt::Display for VisemeSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, v) in self.members.iter().enumerate() {
            if i > 0 {
                f.write_str(",")?;
            }
            f.write_str(v.name())?;
        }
        Ok(())
    }
}

impl FromStr for VisemeSet {
    type Err = VisemeError;

    fn from_str(arg: &str) -> Result<Self, Self::Err> {
        Self::parse(arg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_in_canonical_order() {
        let names: Vec<&str> = Viseme::ALL.iter().map(|v| v.name()).collect();
        assert_eq!(names.join(" "), "sil PP FF TH DD kk CH SS nn RR aa E I O U");
        for v in Viseme::ALL {
            assert_eq!(v.name().parse::<Viseme>(), Ok(v));
            assert_eq!(Viseme::ALL[v.index()], v);
        }
    }

    #[test]
    fn reduced_sets_grow_in_table_i_order() {
        assert_eq!(VisemeSet::parse("2").unwrap().to_string(), "PP,aa");
        assert_eq!(VisemeSet::parse("3").unwrap().to_string(), "PP,aa,I");
        assert_eq!(VisemeSet::parse("6").unwrap().to_string(), "PP,aa,I,O,E,FF");
        assert_eq!(VisemeSet::parse("15").unwrap().len(), 15);
        assert!(matches!(
            VisemeSet::parse("7"),
            Err(VisemeError::BadSize { got: 7, .. })
        ));
        assert!(matches!(
            VisemeSet::parse("1"),
            Err(VisemeError::BadSize { got: 1, .. })
        ));
    }

    #[test]
    fn name_lists_are_validated() {
        assert_eq!(
            VisemeSet::parse("sil, aa ,U").unwrap().members(),
            &[Viseme::Sil, Viseme::Aa, Viseme::U]
        );
        assert_eq!(
            VisemeSet::parse("PP,AA"),
            Err(VisemeError::UnknownName("AA".into()))
        );
        assert_eq!(
            VisemeSet::parse("PP,aa,PP"),
            Err(VisemeError::Duplicate(Viseme::PP))
        );
        assert!(VisemeSet::parse("PP").is_err());
    }
}

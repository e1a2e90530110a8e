//! Lip sync: viseme sets, phone-derived targets, mouth geometry, the paper's decomposition, the
//! per-frame network and the jaw-from-energy baseline.

pub mod coarticulation;
pub mod decompose;
pub mod mouth;
pub mod phones;
pub mod visemes;

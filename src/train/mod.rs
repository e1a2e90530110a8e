//! Offline training and evaluation of the lip-sync network on a TIMIT-style corpus.

pub mod corpus;

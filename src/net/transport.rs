//! What every link stands on, whatever its protocol: the socket [`Driver`] under a sans-I/O
//! core ([`SansIo`]), the datagrams a core sends ([`Transmit`]), and what a link reports about
//! its remote peers ([`PeerInfo`], each named by a transport-neutral [`PeerId`]) and hands on
//! from them ([`PeerFrame`]).

mod driver;
mod peer;

pub use driver::{Driver, SansIo, Transmit, TransmitKind};
pub use peer::{PeerFrame, PeerId, PeerInfo};

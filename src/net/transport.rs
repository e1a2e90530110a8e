//! What every link stands on, whatever its protocol: the socket [`Driver`] under a sans-I/O
//! core ([`SansIo`]), the datagrams a core sends ([`Transmit`]), and what a link reports about
//! its remote peers ([`PeerInfo`], each named by a transport-neutral [`PeerId`]) and hands on
//! from them ([`PeerFrame`]). Datagrams are stamped by the kernel as they arrive (`stamp`), not
//! when the socket thread reads them.

mod driver;
mod peer;
mod stamp;

pub use driver::{Driver, SansIo, Transmit, TransmitKind};
pub use peer::{PeerFrame, PeerId, PeerInfo};

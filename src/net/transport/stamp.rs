//! When a datagram arrived, by the kernel's clock, not by when our thread got round to reading
//! it. A socket thread starved by a busy machine reads what came during its stall in a burst;
//! stamped at the read, that burst looks like network jitter (and, held up for long, like a
//! sender's clock drifting), and the jitter buffer grows, conceals and stretches for packets
//! that were on time. The kernel stamps each datagram as it is queued (`SO_TIMESTAMPNS`,
//! `SCM_TIMESTAMPNS` with `recvmsg`); the stamp is on the system's real-time clock and is
//! turned into an [`Instant`] by its age at the read.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant, SystemTime};

/// A stamp older than this at its read is not trusted (the real-time clock was set meanwhile):
/// the datagram is taken to arrive when it was read.
const OLDEST: Duration = Duration::from_secs(2);

/// Asks the kernel to stamp every datagram `socket` receives. A socket it cannot be asked of
/// is read as before, stamped at the read.
pub fn enable(socket: &UdpSocket) {
    #[cfg(target_os = "linux")]
    if let Err(e) =
        nix::sys::socket::setsockopt(socket, nix::sys::socket::sockopt::ReceiveTimestampns, &true)
    {
        tracing::debug!("no kernel receive timestamps ({e}): datagrams stamped when read");
    }
    #[cfg(not(target_os = "linux"))]
    let _ = socket;
}

/// Reads one datagram into `buf`: its length, its source and when it arrived (the kernel's
/// stamp where [`enable`] took, else now).
pub fn recv_from(
    socket: &UdpSocket,
    buf: &mut [u8],
) -> std::io::Result<(usize, SocketAddr, Instant)> {
    #[cfg(target_os = "linux")]
    {
        linux::recv_from(socket, buf, false)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let (n, from) = socket.recv_from(buf)?;
        Ok((n, from, Instant::now()))
    }
}

/// The instant of a real-time `stamp`, read at `read` (and `wall`, the real-time clock then).
fn arrival(stamp: SystemTime, read: Instant, wall: SystemTime) -> Instant {
    match wall.duration_since(stamp) {
        Ok(age) if age <= OLDEST => read.checked_sub(age).unwrap_or(read),
        // Stamped after the read by the wall clock: the clock was set back; or too old.
        _ => read,
    }
}

/// As [`recv_from`] for a datagram already waiting; `WouldBlock` when none is (where the
/// kernel cannot be asked for one without waiting: always).
pub fn recv_waiting(
    socket: &UdpSocket,
    buf: &mut [u8],
) -> std::io::Result<(usize, SocketAddr, Instant)> {
    #[cfg(target_os = "linux")]
    {
        linux::recv_from(socket, buf, true)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (socket, buf);
        Err(std::io::ErrorKind::WouldBlock.into())
    }
}

#[cfg(target_os = "linux")]
mod linux {
    use std::io::IoSliceMut;
    use std::net::{SocketAddr, UdpSocket};
    use std::os::fd::AsRawFd;
    use std::time::{Duration, Instant, SystemTime};

    use nix::sys::socket::{ControlMessageOwned, MsgFlags, SockaddrStorage, recvmsg};

    pub fn recv_from(
        socket: &UdpSocket,
        buf: &mut [u8],
        waiting_only: bool,
    ) -> std::io::Result<(usize, SocketAddr, Instant)> {
        let flags = if waiting_only {
            MsgFlags::MSG_DONTWAIT
        } else {
            MsgFlags::empty()
        };
        let mut control = nix::cmsg_space!(nix::sys::time::TimeSpec);
        let mut iov = [IoSliceMut::new(buf)];
        let msg =
            recvmsg::<SockaddrStorage>(socket.as_raw_fd(), &mut iov, Some(&mut control), flags)
                .map_err(std::io::Error::from)?;
        let (read, wall) = (Instant::now(), SystemTime::now());
        let from = msg
            .address
            .and_then(|a| socket_addr(&a))
            .ok_or_else(|| std::io::Error::other("a datagram from no IP address"))?;
        let mut at = read;
        if let Ok(cmsgs) = msg.cmsgs() {
            for cmsg in cmsgs {
                if let ControlMessageOwned::ScmTimestampns(ts) = cmsg {
                    let (secs, nanos) = (ts.tv_sec(), ts.tv_nsec());
                    if let (Ok(secs), Ok(nanos)) = (u64::try_from(secs), u32::try_from(nanos)) {
                        let stamp = SystemTime::UNIX_EPOCH + Duration::new(secs, nanos);
                        at = super::arrival(stamp, read, wall);
                    }
                }
            }
        }
        Ok((msg.bytes, from, at))
    }

    fn socket_addr(address: &SockaddrStorage) -> Option<SocketAddr> {
        if let Some(v4) = address.as_sockaddr_in() {
            return Some(SocketAddr::from((v4.ip(), v4.port())));
        }
        let v6 = address.as_sockaddr_in6()?;
        Some(SocketAddr::V6(std::net::SocketAddrV6::new(
            v6.ip(),
            v6.port(),
            v6.flowinfo(),
            v6.scope_id(),
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stamp_becomes_the_instant_its_age_before_the_read() {
        let read = Instant::now();
        let wall = SystemTime::now();
        let at = arrival(wall - Duration::from_millis(150), read, wall);
        assert_eq!(read - at, Duration::from_millis(150));
        // A clock set back, or a stamp too old to trust: the read's time.
        assert_eq!(arrival(wall + Duration::from_secs(1), read, wall), read);
        assert_eq!(arrival(wall - Duration::from_secs(60), read, wall), read);
    }

    #[test]
    fn datagrams_read_in_a_burst_after_a_stall_keep_the_spacing_they_arrived_with() {
        let receiver = UdpSocket::bind("127.0.0.1:0").unwrap();
        enable(&receiver);
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        let to = receiver.local_addr().unwrap();
        let mut buf = [0u8; 16];
        // Linux turns its receive stamps on a moment after the first socket asks (deferred
        // work); until then a datagram is stamped at its read. Wait until one is stamped early.
        let on = (0..50).any(|_| {
            sender.send_to(&[9], to).unwrap();
            std::thread::sleep(Duration::from_millis(30));
            let (_, _, at) = recv_from(&receiver, &mut buf).unwrap();
            Instant::now() - at >= Duration::from_millis(20)
        });
        assert!(on, "the kernel never stamped a datagram before its read");
        // Five datagrams 30 ms apart while the reader is away; read together 150 ms later.
        for k in 0..5u8 {
            sender.send_to(&[k], to).unwrap();
            std::thread::sleep(Duration::from_millis(30));
        }
        std::thread::sleep(Duration::from_millis(150));
        let mut stamps = Vec::new();
        for k in 0..5u8 {
            let (n, from, at) = recv_from(&receiver, &mut buf).unwrap();
            assert_eq!((n, buf[0], from), (1, k, sender.local_addr().unwrap()));
            stamps.push(at);
        }
        let read = Instant::now();
        // The first came at least 150 ms (the stall) plus four gaps before the burst was read.
        assert!(
            read - stamps[0] >= Duration::from_millis(150 + 4 * 30),
            "{stamps:?}"
        );
        for pair in stamps.windows(2) {
            // Each at least the sender's sleep after the one before (a loaded machine's
            // sender only sleeps longer), nowhere near the microseconds between the reads.
            assert!(pair[1] - pair[0] >= Duration::from_millis(29), "{stamps:?}");
        }
    }
}

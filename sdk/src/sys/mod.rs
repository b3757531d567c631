//! The system calls Courier makes that std and socket2 do not offer, and
//! so every `unsafe` block of the crate: registering descriptors with
//! tokio's reactor, `recvmmsg` and `sendmmsg`, the interface list, reverse DNS for access
//! rules, the `timerfd` of the drivers' timers, the serial lines of the XRCE backend and the allocator settings of the
//! central binary. Everything else is `#![deny(unsafe_code)]`.
#![allow(unsafe_code)]

#[cfg(target_os = "linux")]
pub(crate) mod timerfd;
pub(crate) mod tty;

pub(crate) mod net {
    //! Sockets and interfaces.

    use std::io;
    use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
    use std::os::fd::{AsFd, AsRawFd, OwnedFd};

    use tokio::io::unix::AsyncFd;
    use tokio::io::Interest;

    /// An IPv4 address of one interface.
    #[derive(Debug, Clone)]
    pub(crate) struct Interface {
        pub(crate) name: String,
        pub(crate) addr: Ipv4Addr,
        pub(crate) up: bool,
        pub(crate) loopback: bool,
        pub(crate) multicast: bool,
    }

    /// Every IPv4 interface address of this machine.
    pub(crate) fn interfaces() -> io::Result<Vec<Interface>> {
        let mut out = Vec::new();
        // SAFETY: getifaddrs fills a linked list that we walk read-only and free
        // with freeifaddrs; every pointer is checked for null before use.
        unsafe {
            let mut head: *mut libc::ifaddrs = std::ptr::null_mut();
            if libc::getifaddrs(&mut head) != 0 {
                return Err(io::Error::last_os_error());
            }
            let mut cur = head;
            while !cur.is_null() {
                let ifa = &*cur;
                if !ifa.ifa_addr.is_null() && i32::from((*ifa.ifa_addr).sa_family) == libc::AF_INET
                {
                    let sin = &*(ifa.ifa_addr as *const libc::sockaddr_in);
                    let addr = Ipv4Addr::from(u32::from_be(sin.sin_addr.s_addr));
                    let name = std::ffi::CStr::from_ptr(ifa.ifa_name)
                        .to_string_lossy()
                        .into_owned();
                    let f = ifa.ifa_flags;
                    out.push(Interface {
                        name,
                        addr,
                        up: f & libc::IFF_UP as u32 != 0,
                        loopback: f & libc::IFF_LOOPBACK as u32 != 0,
                        multicast: f & libc::IFF_MULTICAST as u32 != 0,
                    });
                }
                cur = ifa.ifa_next;
            }
            libc::freeifaddrs(head);
        }
        Ok(out)
    }

    /// Registers `fd` with tokio's reactor for `interest`.
    pub(crate) fn register<T: AsRawFd>(fd: T, interest: Interest) -> io::Result<AsyncFd<T>> {
        // SAFETY: the `AsyncFd` owns `fd`, whose descriptor stays open and the
        // same until the `AsyncFd` is dropped (nothing hands it out mutably or
        // swaps it)
        unsafe { AsyncFd::register_with_interest(fd, interest) }.map_err(|e| e.into_parts().1)
    }

    /// A registration for write readiness of a socket that is registered
    /// for reading only, on a duplicate of its descriptor (one descriptor
    /// has one registration), to be kept only while a write waits for
    /// room. A socket that asks for both is woken each time it gets room
    /// back, which a UNIX socket does on every read by its peer. The kernel
    /// reports readiness at registration, so room that appeared since the
    /// write that found none is not missed.
    pub(crate) fn register_for_room(fd: &impl AsFd) -> io::Result<AsyncFd<OwnedFd>> {
        register(fd.as_fd().try_clone_to_owned()?, Interest::WRITABLE)
    }

    /// One `read(2)` of `fd` into the spare capacity of `buf`, whose length
    /// grows by what was read: a buffer read into this way is never zeroed
    /// first, so only the pages the bytes land on become resident.
    #[cfg(feature = "central")]
    pub(crate) fn read_spare<T: AsRawFd>(fd: &T, buf: &mut Vec<u8>) -> io::Result<usize> {
        let spare = buf.spare_capacity_mut();
        // SAFETY: read(2) writes at most `spare.len()` bytes to memory we own
        // exclusively (the vector's spare capacity), through a valid pointer.
        let n = unsafe { libc::read(fd.as_raw_fd(), spare.as_mut_ptr().cast(), spare.len()) };
        let n = usize::try_from(n).map_err(|_| io::Error::last_os_error())?;
        // SAFETY: read(2) initialised the first `n` bytes of the spare
        // capacity (n <= spare.len()).
        unsafe { buf.set_len(buf.len() + n) };
        Ok(n)
    }

    /// One `recvmmsg` into up to `N` of `bufs`: the length and sender of each
    /// datagram go to `lens` and `from`; returns how many came.
    #[cfg(target_os = "linux")]
    pub(crate) fn recvmmsg<const N: usize>(
        sock: &std::net::UdpSocket,
        bufs: &mut [Vec<u8>],
        lens: &mut [usize; N],
        from: &mut [SocketAddr; N],
        flags: libc::c_int,
    ) -> io::Result<usize> {
        const { assert!(N > 0) };
        if bufs.len() < N {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "fewer buffers than slots",
            ));
        }
        // SAFETY: all-zero is a valid value of these plain C structs
        let mut addrs: [libc::sockaddr_storage; N] = unsafe { std::mem::zeroed() };
        let mut iov: [libc::iovec; N] = unsafe { std::mem::zeroed() };
        let mut hdrs: [libc::mmsghdr; N] = unsafe { std::mem::zeroed() };
        for i in 0..N {
            iov[i] = libc::iovec {
                iov_base: bufs[i].as_mut_ptr().cast(),
                iov_len: bufs[i].len(),
            };
            let h = &mut hdrs[i].msg_hdr;
            h.msg_name = std::ptr::from_mut(&mut addrs[i]).cast();
            h.msg_namelen = std::mem::size_of::<libc::sockaddr_storage>() as libc::socklen_t;
            h.msg_iov = std::ptr::from_mut(&mut iov[i]);
            h.msg_iovlen = 1;
        }
        // SAFETY: every header points at a live buffer of the stated length
        // and at a sockaddr_storage, all of which outlive the call
        let n = unsafe {
            libc::recvmmsg(
                sock.as_raw_fd(),
                hdrs.as_mut_ptr(),
                N as libc::c_uint,
                flags,
                std::ptr::null_mut(),
            )
        };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        let n = usize::try_from(n).unwrap_or(0).min(N);
        for i in 0..n {
            lens[i] = (hdrs[i].msg_len as usize).min(bufs[i].len());
            from[i] = sockaddr_v4(&addrs[i]);
        }
        Ok(n)
    }

    /// Datagrams one [`sendmmsg`] call takes at most; the rest of a longer
    /// list is left to the next call.
    pub(crate) const SEND_SLOTS: usize = 32;

    /// One `sendmmsg` of up to [`SEND_SLOTS`] datagrams, each to its own
    /// IPv4 address and gathered from its own slices: returns how many the
    /// kernel took (at least one), or the error of the first. As with
    /// `sendmmsg(2)`, an error after the first datagram ends the call early
    /// and is not reported: send the rest again to see it.
    #[cfg(target_os = "linux")]
    pub(crate) fn sendmmsg(
        sock: &std::net::UdpSocket,
        msgs: &[(SocketAddrV4, &[io::IoSlice<'_>])],
        flags: libc::c_int,
    ) -> io::Result<usize> {
        let n = msgs.len().min(SEND_SLOTS);
        if n == 0 {
            return Ok(0);
        }
        // SAFETY: all-zero is a valid value of these plain C structs
        let mut addrs: [libc::sockaddr_in; SEND_SLOTS] = unsafe { std::mem::zeroed() };
        let mut hdrs: [libc::mmsghdr; SEND_SLOTS] = unsafe { std::mem::zeroed() };
        for (i, (to, parts)) in msgs[..n].iter().enumerate() {
            addrs[i].sin_family = libc::AF_INET as libc::sa_family_t;
            addrs[i].sin_port = to.port().to_be();
            addrs[i].sin_addr.s_addr = u32::from_ne_bytes(to.ip().octets());
            let h = &mut hdrs[i].msg_hdr;
            h.msg_name = std::ptr::from_mut(&mut addrs[i]).cast();
            h.msg_namelen = std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
            // `IoSlice` is ABI-compatible with `iovec` on Unix (std's
            // documented guarantee); the kernel only reads through it
            h.msg_iov = parts.as_ptr().cast::<libc::iovec>().cast_mut();
            h.msg_iovlen = parts.len() as _;
        }
        // SAFETY: every header points at a live sockaddr_in and at `parts`,
        // slices of valid buffers, all of which outlive the call; n <= the
        // length of `hdrs`
        let sent = unsafe {
            libc::sendmmsg(
                sock.as_raw_fd(),
                hdrs.as_mut_ptr(),
                n as libc::c_uint,
                flags,
            )
        };
        usize::try_from(sent).map_err(|_| io::Error::last_os_error())
    }

    /// [`sendmmsg`] where there is none: one `sendmsg` per datagram, until
    /// one fails.
    #[cfg(not(target_os = "linux"))]
    pub(crate) fn sendmmsg(
        sock: &std::net::UdpSocket,
        msgs: &[(SocketAddrV4, &[io::IoSlice<'_>])],
        flags: libc::c_int,
    ) -> io::Result<usize> {
        let sock = socket2::SockRef::from(sock);
        for (i, (to, parts)) in msgs.iter().take(SEND_SLOTS).enumerate() {
            let to = socket2::SockAddr::from(SocketAddr::V4(*to));
            if let Err(e) = sock.send_to_vectored_with_flags(parts, &to, flags) {
                return if i == 0 { Err(e) } else { Ok(i) };
            }
        }
        Ok(msgs.len().min(SEND_SLOTS))
    }

    /// Waits up to `timeout` with `poll(2)` until one of `fds` is ready
    /// for what it is asked (read, write); returns, for each, whether it
    /// is readable and whether writable (all false when the time ran out).
    /// For waiting without a tokio reactor (a session closing after its
    /// runtime shut down).
    pub(crate) fn poll(
        fds: &[(std::os::fd::BorrowedFd<'_>, bool, bool)],
        timeout: std::time::Duration,
    ) -> io::Result<Vec<(bool, bool)>> {
        let mut p: Vec<libc::pollfd> = fds
            .iter()
            .map(|(fd, read, write)| libc::pollfd {
                fd: fd.as_raw_fd(),
                events: if *read { libc::POLLIN } else { 0 }
                    | if *write { libc::POLLOUT } else { 0 },
                revents: 0,
            })
            .collect();
        let ms = libc::c_int::try_from(timeout.as_millis()).unwrap_or(libc::c_int::MAX);
        let n = libc::nfds_t::try_from(p.len()).unwrap_or(libc::nfds_t::MAX);
        // SAFETY: `p` holds `n` initialised pollfd records that poll only
        // writes `revents` of; the descriptors are borrowed, so open
        let r = unsafe { libc::poll(p.as_mut_ptr(), n, ms) };
        if r < 0 {
            let e = io::Error::last_os_error();
            if e.kind() != io::ErrorKind::Interrupted {
                return Err(e);
            }
            p.iter_mut().for_each(|x| x.revents = 0);
        }
        Ok(p.iter()
            .map(|x| {
                let err = x.revents & (libc::POLLERR | libc::POLLHUP) != 0;
                (
                    x.revents & libc::POLLIN != 0 || err,
                    x.revents & libc::POLLOUT != 0 || err,
                )
            })
            .collect())
    }

    /// The IPv4 sender in a `sockaddr_storage` (0.0.0.0:0 for anything else:
    /// these sockets are IPv4).
    #[cfg(target_os = "linux")]
    fn sockaddr_v4(a: &libc::sockaddr_storage) -> SocketAddr {
        if i32::from(a.ss_family) != libc::AF_INET {
            return SocketAddr::from(([0, 0, 0, 0], 0));
        }
        // SAFETY: ss_family says this storage holds a sockaddr_in
        let sin = unsafe { &*std::ptr::from_ref(a).cast::<libc::sockaddr_in>() };
        SocketAddr::V4(SocketAddrV4::new(
            Ipv4Addr::from(u32::from_be(sin.sin_addr.s_addr)),
            u16::from_be(sin.sin_port),
        ))
    }
    #[cfg(test)]
    mod tests {
        use super::*;
        use std::io::IoSlice;

        /// Each datagram of one `sendmmsg` arrives whole (its slices
        /// gathered), in order, at its own address; a longer list is cut
        /// at `SEND_SLOTS`.
        #[test]
        fn sendmmsg_sends_each_datagram_gathered_and_in_order() {
            let rx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            rx.set_read_timeout(Some(std::time::Duration::from_secs(5)))
                .unwrap();
            let tx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            let SocketAddr::V4(to) = rx.local_addr().unwrap() else {
                unreachable!("bound to IPv4")
            };
            let bodies: Vec<[Vec<u8>; 2]> = (0..SEND_SLOTS as u8 + 3)
                .map(|i| [vec![i; 3], vec![i.wrapping_add(100); 2000]])
                .collect();
            let iovs: Vec<[IoSlice<'_>; 2]> = bodies
                .iter()
                .map(|[a, b]| [IoSlice::new(a), IoSlice::new(b)])
                .collect();
            let msgs: Vec<(SocketAddrV4, &[IoSlice<'_>])> =
                iovs.iter().map(|p| (to, &p[..])).collect();
            assert_eq!(sendmmsg(&tx, &msgs, 0).unwrap(), SEND_SLOTS);
            assert_eq!(sendmmsg(&tx, &msgs[SEND_SLOTS..], 0).unwrap(), 3);
            assert_eq!(sendmmsg(&tx, &[], 0).unwrap(), 0);
            let mut buf = vec![0; 4096];
            for [a, b] in &bodies {
                let n = rx.recv(&mut buf).unwrap();
                assert_eq!(&buf[..n], [&a[..], &b[..]].concat());
            }
        }
    }
}

#[cfg(feature = "central")]
pub(crate) mod dns {
    //! Reverse lookups for central's access rules.

    use std::net::IpAddr;

    /// The name `ip` resolves to (`NI_NAMEREQD`: no numeric fallback).
    pub(crate) fn getnameinfo(ip: IpAddr) -> Option<String> {
        // SAFETY: the sockaddr structures are fully initialised (zeroed, then
        // filled), the lengths passed are their sizes, and the host buffer is
        // NI_MAXHOST bytes long and NUL-terminated by getnameinfo on success.
        unsafe {
            let mut host = [0 as libc::c_char; libc::NI_MAXHOST as usize];
            let rc = match ip {
                IpAddr::V4(v4) => {
                    let mut sa: libc::sockaddr_in = std::mem::zeroed();
                    sa.sin_family = libc::AF_INET as libc::sa_family_t;
                    sa.sin_addr.s_addr = u32::from_ne_bytes(v4.octets());
                    libc::getnameinfo(
                        &sa as *const libc::sockaddr_in as *const libc::sockaddr,
                        std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t,
                        host.as_mut_ptr(),
                        host.len() as libc::socklen_t,
                        std::ptr::null_mut(),
                        0,
                        libc::NI_NAMEREQD,
                    )
                }
                IpAddr::V6(v6) => {
                    let mut sa: libc::sockaddr_in6 = std::mem::zeroed();
                    sa.sin6_family = libc::AF_INET6 as libc::sa_family_t;
                    sa.sin6_addr.s6_addr = v6.octets();
                    libc::getnameinfo(
                        &sa as *const libc::sockaddr_in6 as *const libc::sockaddr,
                        std::mem::size_of::<libc::sockaddr_in6>() as libc::socklen_t,
                        host.as_mut_ptr(),
                        host.len() as libc::socklen_t,
                        std::ptr::null_mut(),
                        0,
                        libc::NI_NAMEREQD,
                    )
                }
            };
            if rc != 0 {
                return None;
            }
            let s = std::ffi::CStr::from_ptr(host.as_ptr());
            Some(s.to_string_lossy().into_owned())
        }
    }
}

#[cfg(feature = "central")]
pub(crate) mod alloc {
    //! glibc's allocator settings for the central binary.

    use std::sync::atomic::{AtomicBool, Ordering};

    /// [`keep_freed_memory`] was called: [`give_back`] trims.
    static KEEPING: AtomicBool = AtomicBool::new(false);

    /// Keeps large freed allocations in the heap (see
    /// [`crate::central::keep_freed_memory`]).
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    pub(crate) fn keep_freed_memory() {
        // SAFETY: mallopt only sets glibc allocator parameters; the caller
        // runs before any other thread exists.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
            libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
        }
        KEEPING.store(true, Ordering::Relaxed);
    }

    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    pub(crate) fn keep_freed_memory() {}

    /// Hands the free memory [`keep_freed_memory`] kept back to the kernel
    /// (`malloc_trim`); nothing if it was not called.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    pub(crate) fn give_back() {
        if KEEPING.load(Ordering::Relaxed) {
            // SAFETY: malloc_trim only releases free heap memory; it is
            // thread-safe (it takes the arenas' locks).
            unsafe {
                libc::malloc_trim(0);
            }
        }
    }

    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    pub(crate) fn give_back() {
        let _ = &KEEPING;
    }
}

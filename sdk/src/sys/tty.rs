//! Serial lines for the XRCE backend: a tty opened non-blocking in raw mode
//! at a given speed (`termios`), and, for tests, pseudo-terminal pairs.

use std::ffi::CString;
use std::fs::File;
use std::io;
use std::os::fd::{FromRawFd, OwnedFd};

/// The `speed_t` of a line speed in baud, if POSIX (or Linux) has one.
pub(crate) fn speed(baud: u32) -> Option<libc::speed_t> {
    Some(match baud {
        50 => libc::B50,
        75 => libc::B75,
        110 => libc::B110,
        134 => libc::B134,
        150 => libc::B150,
        200 => libc::B200,
        300 => libc::B300,
        600 => libc::B600,
        1200 => libc::B1200,
        1800 => libc::B1800,
        2400 => libc::B2400,
        4800 => libc::B4800,
        9600 => libc::B9600,
        19200 => libc::B19200,
        38400 => libc::B38400,
        57600 => libc::B57600,
        115_200 => libc::B115200,
        230_400 => libc::B230400,
        460_800 => libc::B460800,
        500_000 => libc::B500000,
        576_000 => libc::B576000,
        921_600 => libc::B921600,
        1_000_000 => libc::B1000000,
        1_152_000 => libc::B1152000,
        1_500_000 => libc::B1500000,
        2_000_000 => libc::B2000000,
        2_500_000 => libc::B2500000,
        3_000_000 => libc::B3000000,
        3_500_000 => libc::B3500000,
        4_000_000 => libc::B4000000,
        _ => return None,
    })
}

/// Puts `fd` in raw mode (no echo, no line editing, no translation, 8N1,
/// receiver on, modem lines ignored) at `speed`.
fn make_raw(fd: libc::c_int, speed: Option<libc::speed_t>) -> io::Result<()> {
    // SAFETY: termios is plain data; tcgetattr fills it before it is read,
    // and every call gets a descriptor the caller owns.
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(fd, &mut t) != 0 {
            return Err(io::Error::last_os_error());
        }
        libc::cfmakeraw(&mut t);
        t.c_cflag |= libc::CLOCAL | libc::CREAD;
        t.c_cc[libc::VMIN] = 0;
        t.c_cc[libc::VTIME] = 0;
        if let Some(s) = speed {
            if libc::cfsetispeed(&mut t, s) != 0 || libc::cfsetospeed(&mut t, s) != 0 {
                return Err(io::Error::last_os_error());
            }
        }
        if libc::tcsetattr(fd, libc::TCSANOW, &t) != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

/// Opens the tty at `path` for reading and writing, non-blocking, not as
/// the controlling terminal, in raw mode at `baud`.
pub(crate) fn open_raw(path: &str, baud: u32) -> io::Result<File> {
    let speed = speed(baud).ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{baud} is not a line speed"),
        )
    })?;
    let c = CString::new(path)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "NUL in tty path"))?;
    // SAFETY: a NUL-terminated path; the descriptor is owned at once.
    let raw = unsafe {
        libc::open(
            c.as_ptr(),
            libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC,
        )
    };
    if raw < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `raw` is a fresh descriptor nobody else owns.
    let fd = unsafe { OwnedFd::from_raw_fd(raw) };
    make_raw(raw, Some(speed))?;
    Ok(File::from(fd))
}

/// A pseudo-terminal pair: the master side (non-blocking, raw) and the
/// path of the slave side, for tests of serial links.
#[allow(dead_code)] // used by tests
pub(crate) fn pty_pair() -> io::Result<(File, String)> {
    // SAFETY: posix_openpt returns a fresh descriptor owned at once;
    // grantpt/unlockpt take it; ptsname_r writes at most `buf.len()` bytes
    // into our buffer, NUL-terminated.
    unsafe {
        let raw = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC);
        if raw < 0 {
            return Err(io::Error::last_os_error());
        }
        let fd = OwnedFd::from_raw_fd(raw);
        if libc::grantpt(raw) != 0 || libc::unlockpt(raw) != 0 {
            return Err(io::Error::last_os_error());
        }
        let mut buf = [0 as libc::c_char; 128];
        let r = libc::ptsname_r(raw, buf.as_mut_ptr(), buf.len());
        if r != 0 {
            return Err(io::Error::from_raw_os_error(r));
        }
        let path = std::ffi::CStr::from_ptr(buf.as_ptr())
            .to_string_lossy()
            .into_owned();
        make_raw(raw, None)?;
        let flags = libc::fcntl(raw, libc::F_GETFL);
        if flags < 0 || libc::fcntl(raw, libc::F_SETFL, flags | libc::O_NONBLOCK) != 0 {
            return Err(io::Error::last_os_error());
        }
        Ok((File::from(fd), path))
    }
}

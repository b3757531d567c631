//! What the binaries ask of the process's signal dispositions.

/// Whether SIGHUP is ignored, as `nohup` leaves it: a program that stops
/// cleanly on a hang-up is then to go on ignoring it (installing a
/// handler would undo what `nohup` asked for).
#[doc(hidden)]
#[allow(unsafe_code)]
pub fn sighup_ignored() -> bool {
    // SAFETY: sigaction(2) with no new action only reads the disposition
    // into `old`, a plain C struct for which all zeroes are valid.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(libc::SIGHUP, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

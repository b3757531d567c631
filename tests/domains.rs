//! DDS domain ids for tests, unique among all processes on this machine.
//!
//! A DDS domain id picks the UDP ports a participant uses (7400 + 250 ×
//! domain + …), and two participants on one domain discover each other.
//! Two test runs on one machine (two clones, or CI and a developer) that
//! hard-code the same domain ids therefore see each other's participants
//! and steal each other's ports. Instead, a test names its domain with a
//! small *key* of its own choosing (unique within its test binary), and
//! [`lease`] maps that key to a domain id that no other process holding a
//! lease has: each id is guarded by an exclusive `flock` on
//! `<tmp>/courier-test-domains/<id>.lock`, held until the process exits
//! (the kernel releases it even if the process is killed).
//!
//! Domain 0, the default of every DDS implementation, is never leased.

use std::collections::HashMap;
use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::PathBuf;
use std::sync::Mutex;

/// The highest domain id whose ports fit below 65 536 (DDSI-RTPS §9.6.1.1
/// with the default port parameters: 7400 + 250 × 232 + 11 + 2 × 119).
pub const MAX_DOMAIN: u32 = 232;

struct Leases {
    by_key: HashMap<u32, u32>,
    /// The locked files: closing one would release its domain.
    held: Vec<File>,
}

static LEASES: Mutex<Option<Leases>> = Mutex::new(None);

fn lock_dir() -> PathBuf {
    std::env::temp_dir().join("courier-test-domains")
}

/// Takes the lock of domain `d` if no other process holds it.
fn try_take(d: u32) -> Option<File> {
    let path = lock_dir().join(format!("{d}.lock"));
    let f = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .unwrap_or_else(|e| panic!("cannot open {}: {e}", path.display()));
    // SAFETY: flock on a descriptor this function owns; no memory involved.
    #[allow(unsafe_code)]
    let r = unsafe { libc::flock(f.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    (r == 0).then_some(f)
}

/// The domain id leased to `key` in this process: the same key gives the
/// same id for the life of the process, different keys different ids, and
/// no other process holding a lease has the same id at the same time.
///
/// # Panics
/// If all 232 domains are leased by other processes, or the lock directory
/// cannot be created: a test cannot run hermetically then.
pub fn lease(key: u32) -> u32 {
    let mut guard = LEASES.lock().unwrap_or_else(|e| e.into_inner());
    let leases = guard.get_or_insert_with(|| Leases {
        by_key: HashMap::new(),
        held: Vec::new(),
    });
    if let Some(&d) = leases.by_key.get(&key) {
        return d;
    }
    let dir = lock_dir();
    std::fs::create_dir_all(&dir)
        .unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    // Start where this process is unlikely to meet another one, then walk.
    let start = std::process::id() % MAX_DOMAIN;
    for i in 0..MAX_DOMAIN {
        let d = 1 + (start + i) % MAX_DOMAIN;
        if leases.by_key.values().any(|&x| x == d) {
            continue;
        }
        if let Some(f) = try_take(d) {
            leases.held.push(f);
            leases.by_key.insert(key, d);
            return d;
        }
    }
    panic!(
        "all DDS domains 1..={MAX_DOMAIN} are leased by other processes (locks in {})",
        dir.display()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_keeps_its_domain_and_keys_do_not_share() {
        let a = lease(1_000_001);
        let b = lease(1_000_002);
        assert_ne!(a, b);
        assert_eq!(lease(1_000_001), a);
        assert!((1..=MAX_DOMAIN).contains(&a));
        // another open file description cannot take a leased domain
        assert!(try_take(a).is_none(), "domain {a} is held");
    }
}

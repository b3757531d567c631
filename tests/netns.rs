//! Private network namespaces for the tests that need a network of their
//! own (loss and reordering with iptables, multicast discovery): the one
//! place such tests may send anything but unicast on `lo`.

use std::process::Command;

/// Runs a command; its stderr as the error when it fails.
pub fn sh(args: &[&str]) -> Result<(), String> {
    let Some((prog, rest)) = args.split_first() else {
        return Err("no command".into());
    };
    let out = Command::new(prog)
        .args(rest)
        .output()
        .map_err(|e| format!("cannot run {prog}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{} failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// A network namespace by name, removed however the test ends.
pub struct Netns(pub String);

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = sh(&["ip", "netns", "del", &self.0]);
    }
}

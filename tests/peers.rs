//! The RTPS interop peer programs of `tests/peers/rtps/` (a Cyclone DDS 0.10
//! and a Fast DDS 2.9 publisher/subscriber, see the README there): built on
//! first use and run as child processes whose output lines a test waits for.
//!
//! Building needs `idlc`, `cc`, `g++` and `pkg-config` on `PATH` and the
//! Debian packages `cyclonedds-tools cyclonedds-dev libfastrtps-dev
//! libfastcdr-dev build-essential pkg-config` (`.ci/run` installs them).
//! When something is missing the build functions return an error that names
//! it; callers panic with it, so a machine without the tools fails the tests
//! instead of skipping them.
//!
//! A program is built once per test process, into a fresh directory that is
//! then renamed to `target/courier-peers/<hash>/`, the hash covering its
//! sources and build recipe: test binaries building in parallel never see a
//! half-built program, and an unchanged program is not rebuilt.
//!
//! The peers only ever run their built-in loopback configuration (interface
//! `lo`, unicast discovery to 127.0.0.1, no multicast); tests choose the
//! domain with `--domain N`.

use std::ffi::OsStr;
use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Bumped whenever the way the programs are built changes, so that
/// `target/courier-peers/` is not reused across recipes.
const RECIPE: &str = "courier-peers recipe 1";

/// At most this much of a peer's stderr is kept for error messages.
const STDERR_CAP: usize = 64 * 1024;

/// The directory holding the peers' sources (`tests/peers/rtps`).
pub fn sources_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/rtps")
}

/// The Cyclone DDS peer, built on first use in this process.
pub fn cyclone_peer() -> Result<PathBuf, String> {
    static BUILT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    BUILT.get_or_init(|| build(Program::Cyclone)).clone()
}

/// The Fast DDS peer, built on first use in this process.
pub fn fastdds_peer() -> Result<PathBuf, String> {
    static BUILT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    BUILT.get_or_init(|| build(Program::FastDds)).clone()
}

/// Where `.ci/run` installs the `cyclonedds` Python package (11.x, with its
/// own Cyclone DDS 11 C library): a virtual environment in the target
/// directory (`target/` unless `CARGO_TARGET_DIR` says otherwise).
pub const CYCLONE11_VENV: &str = "cyclonedds-py";

/// The Python interpreter that has the `cyclonedds` package 11.x, for
/// [`cyclone11_peer_args`]: `COURIER_CYCLONEDDS_PYTHON` when set, else
/// `cyclonedds-py/bin/python` in the target directory (what `.ci/run`
/// makes). Checked once
/// per process; the error names what is missing and how to install it.
pub fn cyclone11_python() -> Result<PathBuf, String> {
    static FOUND: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    FOUND
        .get_or_init(|| {
            let python = match std::env::var_os("COURIER_CYCLONEDDS_PYTHON") {
                Some(p) => PathBuf::from(p),
                None => target_dir().join(CYCLONE11_VENV).join("bin/python"),
            };
            let venv = target_dir().join(CYCLONE11_VENV);
            let install = format!(
                "install it with `python3 -m venv {v} && {v}/bin/pip install \
                 'cyclonedds==11.*'` (what .ci/run does), or point COURIER_CYCLONEDDS_PYTHON at \
                 a Python that has it",
                v = venv.display()
            );
            if !python.exists() {
                return Err(format!(
                    "the Cyclone DDS 11 peer needs the cyclonedds Python package 11.x, and \
                     {} does not exist: {install}",
                    python.display()
                ));
            }
            let out = Command::new(&python)
                .args([
                    "-c",
                    "import cyclonedds.domain, importlib.metadata as m; \
                     print(m.version('cyclonedds'))",
                ])
                .output()
                .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
            let version = String::from_utf8_lossy(&out.stdout).trim().to_string();
            if !out.status.success() || !version.starts_with("11.") {
                return Err(format!(
                    "{} has no cyclonedds 11.x (version {version:?}; {}): {install}",
                    python.display(),
                    String::from_utf8_lossy(&out.stderr).trim()
                ));
            }
            Ok(python)
        })
        .clone()
}

/// The command line of the Cyclone DDS 11 peer (`cyclone11_peer.py`, run by
/// [`cyclone11_python`]) with `args`: spawn `cyclone11_python()` with these.
pub fn cyclone11_peer_args<S: AsRef<OsStr>>(args: &[S]) -> Vec<std::ffi::OsString> {
    let mut v = vec![sources_dir().join("cyclone11_peer.py").into_os_string()];
    v.extend(args.iter().map(|a| a.as_ref().to_os_string()));
    v
}

/// Byte `i` of the payload of sample `seq`, as both peers fill it.
pub fn payload(seq: u32, size: usize) -> Vec<u8> {
    (0..size)
        .map(|i| ((i as u32).wrapping_mul(7).wrapping_add(seq) & 0xff) as u8)
        .collect()
}

/// The `stamp` key `cyclone_peer` gives instance `id` of a `stamped`
/// sample (`courier::test::Stamped`): `0x0102030405060708 + id`, so that
/// every byte of it shows where it lands in a key hash.
pub fn stamp(id: i32) -> i64 {
    0x0102_0304_0506_0708 + i64::from(id)
}

/// FNV-1a (32 bit), the checksum the peers print for a payload.
pub fn fnv1a32(bytes: &[u8]) -> u32 {
    bytes.iter().fold(0x811c_9dc5, |h, &b| {
        (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
    })
}

/// The line a subscriber prints for a `msg` sample written by a peer
/// publisher: `sample <seq> <text> <len> <fnv1a32>` (the text must be free of
/// whitespace, `%` and `"`, which the peers escape).
pub fn msg_sample_line(seq: u32, text: &str, size: usize) -> String {
    format!(
        "sample {seq} {text} {size} {:08x}",
        fnv1a32(&payload(seq, size))
    )
}

// ---------------------------------------------------------------------------
// Building

#[derive(Clone, Copy, Debug)]
enum Program {
    Cyclone,
    FastDds,
}

impl Program {
    fn exe_name(self) -> &'static str {
        match self {
            Program::Cyclone => "cyclone_peer",
            Program::FastDds => "fastdds_peer",
        }
    }

    fn sources(self) -> &'static [&'static str] {
        match self {
            Program::Cyclone => &["types.idl", "cyclone_peer.c"],
            Program::FastDds => &["fastdds_peer.cpp"],
        }
    }
}

const C_FLAGS: &[&str] = &["-std=gnu11", "-O2", "-Wall", "-Wextra", "-Werror"];
const CXX_FLAGS: &[&str] = &["-std=c++17", "-O2", "-Wall", "-Wextra", "-Werror"];
const CXX_LIBS: &[&str] = &["-lfastrtps", "-lfastcdr", "-pthread"];

/// 64-bit FNV-1a, for naming build directories after their inputs.
struct Fnv64(u64);

impl Fnv64 {
    fn new() -> Self {
        Fnv64(0xcbf2_9ce4_8422_2325)
    }

    fn add(&mut self, bytes: &[u8]) {
        // length first, so that ("ab", "c") and ("a", "bc") differ
        for &b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// `target/` of this workspace: `CARGO_TARGET_DIR` when set, otherwise the
/// directory above the running test binary that cargo marked with
/// `CACHEDIR.TAG`, otherwise `<workspace>/target`.
fn target_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("CARGO_TARGET_DIR") {
        let dir = PathBuf::from(dir);
        return if dir.is_absolute() {
            dir
        } else {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(dir)
        };
    }
    if let Ok(exe) = std::env::current_exe() {
        if let Some(dir) = exe
            .ancestors()
            .skip(1)
            .find(|d| d.join("CACHEDIR.TAG").is_file())
        {
            return dir.to_path_buf();
        }
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../target")
}

/// Runs a build step; errors name the tool and, through `package`, the
/// Debian package that provides it.
fn run_step(cmd: &mut Command, package: &str) -> Result<std::process::Output, String> {
    let tool = cmd.get_program().to_string_lossy().into_owned();
    let out = cmd.output().map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            format!("{tool} not found on PATH: install the Debian package {package}")
        } else {
            format!("cannot run {tool}: {e}")
        }
    })?;
    if out.status.success() {
        Ok(out)
    } else {
        Err(format!(
            "{cmd:?} failed ({}):\n{}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

/// Runs Cyclone DDS's IDL compiler, `idlc <args> <idl>`, in `out_dir`
/// (where it writes its `.c` and `.h`). The error names the Debian package
/// `cyclonedds-tools` when `idlc` is not on `PATH`, and carries idlc's
/// output when it refuses the IDL.
pub fn run_idlc(args: &[&str], idl: &Path, out_dir: &Path) -> Result<(), String> {
    run_step(
        Command::new("idlc")
            .args(args)
            .arg(idl)
            .current_dir(out_dir),
        "cyclonedds-tools",
    )
    .map(drop)
}

/// `pkg-config --cflags --libs CycloneDDS`, split into arguments.
fn cyclone_flags() -> Result<Vec<String>, String> {
    let out = run_step(
        Command::new("pkg-config").args(["--cflags", "--libs", "CycloneDDS"]),
        "pkg-config",
    )
    .map_err(|e| {
        if e.starts_with("pkg-config not found") {
            e
        } else {
            format!("cyclonedds-dev not installed: pkg-config CycloneDDS failed: {e}")
        }
    })?;
    Ok(String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .map(str::to_owned)
        .collect())
}

/// What a failed Fast DDS compile most likely lacks.
fn fastdds_hint(err: &str) -> Option<&'static str> {
    let missing_header = |dir: &str| err.contains(dir) && err.contains("No such file");
    if missing_header("fastcdr/") || err.contains("-lfastcdr") {
        Some("libfastcdr-dev not installed")
    } else if missing_header("fastdds/")
        || missing_header("fastrtps/")
        || err.contains("-lfastrtps")
    {
        Some("libfastrtps-dev not installed")
    } else {
        None
    }
}

fn build(program: Program) -> Result<PathBuf, String> {
    let src = sources_dir();
    let name = program.exe_name();

    let cyclone_flags = match program {
        Program::Cyclone => cyclone_flags()?,
        Program::FastDds => Vec::new(),
    };
    let mut hash = Fnv64::new();
    hash.add(RECIPE.as_bytes());
    hash.add(name.as_bytes());
    for file in program.sources() {
        let path = src.join(file);
        let text =
            std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        hash.add(file.as_bytes());
        hash.add(&text);
    }
    for flag in C_FLAGS.iter().chain(CXX_FLAGS).chain(CXX_LIBS) {
        hash.add(flag.as_bytes());
    }
    for flag in &cyclone_flags {
        hash.add(flag.as_bytes());
    }

    let root = target_dir().join("courier-peers");
    let dir = root.join(format!("{:016x}", hash.0));
    let exe = dir.join(name);
    if exe.is_file() {
        return Ok(exe);
    }

    std::fs::create_dir_all(&root).map_err(|e| format!("cannot create {}: {e}", root.display()))?;
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    let tmp = root.join(format!(".build-{name}-{}-{nanos}", std::process::id()));
    std::fs::create_dir(&tmp).map_err(|e| format!("cannot create {}: {e}", tmp.display()))?;
    let result = compile(program, &src, &tmp, &cyclone_flags).and_then(|()| {
        match std::fs::rename(&tmp, &dir) {
            Ok(()) => Ok(()),
            // another test process finished the same build first
            Err(_) if exe.is_file() => Ok(()),
            Err(e) => Err(format!(
                "cannot rename {} to {}: {e}",
                tmp.display(),
                dir.display()
            )),
        }
    });
    let _ = std::fs::remove_dir_all(&tmp);
    result.map(|()| exe)
}

fn compile(
    program: Program,
    src: &Path,
    out: &Path,
    cyclone_flags: &[String],
) -> Result<(), String> {
    let exe = out.join(program.exe_name());
    match program {
        Program::Cyclone => {
            run_idlc(&["-x", "final"], &src.join("types.idl"), out)?;
            run_step(
                Command::new("cc")
                    .args(C_FLAGS)
                    .arg("-o")
                    .arg(&exe)
                    .arg("-I")
                    .arg(out)
                    .arg(src.join("cyclone_peer.c"))
                    .arg(out.join("types.c"))
                    .args(cyclone_flags),
                "build-essential",
            )
            .map_err(|e| format!("building cyclone_peer: {e}"))?;
        }
        Program::FastDds => {
            run_step(
                Command::new("g++")
                    .args(CXX_FLAGS)
                    .arg("-o")
                    .arg(&exe)
                    .arg(src.join("fastdds_peer.cpp"))
                    .args(CXX_LIBS),
                "build-essential",
            )
            .map_err(|e| match fastdds_hint(&e) {
                Some(hint) => format!("{hint}: building fastdds_peer: {e}"),
                None => format!("building fastdds_peer: {e}"),
            })?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Running

/// A running peer program with its stdout read line by line on a background
/// thread and its stderr collected on another; its stdin is a pipe for
/// [`send_line`](Self::send_line) (the go signal of `--wait-stdin`).
/// Dropping it kills and reaps the process. (Should the test process itself die without unwinding, the
/// peers notice that their parent is gone and exit with code 3, and they
/// always end by themselves after `--timeout-s`.)
pub struct PeerProcess {
    child: Child,
    name: String,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    seen: Vec<String>,
    stderr: Arc<Mutex<String>>,
    stderr_reader: Option<JoinHandle<()>>,
    status: Option<ExitStatus>,
}

impl PeerProcess {
    /// Starts `path` with `args`, stdin, stdout and stderr piped.
    pub fn spawn<S: AsRef<OsStr>>(path: impl AsRef<Path>, args: &[S]) -> Result<Self, String> {
        let path = path.as_ref();
        let mut name = path
            .file_name()
            .unwrap_or(path.as_os_str())
            .to_string_lossy()
            .into_owned();
        for a in args {
            name.push(' ');
            name.push_str(&a.as_ref().to_string_lossy());
        }
        let mut child = Command::new(path)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot start {name}: {e}"))?;
        let stdin = child.stdin.take();
        let out = child.stdout.take().expect("piped stdout");
        let mut err = child.stderr.take().expect("piped stderr");
        let (tx, lines) = mpsc::channel();
        spawn_line_reader(out, tx);
        let stderr = Arc::new(Mutex::new(String::new()));
        let sink = Arc::clone(&stderr);
        let stderr_reader = thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = err.read(&mut buf) {
                let mut s = sink.lock().unwrap_or_else(|p| p.into_inner());
                if s.len() < STDERR_CAP {
                    s.push_str(&String::from_utf8_lossy(&buf[..n]));
                }
            }
        });
        Ok(PeerProcess {
            child,
            name,
            stdin,
            lines,
            seen: Vec::new(),
            stderr,
            stderr_reader: Some(stderr_reader),
            status: None,
        })
    }

    /// The program and its arguments, for messages.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Every stdout line read so far, in order.
    pub fn seen(&self) -> &[String] {
        &self.seen
    }

    /// Writes `line` and a newline to the process's stdin.
    pub fn send_line(&mut self, line: &str) -> Result<(), String> {
        let stdin = self
            .stdin
            .as_mut()
            .ok_or_else(|| format!("{}: stdin already closed", self.name))?;
        stdin
            .write_all(format!("{line}\n").as_bytes())
            .and_then(|()| stdin.flush())
            .map_err(|e| format!("{}: cannot write to stdin: {e}", self.name))
    }

    /// Closes the process's stdin (end of input).
    pub fn close_stdin(&mut self) {
        self.stdin = None;
    }

    /// What the process wrote to stderr so far (the first 64 KiB).
    pub fn stderr(&self) -> String {
        self.stderr
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Reads stdout lines until one starts with `prefix` and returns it; the
    /// lines before it are consumed (they stay in [`seen`](Self::seen)).
    /// Fails after `timeout`, or when stdout ends first, with every line seen
    /// and stderr in the message.
    pub fn expect_line(&mut self, prefix: &str, timeout: Duration) -> Result<String, String> {
        let mut lines = self.lines_until(prefix, timeout)?;
        Ok(lines.pop().expect("lines_until returns the matching line"))
    }

    /// Like [`expect_line`](Self::expect_line), but returns every line read,
    /// the one starting with `prefix` last.
    pub fn lines_until(&mut self, prefix: &str, timeout: Duration) -> Result<Vec<String>, String> {
        let deadline = Instant::now() + timeout;
        let mut got = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    self.seen.push(line.clone());
                    let done = line.starts_with(prefix);
                    got.push(line);
                    if done {
                        return Ok(got);
                    }
                }
                Err(RecvTimeoutError::Timeout) => {
                    return Err(self.failure(&format!(
                        "no line starting with {prefix:?} within {timeout:?}"
                    )))
                }
                Err(RecvTimeoutError::Disconnected) => {
                    // give the exit status a moment to be collectable
                    let _ = self.wait(Duration::from_millis(200));
                    return Err(self.failure(&format!(
                        "stdout ended without a line starting with {prefix:?}"
                    )));
                }
            }
        }
    }

    /// The next `n` lines starting with `prefix` (other lines are consumed
    /// and skipped), all within `timeout`.
    pub fn expect_lines(
        &mut self,
        prefix: &str,
        n: usize,
        timeout: Duration,
    ) -> Result<Vec<String>, String> {
        let deadline = Instant::now() + timeout;
        (0..n)
            .map(|_| self.expect_line(prefix, deadline.saturating_duration_since(Instant::now())))
            .collect()
    }

    /// Waits up to `timeout` for the process to exit. On timeout the
    /// process is left running (dropping the `PeerProcess` kills it).
    pub fn wait(&mut self, timeout: Duration) -> Result<ExitStatus, String> {
        if let Some(st) = self.status {
            return Ok(st);
        }
        let deadline = Instant::now() + timeout;
        loop {
            match self.child.try_wait() {
                Ok(Some(st)) => {
                    self.status = Some(st);
                    return Ok(st);
                }
                Ok(None) if Instant::now() < deadline => thread::sleep(Duration::from_millis(10)),
                Ok(None) => return Err(self.failure(&format!("still running after {timeout:?}"))),
                Err(e) => return Err(self.failure(&format!("cannot wait for it: {e}"))),
            }
        }
    }

    /// Waits up to `timeout` for the process to exit with status 0.
    pub fn wait_success(&mut self, timeout: Duration) -> Result<(), String> {
        let st = self.wait(timeout)?;
        if st.success() {
            Ok(())
        } else {
            Err(self.failure(&format!("exited with {st}")))
        }
    }

    /// Kills the process (if it still runs) and reaps it.
    pub fn kill(&mut self) {
        self.stdin = None;
        if self.status.is_none() {
            let _ = self.child.kill();
            if let Ok(st) = self.child.wait() {
                self.status = Some(st);
            }
        }
    }

    /// An error message: what went wrong, the lines seen so far (including
    /// any not read yet) and stderr.
    fn failure(&mut self, what: &str) -> String {
        while let Ok(line) = self.lines.try_recv() {
            self.seen.push(line);
        }
        let status = match self.status {
            Some(st) => format!("exited with {st}"),
            None => match self.child.try_wait() {
                Ok(Some(st)) => {
                    self.status = Some(st);
                    format!("exited with {st}")
                }
                _ => "still running".to_owned(),
            },
        };
        if self.status.is_some() {
            // the process is gone: let the stderr reader reach end of file
            // (bounded, should the pipe be shared with a process of its own)
            let deadline = Instant::now() + Duration::from_millis(500);
            while self
                .stderr_reader
                .as_ref()
                .is_some_and(|h| !h.is_finished())
                && Instant::now() < deadline
            {
                thread::sleep(Duration::from_millis(5));
            }
            if let Some(h) = self.stderr_reader.take_if(|h| h.is_finished()) {
                let _ = h.join();
            }
        }
        let mut msg = format!("{}: {what} ({status})\n--- stdout:\n", self.name);
        for line in &self.seen {
            let _ = writeln!(msg, "{line}");
        }
        let _ = write!(msg, "--- stderr:\n{}", self.stderr());
        msg
    }
}

impl Drop for PeerProcess {
    fn drop(&mut self) {
        self.kill();
    }
}

fn spawn_line_reader(out: ChildStdout, tx: mpsc::Sender<String>) {
    thread::spawn(move || {
        for line in BufReader::new(out).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_fast_dds_packages_are_named() {
        let header = "fastdds_peer.cpp:42:10: fatal error: fastdds/dds/log/Log.hpp: \
                      No such file or directory";
        assert_eq!(fastdds_hint(header), Some("libfastrtps-dev not installed"));
        let cdr = "fatal error: fastcdr/Cdr.h: No such file or directory";
        assert_eq!(fastdds_hint(cdr), Some("libfastcdr-dev not installed"));
        let lib = "/usr/bin/ld: cannot find -lfastrtps: No such file or directory";
        assert_eq!(fastdds_hint(lib), Some("libfastrtps-dev not installed"));
        assert_eq!(fastdds_hint("error: expected ';'"), None);
    }

    #[test]
    fn msg_sample_line_matches_the_peers() {
        // as printed by both peers for `--size 204800`, sample 1
        assert_eq!(
            msg_sample_line(1, "cyclone-1", 204_800),
            "sample 1 cyclone-1 204800 5b81ddc5"
        );
        assert_eq!(msg_sample_line(7, "x", 0), "sample 7 x 0 811c9dc5");
    }
}

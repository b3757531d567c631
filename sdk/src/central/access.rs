//! Access control in the style of `hosts_access(5)`, as the C central does
//! it when built with `ACCESS_CONTROL` (IPC manual, "Access Control").
//!
//! Two files, by default `/etc/hosts.allow` and `/etc/hosts.deny`, hold
//! lines `daemon_list : client_list [: options]`; the daemon name is
//! `central`. A connection is **allowed** if a rule of the allow file
//! matches it, else **denied** if a rule of the deny file matches it, else
//! allowed. `#` starts a comment, a
//! backslash at the end of a line continues it, list items are separated by
//! commas and/or blanks, and the options field is ignored.
//!
//! Patterns (daemon and client lists alike may use `ALL` and `EXCEPT`):
//!
//! | pattern | matches |
//! |---|---|
//! | `ALL` | everything |
//! | `a EXCEPT b` | what `a` matches and `b` does not (nests to the right) |
//! | `localhost` | loopback addresses (127.0.0.0/8, `::1`) and UNIX-socket peers |
//! | `LOCAL` | the same, and any peer whose (verified) host name has no dot |
//! | `10.0.0.5`, `[::1]`, `::1` | that address (IPv4-mapped IPv6 peers count as IPv4) |
//! | `10.0.0.` | addresses starting so (trailing dot: a prefix) |
//! | `10.0.0.0/255.255.255.0`, `10.0.0.0/24`, `[fe80::]/10` | a network |
//! | `.cs.cmu.edu` | peers whose verified host name ends so |
//! | `host.example.org` | the addresses the name resolves to **when the file is read** |
//! | `KNOWN`, `UNKNOWN`, `PARANOID` | peers with a verified name, without one, and whose name does not map back to their address |
//! | `10.0.*.1`, `*.example.org` | `*`/`?` wildcards over the address text or the verified name |
//!
//! **Host names.** A host name in a rule is resolved forward when its file
//! is read ([`AccessControl::load`], and again each time the file's text
//! changes, see below); the rule then matches the addresses it had then.
//! A name that does not resolve matches nothing and gives a warning
//! ([`AccessControl::warnings`]). Only domain suffixes,
//! wildcards over names, `KNOWN`, `UNKNOWN`, `PARANOID` and `LOCAL` (for
//! non-loopback peers) need the peer's own name; for those alone central
//! looks the peer's address up (reverse DNS, then forward again to verify
//! it, as tcpd's `PARANOID` mode does), off the accept path and bounded in
//! time. Rules without such patterns never touch DNS.
//!
//! **UNIX-socket peers** are local: they are checked as if they came from
//! the loopback address (127.0.0.1 or `::1`) with the host name
//! `localhost`.
//!
//! **Files are read again when they change**, as tcpd (which the C central
//! links) reads them at every connection. An [`AccessControl`] loaded from
//! files ([`AccessControl::load`], [`AccessControl::load_files`],
//! [`AccessControl::load_default`]) looks at their metadata (size,
//! modification and change times, inode) at each check; when that changed
//! since the file was last read, it reads the file again, and if its text
//! changed, parses it (resolving its host names) and puts the new rules in
//! force for that same check. An edit to `hosts.deny` thus refuses the very
//! next connection, without a restart. Failures fail closed: a file that
//! disappeared, became unreadable, or now holds a malformed rule for
//! `central` leaves the rules last read from it in force, with one warning
//! (a `tracing` event at WARN) naming the file and the reason, given once
//! per change of the file; the next valid edit is taken up as usual. A
//! default file that did not exist at start is read once it appears. Each
//! file read again is logged at INFO, and its own warnings (skipped rules,
//! names that do not resolve) at WARN. The host names of a new text are
//! resolved during the check that reads it, which waits for the resolver
//! (as tcpd's checks do). Rules built from text ([`AccessControl::new`])
//! are never read again.
//!
//! **Missing files fail closed.** A file named by the operator
//! ([`Rules::load`], [`AccessControl::load`], [`RulesFile::Given`]) that
//! does not exist or cannot be read is an error naming the file and the
//! OS error: a typo in a path must not leave central open to everyone.
//! Only the default locations ([`RulesFile::Default`],
//! [`AccessControl::load_default`]) may be missing; a missing default
//! holds no rules, and [`AccessControl::missing_files_warning`] gives the
//! one line to print about it.
//!
//! **Errors.** A malformed rule for `central` (or `ALL`) is an error naming
//! the file and line; a malformed rule that can only concern other daemons
//! (whose syntax this parser need not know, e.g. NIS `@netgroups`) is
//! skipped with a warning.
//!
//! ```
//! use courier::central::access::{AccessControl, Client, Rules};
//! let allow = Rules::parse("central : localhost, 10.0.0.5\n", "hosts.allow").unwrap();
//! let deny = Rules::parse("ALL : ALL\n", "hosts.deny").unwrap();
//! let ac = AccessControl::new(allow, deny);
//! assert!(ac.check(Client::Ip("127.0.0.1".parse().unwrap())).is_allowed());
//! assert!(ac.check(Client::Ip("10.0.0.5".parse().unwrap())).is_allowed());
//! assert!(ac.check(Client::Unix).is_allowed());
//! let refused = ac.check(Client::Ip("192.0.2.9".parse().unwrap()));
//! assert_eq!(refused.to_string(), "denied by hosts.deny:1");
//! ```

use std::fmt;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

/// The daemon name rules must name (or `ALL`).
pub const DAEMON: &str = "central";

/// The default allow file.
pub const DEFAULT_ALLOW: &str = "/etc/hosts.allow";

/// The default deny file.
pub const DEFAULT_DENY: &str = "/etc/hosts.deny";

/// Who is connecting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Client {
    /// A TCP peer with this address.
    Ip(IpAddr),
    /// A peer on the UNIX socket (a local client).
    Unix,
}

impl From<IpAddr> for Client {
    fn from(ip: IpAddr) -> Self {
        Client::Ip(ip)
    }
}

/// What a reverse lookup of a peer's address found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostName {
    /// A name whose forward lookup includes the address.
    Verified(String),
    /// A name whose forward lookup does not include the address (possibly
    /// forged); it is never used to match names.
    Unverified(String),
    /// No name.
    Unknown,
}

/// A rule's place: `file:line`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RuleRef {
    /// The file, as given.
    pub file: String,
    /// 1-based line number (the first line of a continued line).
    pub line: usize,
}

impl fmt::Display for RuleRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.file, self.line)
    }
}

/// The decision for one connection.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decision {
    /// Allowed by a rule of the allow file, or by default (`None`).
    Allowed(Option<RuleRef>),
    /// Denied by this rule of the deny file.
    Denied(RuleRef),
}

impl Decision {
    /// True for [`Decision::Allowed`].
    pub fn is_allowed(&self) -> bool {
        matches!(self, Decision::Allowed(_))
    }
}

impl fmt::Display for Decision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Decision::Allowed(Some(r)) => write!(f, "allowed by {r}"),
            Decision::Allowed(None) => f.write_str("allowed (no rule matched)"),
            Decision::Denied(r) => write!(f, "denied by {r}"),
        }
    }
}

/// A malformed line in a hosts file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}:{line}: {what}")]
pub struct ParseError {
    /// File name as given.
    pub file: String,
    /// 1-based line number.
    pub line: usize,
    /// What is wrong.
    pub what: String,
}

/// A hosts file could not be read or parsed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The file does not exist or could not be read.
    #[error("cannot read {file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A line is malformed.
    #[error(transparent)]
    Parse(#[from] ParseError),
}

#[derive(Debug, Clone, PartialEq)]
enum Pattern {
    All,
    Local,
    Localhost,
    Known,
    Unknown,
    Paranoid,
    Addr(IpAddr),
    /// `10.0.0.` (text prefix of the dotted address).
    Prefix(String),
    Net(IpAddr, u32),
    /// `.domain` (lower case, with the dot).
    Suffix(String),
    /// A host name and the addresses it resolved to.
    Name {
        name: String,
        addrs: Vec<IpAddr>,
    },
    /// Contains `*` or `?` (lower case).
    Wildcard(String),
    /// A daemon name.
    Daemon(String),
}

impl Pattern {
    fn needs_host_name(&self) -> bool {
        match self {
            Pattern::Local | Pattern::Known | Pattern::Unknown | Pattern::Paranoid => true,
            Pattern::Suffix(_) => true,
            Pattern::Wildcard(w) => w.chars().any(|c| c.is_ascii_alphabetic()),
            _ => false,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
struct List {
    include: Vec<Pattern>,
    except: Option<Box<List>>,
}

impl List {
    fn matches(&self, m: &mut dyn FnMut(&Pattern) -> bool) -> bool {
        self.include.iter().any(&mut *m) && !self.except.as_ref().is_some_and(|e| e.matches(m))
    }

    fn patterns(&self) -> Vec<&Pattern> {
        let mut v: Vec<&Pattern> = self.include.iter().collect();
        if let Some(e) = &self.except {
            v.extend(e.patterns());
        }
        v
    }

    fn patterns_mut(&mut self) -> Vec<&mut Pattern> {
        let mut v: Vec<&mut Pattern> = self.include.iter_mut().collect();
        if let Some(e) = &mut self.except {
            v.extend(e.patterns_mut());
        }
        v
    }
}

#[derive(Debug, Clone, PartialEq)]
struct Rule {
    daemons: List,
    clients: List,
    line: usize,
}

/// The rules of one file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rules {
    file: String,
    rules: Vec<Rule>,
    warnings: Vec<String>,
}

impl Rules {
    /// Reads and parses a file, then resolves the host names in it. A file
    /// that does not exist or cannot be read is an error
    /// ([`LoadError::Io`]): rules the operator named must be in force.
    pub fn load(path: &Path) -> Result<Rules, LoadError> {
        let name = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => Ok(Rules::from_text(&text, &name)?),
            Err(source) => Err(LoadError::Io { file: name, source }),
        }
    }

    /// Like [`Rules::load`], but a file that does not exist gives `None`
    /// (for default locations, which need not exist). Any other error
    /// reading it is still an error.
    pub fn load_if_exists(path: &Path) -> Result<Option<Rules>, LoadError> {
        let name = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => Ok(Some(Rules::from_text(&text, &name)?)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(LoadError::Io { file: name, source }),
        }
    }

    /// Parses and resolves names with the system resolver.
    fn from_text(text: &str, name: &str) -> Result<Rules, ParseError> {
        let mut rules = Rules::parse(text, name)?;
        rules.resolve_names(&mut |name| {
            (name, 0)
                .to_socket_addrs()
                .map(|a| a.map(|s| s.ip()).collect())
                .unwrap_or_default()
        });
        Ok(rules)
    }

    /// Parses the text of a file called `file` (the name is for messages).
    /// Host names stay unresolved (matching nothing) until
    /// [`Rules::resolve_names`].
    pub fn parse(text: &str, file: &str) -> Result<Rules, ParseError> {
        let mut rules = Rules {
            file: file.to_string(),
            ..Rules::default()
        };
        let mut logical = String::new();
        let mut start = 0;
        for (i, raw) in text.lines().enumerate() {
            if logical.is_empty() {
                start = i + 1;
            }
            if let Some(cont) = raw.strip_suffix('\\') {
                logical.push_str(cont);
                logical.push(' ');
                continue;
            }
            logical.push_str(raw);
            let l = std::mem::take(&mut logical);
            rules.parse_line(&l, start)?;
        }
        if !logical.is_empty() {
            rules.parse_line(&logical.clone(), start)?;
        }
        Ok(rules)
    }

    /// Resolves every host name pattern with `resolve` (name → addresses);
    /// a name without addresses gives a warning and matches nothing.
    pub fn resolve_names(&mut self, resolve: &mut dyn FnMut(&str) -> Vec<IpAddr>) {
        let file = self.file.clone();
        let mut warnings = Vec::new();
        for rule in &mut self.rules {
            // Other daemons' names are none of central's business.
            if !rule.daemons.matches(&mut daemon_matches) {
                continue;
            }
            for p in rule.clients.patterns_mut() {
                if let Pattern::Name { name, addrs } = p {
                    *addrs = resolve(name).into_iter().map(unmap).collect();
                    if addrs.is_empty() {
                        warnings.push(format!(
                            "{file}:{}: host name '{name}' does not resolve; the rule never matches it",
                            rule.line
                        ));
                    }
                }
            }
        }
        self.warnings.extend(warnings);
    }

    /// Lines skipped or patterns that cannot match.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The file name given when loading or parsing.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// Number of rules (lines with a daemon and a client list).
    pub fn len(&self) -> usize {
        self.rules.len()
    }

    /// True if there are no rules.
    pub fn is_empty(&self) -> bool {
        self.rules.is_empty()
    }

    fn parse_line(&mut self, line: &str, n: usize) -> Result<(), ParseError> {
        let err = |what: String| ParseError {
            file: self.file.clone(),
            line: n,
            what,
        };
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            return Ok(());
        }
        // Daemon names hold no colons: the first one ends the daemon list.
        let Some((daemons, rest)) = line.split_once(':') else {
            return Err(err(format!(
                "expected 'daemon_list : client_list', found '{line}'"
            )));
        };
        let daemons = daemons.trim();
        if daemons.is_empty() {
            return Err(err("empty daemon list".into()));
        }
        let daemons = parse_list(&words(daemons), true).map_err(&err)?;
        let concerns_us = daemons.matches(&mut daemon_matches);
        let clients = match client_words(rest) {
            Ok(w) if w.is_empty() => Err("empty client list".to_string()),
            Ok(w) => parse_list(&w, false),
            Err(e) => Err(e),
        };
        let clients = match clients {
            Ok(c) => c,
            Err(e) if concerns_us => return Err(err(e)),
            Err(e) => {
                self.warnings.push(format!(
                    "{}:{n}: rule skipped (it does not concern central): {e}",
                    self.file
                ));
                return Ok(());
            }
        };
        self.rules.push(Rule {
            daemons,
            clients,
            line: n,
        });
        Ok(())
    }

    fn needs_host_name(&self) -> bool {
        self.rules.iter().any(|r| {
            r.daemons.matches(&mut daemon_matches)
                && r.clients.patterns().iter().any(|p| p.needs_host_name())
        })
    }

    /// The first rule matching `central` and this client.
    fn matching(&self, client: Client, name: &mut Lazy<'_>) -> Option<RuleRef> {
        self.rules
            .iter()
            .find(|r| {
                r.daemons.matches(&mut daemon_matches)
                    && r.clients.matches(&mut |p| client_matches(p, client, name))
            })
            .map(|r| RuleRef {
                file: self.file.clone(),
                line: r.line,
            })
    }
}

/// Where a rules file is to be read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RulesFile<'a> {
    /// Named by the operator (`--hosts-allow`, `--hosts-deny`): it must
    /// exist and be readable.
    Given(&'a Path),
    /// A default location (`/etc/hosts.allow`, `/etc/hosts.deny`): if it
    /// does not exist, it holds no rules.
    Default(&'a Path),
}

impl<'a> RulesFile<'a> {
    fn as_path(self) -> &'a Path {
        match self {
            RulesFile::Given(p) | RulesFile::Default(p) => p,
        }
    }

    /// Reads and parses the file; `Ok(None)`: a default file that does not
    /// exist. Also returns what is needed to notice a change later.
    fn load(self) -> Result<Option<(Rules, Stamp, String)>, LoadError> {
        let path = self.as_path();
        let name = path.display().to_string();
        // Looked at before reading: a change made while reading is then
        // seen at the next check.
        let stamp = std::fs::metadata(path).map(|m| Stamp::of(&m, SystemTime::now()));
        let text = match std::fs::read_to_string(path) {
            Ok(text) => text,
            Err(e)
                if e.kind() == std::io::ErrorKind::NotFound
                    && matches!(self, RulesFile::Default(_)) =>
            {
                return Ok(None)
            }
            Err(source) => return Err(LoadError::Io { file: name, source }),
        };
        let rules = Rules::from_text(&text, &name)?;
        // Read although it could not be looked at: look again next time.
        let stamp = stamp.unwrap_or(Stamp::UNKNOWN);
        Ok(Some((rules, stamp, text)))
    }
}

/// What is looked at to notice that a rules file changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Stamp {
    len: u64,
    modified: Option<SystemTime>,
    /// Status change time (seconds, nanoseconds): a rename over the file,
    /// a `chmod`.
    changed: (i64, i64),
    inode: (u64, u64),
    /// Modified so shortly before it was looked at that a second change
    /// within the file system's clock granularity could leave the same
    /// stamp: the text is compared again at the next check.
    recent: bool,
}

impl Stamp {
    /// A file that was read but could not be looked at.
    const UNKNOWN: Stamp = Stamp {
        len: u64::MAX,
        modified: None,
        changed: (0, 0),
        inode: (0, 0),
        recent: true,
    };

    /// How long after its modification time a file counts as recent.
    const RECENT: Duration = Duration::from_secs(2);

    fn of(m: &std::fs::Metadata, now: SystemTime) -> Stamp {
        #[cfg(unix)]
        let (changed, inode) = {
            use std::os::unix::fs::MetadataExt;
            ((m.ctime(), m.ctime_nsec()), (m.dev(), m.ino()))
        };
        #[cfg(not(unix))]
        let (changed, inode) = ((0, 0), (0, 0));
        let modified = m.modified().ok();
        let recent = modified.is_none_or(|t| {
            now.duration_since(t)
                .map_or(true, |age| age < Stamp::RECENT)
        });
        Stamp {
            len: m.len(),
            modified,
            changed,
            inode,
            recent,
        }
    }

    /// The same file, unchanged (ignoring when it was looked at).
    fn same_as(&self, other: &Stamp) -> bool {
        (self.len, self.modified, self.changed, self.inode)
            == (other.len, other.modified, other.changed, other.inode)
    }
}

/// Why a rules file could not be read again (each warned about once).
#[derive(Debug, Clone, PartialEq, Eq)]
enum Trouble {
    /// It no longer exists.
    Gone,
    /// It cannot be looked at (this error).
    Stat(String),
    /// This version of it cannot be read or parsed.
    Version(Stamp),
}

/// A rules file read again when it changes.
#[derive(Debug, Clone)]
struct Watched {
    path: PathBuf,
    name: String,
    /// The deny file (else the allow file).
    deny: bool,
    /// The file as last read successfully, and its text; `None`: a default
    /// file that did not exist.
    read: Option<(Stamp, String)>,
    /// What the last warning was about.
    warned: Option<Trouble>,
}

impl Watched {
    /// Looks at the file; new rules if it changed and reads and parses
    /// well. Otherwise the rules in force stay, with a warning (once) if
    /// the file cannot be read again.
    fn check(&mut self, now: SystemTime) -> Option<Rules> {
        let stamp = match std::fs::metadata(&self.path) {
            Ok(m) => Stamp::of(&m, now),
            // A default file that never existed holds no rules still.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound && self.read.is_none() => {
                return None
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                self.warn(Trouble::Gone, format!("{} no longer exists", self.name));
                return None;
            }
            Err(e) => {
                let why = format!("cannot look at {}: {e}", self.name);
                self.warn(Trouble::Stat(e.to_string()), why);
                return None;
            }
        };
        let unchanged = self
            .read
            .as_ref()
            .is_some_and(|(seen, _)| seen.same_as(&stamp))
            || matches!(&self.warned, Some(Trouble::Version(bad)) if bad.same_as(&stamp));
        if unchanged && !stamp.recent {
            return None;
        }
        let text = match std::fs::read_to_string(&self.path) {
            Ok(t) => t,
            Err(e) => {
                let why = format!("cannot read {}: {e}", self.name);
                self.warn(Trouble::Version(stamp), why);
                return None;
            }
        };
        if let Some((seen, old)) = &mut self.read {
            if *old == text {
                // Touched, or written back as it was: nothing to parse.
                *seen = stamp;
                if self.warned.take().is_some() {
                    tracing::info!("access rules: {} is readable again, as it was", self.name);
                }
                return None;
            }
        }
        match Rules::from_text(&text, &self.name) {
            Ok(rules) => {
                tracing::info!(
                    "access rules: read {} again: {} rule(s)",
                    self.name,
                    rules.len()
                );
                for w in rules.warnings() {
                    tracing::warn!("access rules: {w}");
                }
                self.read = Some((stamp, text));
                self.warned = None;
                Some(rules)
            }
            Err(e) => {
                self.warn(Trouble::Version(stamp), e.to_string());
                None
            }
        }
    }

    /// One warning per trouble: a check that meets the same one again
    /// says nothing.
    fn warn(&mut self, trouble: Trouble, why: String) {
        let again = match (&self.warned, &trouble) {
            (Some(Trouble::Version(a)), Trouble::Version(b)) => a.same_as(b),
            (a, b) => a.as_ref() == Some(b),
        };
        if again {
            return;
        }
        let kept = if self.read.is_some() {
            format!("the rules last read from {} stay in force", self.name)
        } else {
            format!("no rules from {} are in force", self.name)
        };
        tracing::warn!("access rules: {why}; {kept}");
        self.warned = Some(trouble);
    }
}

/// The rules in force.
#[derive(Debug, Clone, Default, PartialEq)]
struct Current {
    allow: Rules,
    deny: Rules,
    /// Default files that did not exist: (allow, deny).
    missing: (Option<String>, Option<String>),
}

#[derive(Debug, Clone, Default)]
struct State {
    current: Arc<Current>,
    /// The files to read again when they change (none for rules built
    /// from text).
    watched: Vec<Watched>,
}

/// Allow and deny rules together.
///
/// Loaded from files, it reads a file again when it changes (see the
/// [module documentation](self)); checks may come from several threads.
#[derive(Default)]
pub struct AccessControl {
    state: Mutex<State>,
}

impl fmt::Debug for AccessControl {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = self.lock();
        f.debug_struct("AccessControl")
            .field("allow", &s.current.allow)
            .field("deny", &s.current.deny)
            .field("missing", &s.current.missing)
            .field(
                "watched",
                &s.watched.iter().map(|w| &w.path).collect::<Vec<_>>(),
            )
            .finish()
    }
}

impl Clone for AccessControl {
    /// A copy with the same rules, reading the same files again on its own.
    fn clone(&self) -> Self {
        AccessControl {
            state: Mutex::new(self.lock().clone()),
        }
    }
}

impl PartialEq for AccessControl {
    /// The same rules in force now (where they were read from aside).
    fn eq(&self, other: &Self) -> bool {
        self.rules() == other.rules()
    }
}

impl AccessControl {
    /// No rules: everything is allowed.
    pub fn open() -> Self {
        Self::default()
    }

    /// From parsed allow and deny rules (never read again).
    pub fn new(allow: Rules, deny: Rules) -> Self {
        AccessControl {
            state: Mutex::new(State {
                current: Arc::new(Current {
                    allow,
                    deny,
                    missing: (None, None),
                }),
                watched: Vec::new(),
            }),
        }
    }

    /// Reads the two files ([`Rules::load`]); both must exist and be
    /// readable. They are read again when they change.
    pub fn load(allow: &Path, deny: &Path) -> Result<Self, LoadError> {
        Self::load_files(RulesFile::Given(allow), RulesFile::Given(deny))
    }

    /// Reads the two files, each given or a default
    /// ([`RulesFile`]): a given file must exist, a default one that does not
    /// exist holds no rules (see [`AccessControl::missing_files_warning`]).
    /// The allow file is read first. Both are read again when they change
    /// (see the [module documentation](self)).
    pub fn load_files(allow: RulesFile<'_>, deny: RulesFile<'_>) -> Result<Self, LoadError> {
        let a = allow.load()?;
        let d = deny.load()?;
        let watched =
            |f: RulesFile<'_>, deny: bool, read: &Option<(Rules, Stamp, String)>| Watched {
                path: f.as_path().to_path_buf(),
                name: f.as_path().display().to_string(),
                deny,
                read: read.as_ref().map(|(_, s, t)| (*s, t.clone())),
                warned: None,
            };
        let watched = vec![watched(allow, false, &a), watched(deny, true, &d)];
        let current = Current {
            missing: (
                a.is_none().then(|| allow.as_path().display().to_string()),
                d.is_none().then(|| deny.as_path().display().to_string()),
            ),
            allow: a.map(|(r, _, _)| r).unwrap_or_default(),
            deny: d.map(|(r, _, _)| r).unwrap_or_default(),
        };
        Ok(AccessControl {
            state: Mutex::new(State {
                current: Arc::new(current),
                watched,
            }),
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The rules in force, after reading again the files that changed.
    fn rules(&self) -> Arc<Current> {
        let mut s = self.lock();
        if s.watched.is_empty() {
            return s.current.clone();
        }
        let now = SystemTime::now();
        let mut next: Option<Current> = None;
        for i in 0..s.watched.len() {
            let Some(rules) = s.watched[i].check(now) else {
                continue;
            };
            let deny = s.watched[i].deny;
            let c = next.get_or_insert_with(|| (*s.current).clone());
            if deny {
                c.deny = rules;
                c.missing.1 = None;
            } else {
                c.allow = rules;
                c.missing.0 = None;
            }
        }
        if let Some(c) = next {
            s.current = Arc::new(c);
        }
        s.current.clone()
    }

    /// Reads again, now, the files that changed since they were last read
    /// (every check does this by itself).
    pub fn reload_changed(&self) {
        self.rules();
    }

    /// Reads `/etc/hosts.allow` and `/etc/hosts.deny`, either of which may
    /// be missing.
    pub fn load_default() -> Result<Self, LoadError> {
        Self::load_files(
            RulesFile::Default(Path::new(DEFAULT_ALLOW)),
            RulesFile::Default(Path::new(DEFAULT_DENY)),
        )
    }

    /// One line saying which rules are not in force because a default file
    /// ([`RulesFile::Default`]) does not exist; `None` if both were read.
    pub fn missing_files_warning(&self) -> Option<String> {
        let c = self.rules();
        match &c.missing {
            (None, None) => None,
            (Some(a), Some(d)) => Some(format!(
                "no access rules in force: neither {a} nor {d} exists; every host may connect"
            )),
            (None, Some(d)) => Some(format!(
                "no deny rules in force: {d} does not exist; every host may connect"
            )),
            (Some(a), None) => Some(format!(
                "no allow rules in force: {a} does not exist; only {} decides",
                c.deny.file
            )),
        }
    }

    /// Decides for a client, looking its host name up (blocking, with the
    /// system resolver) only if a rule it reaches needs one.
    pub fn check(&self, client: Client) -> Decision {
        self.check_with(client, &mut reverse_lookup)
    }

    /// Decides for a client with `lookup` as the reverse resolver (called at
    /// most once, and only if a rule needs the host name). A rules file
    /// that changed is read again first.
    pub fn check_with(
        &self,
        client: Client,
        lookup: &mut dyn FnMut(IpAddr) -> HostName,
    ) -> Decision {
        // The lookup runs without the lock held: a slow one does not hold
        // other checks up.
        let c = self.rules();
        let mut name = Lazy { lookup, got: None };
        if let Some(r) = c.allow.matching(client, &mut name) {
            return Decision::Allowed(Some(r));
        }
        if let Some(r) = c.deny.matching(client, &mut name) {
            return Decision::Denied(r);
        }
        Decision::Allowed(None)
    }

    /// True if some rule for central needs the peer's host name (so a check
    /// may do DNS lookups and should not run on the accept path). A rules
    /// file that changed is read again first.
    pub fn needs_host_name(&self) -> bool {
        let c = self.rules();
        c.allow.needs_host_name() || c.deny.needs_host_name()
    }

    /// Warnings from both files as last read (skipped rules, names that
    /// did not resolve).
    pub fn warnings(&self) -> Vec<String> {
        let c = self.rules();
        c.allow
            .warnings
            .iter()
            .chain(c.deny.warnings.iter())
            .cloned()
            .collect()
    }
}

/// The peer's host name, looked up on first use.
struct Lazy<'a> {
    lookup: &'a mut dyn FnMut(IpAddr) -> HostName,
    got: Option<HostName>,
}

impl Lazy<'_> {
    fn get(&mut self, ip: IpAddr) -> &HostName {
        if self.got.is_none() {
            self.got = Some(if is_loopback(ip) {
                HostName::Verified("localhost".into())
            } else {
                (self.lookup)(ip)
            });
        }
        self.got.as_ref().unwrap_or(&HostName::Unknown)
    }
}

/// Reverse lookup with the system resolver (`getnameinfo`), verified by a
/// forward lookup of the name, as tcpd does. Blocking.
pub fn reverse_lookup(ip: IpAddr) -> HostName {
    let Some(name) = crate::sys::dns::getnameinfo(ip) else {
        return HostName::Unknown;
    };
    let name = name.trim_end_matches('.').to_ascii_lowercase();
    let back: Vec<IpAddr> = (name.as_str(), 0)
        .to_socket_addrs()
        .map(|a| a.map(|s| unmap(s.ip())).collect())
        .unwrap_or_default();
    if back.contains(&unmap(ip)) {
        HostName::Verified(name)
    } else {
        HostName::Unverified(name)
    }
}

/// Splits a list at commas and blanks.
fn words(s: &str) -> Vec<&str> {
    s.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|w| !w.is_empty())
        .collect()
}

/// The client list after the daemon list's colon: words up to the colon
/// that starts the options field. A word that is an IPv6 address (or
/// network) keeps its colons; any other colon ends the list.
fn client_words(rest: &str) -> Result<Vec<&str>, String> {
    let mut out = Vec::new();
    for w in words(rest) {
        if !w.contains(':') || is_ipv6_word(w) {
            out.push(w);
            continue;
        }
        // `a:b` or `a:` or `:b`: the list ends at the colon.
        let (head, _) = w.split_once(':').unwrap_or((w, ""));
        if !head.is_empty() {
            out.push(head);
        }
        return Ok(out);
    }
    Ok(out)
}

fn is_ipv6_word(w: &str) -> bool {
    let (addr, len) = match w.split_once('/') {
        Some((a, l)) => (a, Some(l)),
        None => (w, None),
    };
    let addr = addr
        .strip_prefix('[')
        .and_then(|a| a.strip_suffix(']'))
        .unwrap_or(addr);
    addr.parse::<Ipv6Addr>().is_ok() && len.is_none_or(|l| l.parse::<u32>().is_ok())
}

fn parse_list(words: &[&str], daemons: bool) -> Result<List, String> {
    let pos = words.iter().position(|w| *w == "EXCEPT");
    let (inc, exc) = match pos {
        Some(p) => (&words[..p], Some(&words[p + 1..])),
        None => (words, None),
    };
    if inc.is_empty() {
        return Err(format!("nothing before EXCEPT in '{}'", words.join(" ")));
    }
    let include = inc
        .iter()
        .map(|w| parse_pattern(w, daemons))
        .collect::<Result<Vec<_>, _>>()?;
    let except = match exc {
        Some([]) => return Err(format!("nothing after EXCEPT in '{}'", words.join(" "))),
        Some(rest) => Some(Box::new(parse_list(rest, daemons)?)),
        None => None,
    };
    Ok(List { include, except })
}

fn parse_pattern(w: &str, daemon: bool) -> Result<Pattern, String> {
    if w == "ALL" {
        return Ok(Pattern::All);
    }
    if daemon {
        // `daemon@host` forms name a server address; central has one.
        let name = w.split('@').next().unwrap_or(w);
        return Ok(Pattern::Daemon(name.to_string()));
    }
    match w {
        "LOCAL" => return Ok(Pattern::Local),
        "KNOWN" => return Ok(Pattern::Known),
        "UNKNOWN" => return Ok(Pattern::Unknown),
        "PARANOID" => return Ok(Pattern::Paranoid),
        _ => {}
    }
    if w.eq_ignore_ascii_case("localhost") {
        return Ok(Pattern::Localhost);
    }
    if w.starts_with('@') {
        return Err(format!("NIS netgroup '{w}' is not supported"));
    }
    if w.starts_with('/') {
        return Err(format!("pattern files ('{w}') are not supported"));
    }
    let unbracket = |a: &str| -> String { a.trim_start_matches('[').trim_end_matches(']').into() };
    if let Some((a, m)) = w.split_once('/') {
        let ip: IpAddr = unbracket(a)
            .parse()
            .map_err(|_| format!("bad network address in '{w}'"))?;
        let max = if ip.is_ipv4() { 32 } else { 128 };
        let bits = match (m.parse::<u32>(), m.parse::<Ipv4Addr>()) {
            (Ok(b), _) => b,
            (_, Ok(mask)) if ip.is_ipv4() => {
                let v = u32::from(mask);
                if v.leading_ones() + v.trailing_zeros() != 32 {
                    return Err(format!("netmask {mask} in '{w}' is not contiguous"));
                }
                v.leading_ones()
            }
            _ => return Err(format!("bad netmask or prefix length in '{w}'")),
        };
        if bits > max {
            return Err(format!("prefix length {bits} too long in '{w}'"));
        }
        return Ok(Pattern::Net(unmap(ip), bits));
    }
    if let Ok(ip) = unbracket(w).parse::<IpAddr>() {
        if w.starts_with('[') != w.ends_with(']') {
            return Err(format!("unbalanced brackets in '{w}'"));
        }
        return Ok(Pattern::Addr(unmap(ip)));
    }
    let lower = w.to_ascii_lowercase();
    let hostish = |s: &str| {
        !s.is_empty()
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_' | '*' | '?'))
    };
    if !hostish(&lower) {
        return Err(format!("unrecognised pattern '{w}'"));
    }
    if lower.contains(['*', '?']) {
        return Ok(Pattern::Wildcard(lower));
    }
    if lower.ends_with('.') {
        if lower.chars().all(|c| c.is_ascii_digit() || c == '.') && !lower.starts_with('.') {
            return Ok(Pattern::Prefix(lower));
        }
        return Err(format!(
            "'{w}': a trailing dot is only for address prefixes like 10.0.0."
        ));
    }
    if lower.starts_with('.') {
        if lower.len() == 1 {
            return Err("'.' alone is not a domain".into());
        }
        return Ok(Pattern::Suffix(lower));
    }
    if lower.chars().all(|c| c.is_ascii_digit() || c == '.') {
        return Err(format!("'{w}' is not an IPv4 address"));
    }
    Ok(Pattern::Name {
        name: lower,
        addrs: Vec::new(),
    })
}

fn daemon_matches(p: &Pattern) -> bool {
    match p {
        Pattern::All => true,
        Pattern::Daemon(d) => d == DAEMON,
        _ => false,
    }
}

/// IPv4-mapped IPv6 addresses as IPv4.
fn unmap(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    }
}

fn is_loopback(ip: IpAddr) -> bool {
    unmap(ip).is_loopback()
}

fn client_matches(p: &Pattern, client: Client, name: &mut Lazy<'_>) -> bool {
    match client {
        Client::Ip(ip) => ip_matches(p, unmap(ip), name),
        // A local client: as if from either loopback address.
        Client::Unix => [
            IpAddr::V4(Ipv4Addr::LOCALHOST),
            IpAddr::V6(Ipv6Addr::LOCALHOST),
        ]
        .into_iter()
        .any(|ip| ip_matches(p, ip, name)),
    }
}

fn ip_matches(p: &Pattern, ip: IpAddr, name: &mut Lazy<'_>) -> bool {
    match p {
        Pattern::All => true,
        Pattern::Localhost => is_loopback(ip),
        Pattern::Local => {
            is_loopback(ip) || matches!(name.get(ip), HostName::Verified(n) if !n.contains('.'))
        }
        Pattern::Known => matches!(name.get(ip), HostName::Verified(_)),
        Pattern::Unknown => !matches!(name.get(ip), HostName::Verified(_)),
        Pattern::Paranoid => matches!(name.get(ip), HostName::Unverified(_)),
        Pattern::Addr(a) => *a == ip,
        Pattern::Prefix(pre) => ip.is_ipv4() && ip.to_string().starts_with(pre.as_str()),
        Pattern::Net(net, bits) => in_net(ip, *net, *bits),
        Pattern::Suffix(s) => {
            matches!(name.get(ip), HostName::Verified(n) if n.ends_with(s.as_str()))
        }
        Pattern::Name { addrs, .. } => addrs.contains(&ip),
        Pattern::Wildcard(w) => {
            glob(w, &ip.to_string())
                || (w.chars().any(|c| c.is_ascii_alphabetic())
                    && matches!(name.get(ip), HostName::Verified(n) if glob(w, n)))
        }
        Pattern::Daemon(_) => false,
    }
}

fn in_net(ip: IpAddr, net: IpAddr, bits: u32) -> bool {
    match (ip, net) {
        (IpAddr::V4(a), IpAddr::V4(n)) => {
            let mask = u32::MAX.checked_shl(32 - bits).unwrap_or(0);
            u32::from(a) & mask == u32::from(n) & mask
        }
        (IpAddr::V6(a), IpAddr::V6(n)) => {
            let mask = u128::MAX.checked_shl(128 - bits).unwrap_or(0);
            u128::from(a) & mask == u128::from(n) & mask
        }
        _ => false,
    }
}

/// `*` and `?` matching over ASCII text.
fn glob(pat: &str, text: &str) -> bool {
    let (p, t) = (pat.as_bytes(), text.as_bytes());
    let (mut i, mut j) = (0, 0);
    let (mut star, mut mark) = (None, 0);
    while j < t.len() {
        if i < p.len() && (p[i] == b'?' || p[i] == t[j]) {
            i += 1;
            j += 1;
        } else if i < p.len() && p[i] == b'*' {
            star = Some(i);
            mark = j;
            i += 1;
        } else if let Some(s) = star {
            i = s + 1;
            mark += 1;
            j = mark;
        } else {
            return false;
        }
    }
    p[i..].iter().all(|c| *c == b'*')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ac(allow: &str, deny: &str) -> AccessControl {
        AccessControl::new(
            Rules::parse(allow, "hosts.allow").unwrap(),
            Rules::parse(deny, "hosts.deny").unwrap(),
        )
    }

    fn ip(s: &str) -> Client {
        Client::Ip(s.parse().unwrap())
    }

    /// A fake DNS: names for some addresses of the documentation ranges.
    fn fake_dns(ip: IpAddr) -> HostName {
        match ip.to_string().as_str() {
            "192.0.2.10" => HostName::Verified("robot1.cs.cmu.edu".into()),
            "192.0.2.11" => HostName::Verified("robot2".into()),
            "192.0.2.12" => HostName::Unverified("forged.cs.cmu.edu".into()),
            "2001:db8::10" => HostName::Verified("ws.lab.example.org".into()),
            _ => HostName::Unknown,
        }
    }

    fn decide(a: &AccessControl, c: Client) -> bool {
        a.check_with(c, &mut fake_dns).is_allowed()
    }

    #[test]
    fn manual_example() {
        let a = ac(
            "central : localhost, 10.0.0.5\nsshd : .cs.cmu.edu\nsshd-x11 : .cs.cmu.edu\n",
            "ALL : ALL\n",
        );
        let cases = [
            (ip("127.0.0.1"), true),
            (ip("127.1.2.3"), true),
            (ip("::1"), true),
            (ip("::ffff:127.0.0.1"), true),
            (ip("10.0.0.5"), true),
            (ip("::ffff:10.0.0.5"), true),
            (ip("10.0.0.6"), false),
            (ip("192.0.2.10"), false),
            (Client::Unix, true),
        ];
        for (peer, allowed) in cases {
            assert_eq!(decide(&a, peer), allowed, "{peer:?}");
        }
        assert_eq!(
            a.check(ip("10.0.0.6")),
            Decision::Denied(RuleRef {
                file: "hosts.deny".into(),
                line: 1
            })
        );
        assert_eq!(
            a.check(ip("10.0.0.5")).to_string(),
            "allowed by hosts.allow:1"
        );
        assert!(
            !a.needs_host_name(),
            "sshd's domain rules do not concern central"
        );
    }

    #[test]
    fn client_patterns() {
        // (allow-file client list, peer, allowed?) with "ALL : ALL" denied.
        let cases: &[(&str, &str, bool)] = &[
            ("ALL", "192.0.2.1", true),
            ("10.1.", "10.1.9.9", true),
            ("10.1.", "10.10.0.1", false),
            ("10.1. EXCEPT 10.1.2.3", "10.1.2.3", false),
            ("10.1. EXCEPT 10.1.2.3", "10.1.2.4", true),
            ("192.168.0.0/255.255.0.0", "192.168.44.1", true),
            ("192.168.0.0/255.255.0.0", "192.169.0.1", false),
            ("172.16.0.0/12", "172.31.0.1", true),
            ("172.16.0.0/12", "172.32.0.1", false),
            ("0.0.0.0/0", "203.0.113.1", true),
            ("10.0.0.1/32", "10.0.0.1", true),
            ("10.0.0.1/32", "10.0.0.2", false),
            ("[fe80::]/10", "fe80::1", true),
            ("[fe80::]/10", "2001:db8::1", false),
            ("fe80::/10", "fe80::2", true),
            ("[::1]", "::1", true),
            ("::1", "::1", true),
            ("2001:db8::10", "2001:db8::10", true),
            ("2001:db8::10", "2001:db8::11", false),
            ("10.0.0.5", "::ffff:10.0.0.5", true),
            ("localhost", "127.0.0.53", true),
            ("localhost", "::1", true),
            ("localhost", "10.0.0.1", false),
            ("LOCAL", "127.0.0.1", true),
            ("LOCAL", "192.0.2.11", true),
            ("LOCAL", "192.0.2.10", false),
            (".cs.cmu.edu", "192.0.2.10", true),
            (".CS.CMU.EDU", "192.0.2.10", true),
            (".cs.cmu.edu", "192.0.2.12", false),
            (".cmu.edu", "192.0.2.11", false),
            (".example.org", "2001:db8::10", true),
            ("KNOWN", "192.0.2.10", true),
            ("KNOWN", "192.0.2.12", false),
            ("UNKNOWN", "192.0.2.99", true),
            ("UNKNOWN", "192.0.2.12", true),
            ("PARANOID", "192.0.2.12", true),
            ("PARANOID", "192.0.2.10", false),
            ("192.0.2.1?", "192.0.2.10", true),
            ("192.0.*.10", "192.0.2.10", true),
            ("192.0.*.10", "192.0.2.11", false),
            ("robot*.cs.cmu.edu", "192.0.2.10", true),
            ("robot*.cs.cmu.edu", "192.0.2.11", false),
            (
                "ALL EXCEPT 192.0.2.0/24 EXCEPT 192.0.2.7",
                "192.0.2.7",
                true,
            ),
            (
                "ALL EXCEPT 192.0.2.0/24 EXCEPT 192.0.2.7",
                "192.0.2.8",
                false,
            ),
            (
                "ALL EXCEPT 192.0.2.0/24 EXCEPT 192.0.2.7",
                "198.51.100.1",
                true,
            ),
            ("10.0.0.1,10.0.0.2 10.0.0.3", "10.0.0.3", true),
        ];
        for (list, peer, allowed) in cases {
            let a = ac(&format!("central : {list}\n"), "ALL : ALL\n");
            assert_eq!(decide(&a, ip(peer)), *allowed, "'{list}' for {peer}");
        }
    }

    #[test]
    fn unix_socket_peers_are_local() {
        let cases: &[(&str, bool)] = &[
            ("ALL", true),
            ("localhost", true),
            ("LOCAL", true),
            ("127.0.0.1", true),
            ("127.", true),
            ("[::1]", true),
            ("KNOWN", true),
            ("10.0.0.1", false),
            (".cs.cmu.edu", false),
        ];
        for (list, denied) in cases {
            let a = ac("", &format!("central : {list}\n"));
            let d = a.check_with(Client::Unix, &mut |_| panic!("no lookup for local peers"));
            assert_eq!(!d.is_allowed(), *denied, "'{list}'");
        }
    }

    #[test]
    fn daemon_lists() {
        let cases: &[(&str, bool)] = &[
            ("central", true),
            ("ALL", true),
            ("sshd", false),
            ("sshd, central", true),
            ("sshd central", true),
            ("ALL EXCEPT central", false),
            ("ALL EXCEPT sshd", true),
            ("central@192.0.2.1", true),
            ("Central", false),
        ];
        for (daemons, denied) in cases {
            let a = ac("", &format!("{daemons} : ALL\n"));
            assert_eq!(
                !a.check(ip("192.0.2.1")).is_allowed(),
                *denied,
                "'{daemons}'"
            );
        }
    }

    #[test]
    fn allow_before_deny_and_default_allow() {
        let a = ac("central : 10.0.0.1\n", "central : 10.0.0.0/8\n");
        assert!(a.check(ip("10.0.0.1")).is_allowed());
        assert!(!a.check(ip("10.0.0.2")).is_allowed());
        assert_eq!(a.check(ip("192.0.2.1")), Decision::Allowed(None));
        assert!(AccessControl::open().check(ip("192.0.2.1")).is_allowed());
        // The first matching line of a file is the one reported.
        let a = ac("", "sshd : ALL\ncentral : 10.\ncentral : ALL\n");
        assert_eq!(
            a.check(ip("10.1.1.1")).to_string(),
            "denied by hosts.deny:2"
        );
        assert_eq!(
            a.check(ip("11.1.1.1")).to_string(),
            "denied by hosts.deny:3"
        );
    }

    #[test]
    fn comments_continuations_and_options() {
        let a = ac(
            "# comment\n\n  # indented comment\ncentral : \\\n  127.0.0.1, \\\n 10.0.0.1 : ALLOW\ncentral: 10.0.0.2:spawn (echo hi)\n",
            "central: ALL # everything else\n",
        );
        assert_eq!(
            a.check(ip("127.0.0.1")).to_string(),
            "allowed by hosts.allow:4"
        );
        assert_eq!(
            a.check(ip("10.0.0.1")).to_string(),
            "allowed by hosts.allow:4"
        );
        assert_eq!(
            a.check(ip("10.0.0.2")).to_string(),
            "allowed by hosts.allow:7"
        );
        assert!(!a.check(ip("127.0.0.2")).is_allowed());
        let a = ac("", "central : [::1] : deny\n");
        assert!(!a.check(ip("::1")).is_allowed());
    }

    #[test]
    fn host_names_resolve_at_load_time() {
        let mut r = Rules::parse(
            "central : robot1.lab, ghost.lab\nsshd : nowhere.lab\n",
            "hosts.allow",
        )
        .unwrap();
        r.resolve_names(&mut |n| match n {
            "robot1.lab" => vec![
                "192.0.2.21".parse().unwrap(),
                "::ffff:192.0.2.22".parse().unwrap(),
            ],
            _ => vec![],
        });
        let a = AccessControl::new(r, Rules::parse("ALL : ALL", "hosts.deny").unwrap());
        assert!(a.check(ip("192.0.2.21")).is_allowed());
        assert!(a.check(ip("192.0.2.22")).is_allowed());
        assert!(!a.check(ip("192.0.2.23")).is_allowed());
        let w = a.warnings();
        assert_eq!(
            w,
            ["hosts.allow:1: host name 'ghost.lab' does not resolve; the rule never matches it"]
        );
        assert!(!a.needs_host_name(), "names are matched by address");
    }

    #[test]
    fn host_name_lookups_only_when_needed() {
        let a = ac("central : 10.0.0.1, .cs.cmu.edu\n", "ALL : ALL\n");
        assert!(a.needs_host_name());
        let mut calls = 0;
        let d = a.check_with(ip("10.0.0.1"), &mut |_| {
            calls += 1;
            HostName::Unknown
        });
        assert!(d.is_allowed());
        assert_eq!(calls, 0, "the address matched first");
        let d = a.check_with(ip("10.0.0.2"), &mut |_| {
            calls += 1;
            HostName::Unknown
        });
        assert!(!d.is_allowed());
        assert_eq!(calls, 1, "looked up once for both files");
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            (
                "central\n",
                "hosts.x:1: expected 'daemon_list : client_list'",
            ),
            ("sshd : ALL\n : ALL\n", "hosts.x:2: empty daemon list"),
            ("central : \n", "hosts.x:1: empty client list"),
            ("central : : spawn\n", "hosts.x:1: empty client list"),
            (
                "central : EXCEPT 1.2.3.4\n",
                "hosts.x:1: nothing before EXCEPT",
            ),
            ("central : ALL EXCEPT\n", "hosts.x:1: nothing after EXCEPT"),
            ("EXCEPT central : ALL\n", "hosts.x:1: nothing before EXCEPT"),
            (
                "central : 1.2.3.4/33\n",
                "hosts.x:1: prefix length 33 too long",
            ),
            (
                "central : [::]/129\n",
                "hosts.x:1: prefix length 129 too long",
            ),
            (
                "central : 1.2.3.4/255.0.255.0\n",
                "hosts.x:1: netmask 255.0.255.0",
            ),
            ("central : 1.2.3.4/abc\n", "hosts.x:1: bad netmask"),
            ("central : 1.2.3.400/8\n", "hosts.x:1: bad network address"),
            (
                "central : 1.2.3.400\n",
                "hosts.x:1: '1.2.3.400' is not an IPv4 address",
            ),
            ("central : [::1\n", "hosts.x:1: unrecognised pattern"),
            ("central : a$b\n", "hosts.x:1: unrecognised pattern 'a$b'"),
            ("central : @robots\n", "hosts.x:1: NIS netgroup '@robots'"),
            ("central : /etc/robots\n", "hosts.x:1: pattern files"),
            ("central : foo.\n", "hosts.x:1: 'foo.': a trailing dot"),
            (
                "# a\n\ncentral : \\\n  ALL EXCEPT\n",
                "hosts.x:3: nothing after EXCEPT",
            ),
            ("ALL : 10.0.0.%\n", "hosts.x:1: unrecognised pattern"),
        ];
        for (text, want) in cases {
            let e = Rules::parse(text, "hosts.x").unwrap_err().to_string();
            assert!(e.starts_with(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn other_daemons_bad_rules_are_skipped_with_a_warning() {
        let r = Rules::parse("sshd : @trusted\ncentral : 10.0.0.1\n", "hosts.allow").unwrap();
        assert_eq!(r.len(), 1);
        assert_eq!(
            r.warnings(),
            ["hosts.allow:1: rule skipped (it does not concern central): NIS netgroup '@trusted' is not supported"]
        );
    }

    #[test]
    fn a_given_file_must_exist_and_be_readable() {
        let e = Rules::load(Path::new("/nonexistent/hosts.allow"))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "cannot read /nonexistent/hosts.allow: No such file or directory (os error 2)"
        );
        let e = AccessControl::load(Path::new("/nonexistent/a"), Path::new("/nonexistent/d"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("cannot read /nonexistent/a: "), "{e}");
        // A directory cannot be read as a file (root reads any file, so a
        // mode-000 file would not do for this test).
        let dir = std::env::temp_dir();
        let e = AccessControl::load_files(
            RulesFile::Default(Path::new("/nonexistent/a")),
            RulesFile::Default(&dir),
        )
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            format!(
                "cannot read {}: Is a directory (os error 21)",
                dir.display()
            )
        );
        assert_eq!(
            Rules::load_if_exists(Path::new("/nonexistent/x")).unwrap(),
            None
        );
    }

    #[test]
    fn missing_default_files_hold_no_rules_and_say_so() {
        let dir = std::env::temp_dir().join(format!("courier-access-d-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let deny = dir.join("hosts.deny");
        std::fs::write(&deny, "central : 10.\n").unwrap();
        let (na, nd) = (Path::new("/nonexistent/a"), Path::new("/nonexistent/d"));
        let both =
            AccessControl::load_files(RulesFile::Default(na), RulesFile::Default(nd)).unwrap();
        assert!(both.check(ip("10.0.0.1")).is_allowed());
        assert_eq!(
            both.missing_files_warning().unwrap(),
            "no access rules in force: neither /nonexistent/a nor /nonexistent/d exists; every host may connect"
        );
        let no_deny =
            AccessControl::load_files(RulesFile::Given(&deny), RulesFile::Default(nd)).unwrap();
        assert_eq!(
            no_deny.missing_files_warning().unwrap(),
            "no deny rules in force: /nonexistent/d does not exist; every host may connect"
        );
        let no_allow =
            AccessControl::load_files(RulesFile::Default(na), RulesFile::Given(&deny)).unwrap();
        assert!(!no_allow.check(ip("10.0.0.1")).is_allowed());
        assert_eq!(
            no_allow.missing_files_warning().unwrap(),
            format!(
                "no allow rules in force: /nonexistent/a does not exist; only {} decides",
                deny.display()
            )
        );
        let all = AccessControl::load_files(RulesFile::Default(&deny), RulesFile::Default(&deny))
            .unwrap();
        assert_eq!(all.missing_files_warning(), None);
        // A given file never falls back to "no rules".
        assert!(AccessControl::load_files(RulesFile::Given(na), RulesFile::Default(nd)).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn load_reads_files_and_reports_errors() {
        let dir = std::env::temp_dir().join(format!("courier-access-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let allow = dir.join("hosts.allow");
        let deny = dir.join("hosts.deny");
        std::fs::write(&allow, "central : localhost\n").unwrap();
        std::fs::write(&deny, "ALL : ALL\n").unwrap();
        let a = AccessControl::load(&allow, &deny).unwrap();
        assert!(a.check(ip("127.0.0.1")).is_allowed());
        assert!(!a.check(ip("192.0.2.1")).is_allowed());
        std::fs::write(&deny, "ALL : ALL\ncentral : 1.2.3.4/99\n").unwrap();
        let e = AccessControl::load(&allow, &deny).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "{}:2: prefix length 99 too long in '1.2.3.4/99'",
                deny.display()
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The log lines of this thread while the guard lives.
    fn capture_logs() -> (Arc<Mutex<Vec<u8>>>, tracing::subscriber::DefaultGuard) {
        struct Sink(Arc<Mutex<Vec<u8>>>);
        impl std::io::Write for Sink {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let buf = Arc::new(Mutex::new(Vec::new()));
        let sink = buf.clone();
        let sub = tracing_subscriber::fmt()
            .with_ansi(false)
            .with_max_level(tracing::Level::INFO)
            .with_writer(move || Sink(sink.clone()))
            .finish();
        (buf, tracing::subscriber::set_default(sub))
    }

    fn log_lines(buf: &Arc<Mutex<Vec<u8>>>, with: &str) -> Vec<String> {
        String::from_utf8_lossy(&buf.lock().unwrap())
            .lines()
            .filter(|l| l.contains(with))
            .map(str::to_string)
            .collect()
    }

    /// A directory of its own for one test.
    fn scratch(test: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("courier-access-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn changed_files_are_read_again_at_the_next_check() {
        let dir = scratch("reload");
        let (allow, deny) = (dir.join("hosts.allow"), dir.join("hosts.deny"));
        std::fs::write(&allow, "# none\n").unwrap();
        std::fs::write(&deny, "# none\n").unwrap();
        let (logs, _guard) = capture_logs();
        let a = AccessControl::load(&allow, &deny).unwrap();
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        std::fs::write(&deny, "central : 192.0.2.1\n").unwrap();
        assert_eq!(
            a.check(ip("192.0.2.1")).to_string(),
            format!("denied by {}:1", deny.display())
        );
        // The same size at once (possibly the same modification time): the
        // text is compared while the file is that recent.
        std::fs::write(&deny, "central : 192.0.2.2\n").unwrap();
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        assert!(!a.check(ip("192.0.2.2")).is_allowed());
        // The allow file comes first, as at start.
        std::fs::write(&allow, "central : 192.0.2.2\n").unwrap();
        assert_eq!(
            a.check(ip("192.0.2.2")).to_string(),
            format!("allowed by {}:1", allow.display())
        );
        // A file replaced by a rename is read too.
        let new = dir.join("hosts.deny.new");
        std::fs::write(&new, "central : ALL EXCEPT 192.0.2.2\n").unwrap();
        std::fs::rename(&new, &deny).unwrap();
        assert!(!a.check(ip("192.0.2.3")).is_allowed());
        assert!(!a.needs_host_name());
        // The name rule of a new text is resolved when it is read, and
        // `needs_host_name` sees the new rules.
        std::fs::write(&deny, "central : .example.org\n").unwrap();
        assert!(a.needs_host_name());
        // Written back as it was: not parsed again.
        let before = log_lines(&logs, "again").len();
        std::fs::write(&deny, "central : .example.org\n").unwrap();
        assert!(a.needs_host_name());
        assert_eq!(log_lines(&logs, "again").len(), before);
        let read = log_lines(&logs, &format!("read {} again", deny.display()));
        assert_eq!(read.len(), 4, "{read:#?}");
        assert!(read[0].contains("INFO"), "{read:#?}");
        assert!(log_lines(&logs, "WARN").is_empty());
        // Rules built from text are not files.
        assert!(!ac("", "").needs_host_name());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_that_breaks_keeps_its_rules_and_warns_once() {
        let dir = scratch("broken");
        let (allow, deny) = (dir.join("hosts.allow"), dir.join("hosts.deny"));
        std::fs::write(&allow, "").unwrap();
        std::fs::write(&deny, "central : ALL\n").unwrap();
        let (logs, _guard) = capture_logs();
        let a = AccessControl::load(&allow, &deny).unwrap();
        let denied = |a: &AccessControl| !a.check(ip("192.0.2.1")).is_allowed();
        assert!(denied(&a));
        // Malformed: the old rules stay, and it is said once.
        std::fs::write(&deny, "central : 1.2.3.4/99\n").unwrap();
        assert!(denied(&a) && denied(&a) && denied(&a));
        let warned = log_lines(&logs, "WARN");
        assert_eq!(warned.len(), 1, "{warned:#?}");
        assert!(
            warned[0].ends_with(&format!(
                "access rules: {0}:1: prefix length 99 too long in '1.2.3.4/99'; \
                 the rules last read from {0} stay in force",
                deny.display()
            )),
            "{warned:#?}"
        );
        // Gone: the same.
        std::fs::remove_file(&deny).unwrap();
        assert!(denied(&a) && denied(&a));
        let warned = log_lines(&logs, "WARN");
        assert_eq!(warned.len(), 2, "{warned:#?}");
        assert!(
            warned[1].contains(&format!("{} no longer exists;", deny.display())),
            "{warned:#?}"
        );
        // Unreadable (a directory in its place: root reads any file): the
        // same.
        std::fs::create_dir(&deny).unwrap();
        assert!(denied(&a) && denied(&a));
        let warned = log_lines(&logs, "WARN");
        assert_eq!(warned.len(), 3, "{warned:#?}");
        assert!(
            warned[2].contains(&format!("cannot read {}: ", deny.display())),
            "{warned:#?}"
        );
        // A valid file again: in force.
        std::fs::remove_dir(&deny).unwrap();
        std::fs::write(&deny, "central : 10.0.0.1\n").unwrap();
        assert!(!denied(&a));
        assert!(!a.check(ip("10.0.0.1")).is_allowed());
        assert_eq!(log_lines(&logs, "WARN").len(), 3);
        // The allow file breaking does not open anything either.
        std::fs::write(&allow, "central : ALL EXCEPT\n").unwrap();
        assert!(!a.check(ip("10.0.0.1")).is_allowed());
        assert_eq!(log_lines(&logs, "WARN").len(), 4);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_default_file_that_appears_is_read() {
        let dir = scratch("appears");
        let (allow, deny) = (dir.join("hosts.allow"), dir.join("hosts.deny"));
        let a = AccessControl::load_files(RulesFile::Default(&allow), RulesFile::Default(&deny))
            .unwrap();
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        assert!(a
            .missing_files_warning()
            .unwrap()
            .starts_with("no access rules in force"));
        std::fs::write(&deny, "ALL : ALL\n").unwrap();
        assert!(!a.check(ip("192.0.2.1")).is_allowed());
        assert_eq!(
            a.missing_files_warning().unwrap(),
            format!(
                "no allow rules in force: {} does not exist; only {} decides",
                allow.display(),
                deny.display()
            )
        );
        std::fs::write(&allow, "central : 192.0.2.1\n").unwrap();
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        assert_eq!(a.missing_files_warning(), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn glob_matching() {
        for (p, t, m) in [
            ("*", "", true),
            ("a*c", "abbbc", true),
            ("a*c", "abbb", false),
            ("a?c", "abc", true),
            ("a?c", "ac", false),
            ("*.org", "x.example.org", true),
            ("**x", "x", true),
        ] {
            assert_eq!(glob(p, t), m, "{p} {t}");
        }
    }

    #[test]
    fn reverse_lookup_of_loopback_is_not_needed() {
        // Loopback peers are `localhost` without asking DNS.
        let a = ac("", "central : KNOWN\n");
        let d = a.check_with(ip("127.0.0.1"), &mut |_| panic!("no lookup for loopback"));
        assert!(!d.is_allowed());
    }
}

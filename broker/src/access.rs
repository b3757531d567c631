//! Access control in the style of `hosts_access(5)` (the manual's "Access
//! Control" section): `/etc/hosts.allow` and `/etc/hosts.deny` hold lines
//! `daemon_list : client_list [: options]`; the daemon name is `central`.
//!
//! A connection is **allowed** if a rule in the allow file matches it,
//! else **denied** if a rule in the deny file matches it, else allowed.
//! Missing files hold no rules.
//!
//! Supported patterns (daemon and client lists alike): `ALL`, `LOCAL`
//! (clients: local connections, i.e. loopback addresses and UNIX sockets),
//! `EXCEPT` lists, literal IPv4/IPv6 addresses, `n.n.n.` address prefixes,
//! `n.n.n.n/m.m.m.m` and `addr/len` networks, and `localhost`. Host *names*
//! other than `localhost` (including `.domain` suffixes) would need a
//! reverse DNS lookup for every connection; they are accepted in the files
//! but never match, and [`AccessControl::warnings`] says so.
//!
//! ```
//! use courier_broker::access::{AccessControl, Rules};
//! let allow = Rules::parse("central : localhost, 10.0.0.5\n", "hosts.allow").unwrap();
//! let deny = Rules::parse("ALL : ALL\n", "hosts.deny").unwrap();
//! let ac = AccessControl::new(allow, deny);
//! assert!(ac.check(Some("127.0.0.1".parse().unwrap())).is_allowed());
//! assert!(ac.check(Some("10.0.0.5".parse().unwrap())).is_allowed());
//! assert!(!ac.check(Some("192.0.2.9".parse().unwrap())).is_allowed());
//! ```

use std::net::IpAddr;
use std::path::Path;

/// The daemon name rules must name (or `ALL`).
pub const DAEMON: &str = "central";

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

#[derive(Debug, Clone, PartialEq)]
enum Pattern {
    All,
    Local,
    Localhost,
    Addr(IpAddr),
    /// `10.0.0.` style prefix (text match on the dotted address).
    Prefix(String),
    Net(IpAddr, u32),
    Daemon(String),
    /// A host name: cannot match without DNS.
    Name(String),
}

#[derive(Debug, Clone, PartialEq)]
struct List {
    include: Vec<Pattern>,
    except: Option<Box<List>>,
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

/// The decision for one connection.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decision {
    /// Allowed by a rule (`file:line`), or by default (`None`).
    Allowed(Option<String>),
    /// Denied by the rule at `file:line`.
    Denied(String),
}

impl Decision {
    /// True for [`Decision::Allowed`].
    pub fn is_allowed(&self) -> bool {
        matches!(self, Decision::Allowed(_))
    }
}

/// Allow and deny rules together.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AccessControl {
    allow: Rules,
    deny: Rules,
}

impl AccessControl {
    /// No rules: everything is allowed.
    pub fn open() -> Self {
        Self::default()
    }

    /// From parsed allow and deny rules.
    pub fn new(allow: Rules, deny: Rules) -> Self {
        AccessControl { allow, deny }
    }

    /// Reads the two files; a missing file has no rules.
    pub fn load(allow: &Path, deny: &Path) -> Result<Self, LoadError> {
        Ok(AccessControl {
            allow: Rules::load(allow)?,
            deny: Rules::load(deny)?,
        })
    }

    /// Decides for a peer: `Some(ip)` for TCP, `None` for a UNIX socket.
    pub fn check(&self, peer: Option<IpAddr>) -> Decision {
        if let Some(line) = self.allow.matching(peer) {
            return Decision::Allowed(Some(format!("{}:{line}", self.allow.file)));
        }
        if let Some(line) = self.deny.matching(peer) {
            return Decision::Denied(format!("{}:{line}", self.deny.file));
        }
        Decision::Allowed(None)
    }

    /// Things in the files that can never match (host names).
    pub fn warnings(&self) -> impl Iterator<Item = &str> {
        self.allow
            .warnings
            .iter()
            .chain(self.deny.warnings.iter())
            .map(String::as_str)
    }
}

/// A hosts file could not be read or parsed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The file exists but could not be read.
    #[error("cannot read {file}: {source}")]
    Io {
        /// The file.
        file: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line is malformed.
    #[error(transparent)]
    Parse(#[from] ParseError),
}

impl Rules {
    /// Reads and parses a file; a missing file has no rules.
    pub fn load(path: &Path) -> Result<Rules, LoadError> {
        let name = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => Ok(Rules::parse(&text, &name)?),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Rules {
                file: name,
                ..Rules::default()
            }),
            Err(source) => Err(LoadError::Io { file: name, source }),
        }
    }

    /// Parses the text of a file called `file` (for messages).
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
            let line = raw.trim_end();
            if let Some(cont) = line.strip_suffix('\\') {
                logical.push_str(cont);
                logical.push(' ');
                continue;
            }
            logical.push_str(line);
            let l = std::mem::take(&mut logical);
            rules.parse_line(&l, start)?;
        }
        if !logical.is_empty() {
            rules.parse_line(&logical.clone(), start)?;
        }
        Ok(rules)
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
        let mut fields = split_fields(line).into_iter();
        let daemons = fields.next().unwrap_or("").trim();
        let Some(clients) = fields.next().map(str::trim) else {
            return Err(err(format!(
                "expected 'daemon_list : client_list', found '{line}'"
            )));
        };
        if daemons.is_empty() {
            return Err(err("empty daemon list".into()));
        }
        if clients.is_empty() {
            return Err(err("empty client list".into()));
        }
        let daemons = parse_list(daemons, true).map_err(&err)?;
        let clients = parse_list(clients, false).map_err(&err)?;
        for p in clients.patterns() {
            if let Pattern::Name(name) = p {
                self.warnings.push(format!(
                    "{}:{n}: host name '{name}' is never matched (central does no DNS lookups); use addresses",
                    self.file
                ));
            }
        }
        self.rules.push(Rule {
            daemons,
            clients,
            line: n,
        });
        Ok(())
    }

    /// The line of the first rule matching `central` and this peer.
    fn matching(&self, peer: Option<IpAddr>) -> Option<usize> {
        self.rules
            .iter()
            .find(|r| {
                r.daemons.matches(&|p| daemon_matches(p))
                    && r.clients.matches(&|p| client_matches(p, peer))
            })
            .map(|r| r.line)
    }
}

impl List {
    fn matches(&self, m: &dyn Fn(&Pattern) -> bool) -> bool {
        self.include.iter().any(m) && !self.except.as_ref().is_some_and(|e| e.matches(m))
    }

    fn patterns(&self) -> Vec<&Pattern> {
        let mut v: Vec<&Pattern> = self.include.iter().collect();
        if let Some(e) = &self.except {
            v.extend(e.patterns());
        }
        v
    }
}

/// Splits `daemons : clients : options` at colons outside `[...]` (IPv6).
fn split_fields(line: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut depth = 0;
    let mut start = 0;
    for (i, c) in line.char_indices() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            ':' if depth == 0 && out.len() < 2 => {
                out.push(&line[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&line[start..]);
    out
}

fn parse_list(s: &str, daemons: bool) -> Result<List, String> {
    let words: Vec<&str> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|w| !w.is_empty())
        .collect();
    let pos = words.iter().position(|w| *w == "EXCEPT");
    let (inc, exc) = match pos {
        Some(p) => (&words[..p], Some(&words[p + 1..])),
        None => (&words[..], None),
    };
    if inc.is_empty() {
        return Err(format!("nothing before EXCEPT in '{s}'"));
    }
    let include = inc
        .iter()
        .map(|w| parse_pattern(w, daemons))
        .collect::<Result<Vec<_>, _>>()?;
    let except = match exc {
        Some([]) => return Err(format!("nothing after EXCEPT in '{s}'")),
        Some(rest) => Some(Box::new(parse_list(&rest.join(" "), daemons)?)),
        None => None,
    };
    Ok(List { include, except })
}

fn parse_pattern(w: &str, daemon: bool) -> Result<Pattern, String> {
    if w == "ALL" {
        return Ok(Pattern::All);
    }
    if daemon {
        return Ok(Pattern::Daemon(w.to_string()));
    }
    if w == "LOCAL" {
        return Ok(Pattern::Local);
    }
    if w.eq_ignore_ascii_case("localhost") {
        return Ok(Pattern::Localhost);
    }
    if matches!(w, "KNOWN" | "UNKNOWN" | "PARANOID") {
        return Err(format!(
            "pattern {w} needs DNS lookups and is not supported"
        ));
    }
    let w_ip = w.trim_start_matches('[').trim_end_matches(']');
    if let Ok(ip) = w_ip.parse::<IpAddr>() {
        return Ok(Pattern::Addr(ip));
    }
    if let Some((a, m)) = w_ip.split_once('/') {
        let ip: IpAddr = a
            .trim_end_matches(']')
            .parse()
            .map_err(|_| format!("bad network address in '{w}'"))?;
        let bits = match (m.parse::<u32>(), m.parse::<IpAddr>()) {
            (Ok(b), _) => b,
            (_, Ok(IpAddr::V4(mask))) => {
                let v = u32::from(mask);
                if v.leading_ones() + v.trailing_zeros() != 32 {
                    return Err(format!("netmask {mask} in '{w}' is not contiguous"));
                }
                v.leading_ones()
            }
            _ => return Err(format!("bad netmask or prefix length in '{w}'")),
        };
        let max = if ip.is_ipv4() { 32 } else { 128 };
        if bits > max {
            return Err(format!("prefix length {bits} too long in '{w}'"));
        }
        return Ok(Pattern::Net(ip, bits));
    }
    if w.ends_with('.') && w.chars().all(|c| c.is_ascii_digit() || c == '.') {
        return Ok(Pattern::Prefix(w.to_string()));
    }
    if w.chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'))
    {
        return Ok(Pattern::Name(w.to_string()));
    }
    Err(format!("unrecognised pattern '{w}'"))
}

fn daemon_matches(p: &Pattern) -> bool {
    match p {
        Pattern::All => true,
        Pattern::Daemon(d) => d == DAEMON,
        _ => false,
    }
}

fn is_loopback(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v) => v.is_loopback(),
        IpAddr::V6(v) => v.is_loopback() || v.to_ipv4_mapped().is_some_and(|m| m.is_loopback()),
    }
}

fn client_matches(p: &Pattern, peer: Option<IpAddr>) -> bool {
    let Some(ip) = peer else {
        // A UNIX-domain socket is a local client.
        return matches!(p, Pattern::All | Pattern::Local | Pattern::Localhost);
    };
    let ip = match ip {
        IpAddr::V6(v) => v.to_ipv4_mapped().map(IpAddr::V4).unwrap_or(ip),
        v4 => v4,
    };
    match p {
        Pattern::All => true,
        Pattern::Local | Pattern::Localhost => is_loopback(ip),
        Pattern::Addr(a) => *a == ip,
        Pattern::Prefix(pre) => ip.is_ipv4() && ip.to_string().starts_with(pre.as_str()),
        Pattern::Net(net, bits) => in_net(ip, *net, *bits),
        Pattern::Daemon(_) | Pattern::Name(_) => false,
    }
}

fn in_net(ip: IpAddr, net: IpAddr, bits: u32) -> bool {
    match (ip, net) {
        (IpAddr::V4(a), IpAddr::V4(n)) => {
            let mask = if bits == 0 {
                0
            } else {
                u32::MAX << (32 - bits)
            };
            u32::from(a) & mask == u32::from(n) & mask
        }
        (IpAddr::V6(a), IpAddr::V6(n)) => {
            let mask = if bits == 0 {
                0
            } else {
                u128::MAX << (128 - bits)
            };
            u128::from(a) & mask == u128::from(n) & mask
        }
        _ => false,
    }
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

    fn ip(s: &str) -> Option<IpAddr> {
        Some(s.parse().unwrap())
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
            (ip("10.0.0.6"), false),
            (ip("192.0.2.1"), false),
            (None, true),
        ];
        for (peer, allowed) in cases {
            assert_eq!(a.check(peer).is_allowed(), allowed, "{peer:?}");
        }
        assert_eq!(
            a.check(ip("10.0.0.6")),
            Decision::Denied("hosts.deny:1".into())
        );
        assert_eq!(
            a.check(ip("10.0.0.5")),
            Decision::Allowed(Some("hosts.allow:1".into()))
        );
        assert_eq!(
            a.warnings().count(),
            2,
            "the .cs.cmu.edu names cannot match"
        );
    }

    #[test]
    fn patterns() {
        let a = ac(
            "central : 10.1. , 192.168.0.0/255.255.0.0, 172.16.0.0/12, [fe80::]/10 EXCEPT 10.1.2.3\n",
            "central : ALL\n",
        );
        for (peer, allowed) in [
            ("10.1.9.9", true),
            ("10.1.2.3", false),
            ("10.10.0.1", false),
            ("192.168.44.1", true),
            ("172.31.0.1", true),
            ("172.32.0.1", false),
            ("fe80::1", true),
            ("2001:db8::1", false),
        ] {
            assert_eq!(a.check(ip(peer)).is_allowed(), allowed, "{peer}");
        }
    }

    #[test]
    fn other_daemons_and_defaults() {
        let a = ac("", "sshd : ALL\n");
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        let a = ac("", "ALL EXCEPT central : ALL\n");
        assert!(a.check(ip("192.0.2.1")).is_allowed());
        let a = ac("", "central : ALL EXCEPT LOCAL\n");
        assert!(a.check(ip("127.0.0.1")).is_allowed());
        assert!(!a.check(ip("192.0.2.1")).is_allowed());
        assert!(AccessControl::open().check(ip("192.0.2.1")).is_allowed());
    }

    #[test]
    fn comments_continuations_and_options() {
        let a = ac(
            "# comment\n\ncentral : \\\n  127.0.0.1 : ALLOW\n",
            "central: ALL # everything else\n",
        );
        assert_eq!(
            a.check(ip("127.0.0.1")),
            Decision::Allowed(Some("hosts.allow:3".into()))
        );
        assert!(!a.check(ip("127.0.0.2")).is_allowed());
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            (
                "central\n",
                "hosts.x:1: expected 'daemon_list : client_list'",
            ),
            ("ok : ALL\n : ALL\n", "hosts.x:2: empty daemon list"),
            ("central : \n", "hosts.x:1: empty client list"),
            (
                "central : EXCEPT 1.2.3.4\n",
                "hosts.x:1: nothing before EXCEPT",
            ),
            ("central : ALL EXCEPT\n", "hosts.x:1: nothing after EXCEPT"),
            (
                "central : 1.2.3.4/33\n",
                "hosts.x:1: prefix length 33 too long",
            ),
            (
                "central : 1.2.3.4/255.0.255.0\n",
                "hosts.x:1: netmask 255.0.255.0",
            ),
            ("central : KNOWN\n", "hosts.x:1: pattern KNOWN needs DNS"),
            ("central : a$b\n", "hosts.x:1: unrecognised pattern 'a$b'"),
        ];
        for (text, want) in cases {
            let e = Rules::parse(text, "hosts.x").unwrap_err().to_string();
            assert!(e.starts_with(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn missing_file_is_empty() {
        let r = Rules::load(Path::new("/nonexistent/hosts.allow")).unwrap();
        assert!(r.rules.is_empty());
    }
}

//! Endpoint matching (DDS 1.4 §2.2.3 "requested/offered" rules) and the
//! table of discovered participants with lease expiry, sans-I/O.

use foldhash::HashMap;
use std::time::Instant;

use super::discovery::{
    Durability, Duration, EndpointData, EndpointQos, LivelinessKind, ParticipantData, Reliability,
};
use super::types::GuidPrefix;

/// Why a writer and a reader on the same topic do not match.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Incompatible {
    /// Different topic names.
    #[error("topic {writer:?} vs {reader:?}")]
    Topic {
        /// Writer's topic.
        writer: String,
        /// Reader's topic.
        reader: String,
    },
    /// Different type names.
    #[error("type {writer:?} vs {reader:?}")]
    Type {
        /// Writer's type.
        writer: String,
        /// Reader's type.
        reader: String,
    },
    /// One is keyed (entity kind `WITH_KEY`) and the other not: their
    /// types differ in whether they have a key (Cyclone DDS and Fast DDS
    /// refuse the pair too).
    #[error(
        "topic kind: the writer is {}, the reader {}: declare the same key fields on both sides",
        keyed_word(*writer_keyed),
        keyed_word(*reader_keyed)
    )]
    TopicKind {
        /// The writer is keyed.
        writer_keyed: bool,
        /// The reader is keyed.
        reader_keyed: bool,
    },
    /// The reader wants reliable, the writer offers best effort.
    #[error(
        "reliability: the reader requests RELIABLE, the writer offers BEST_EFFORT: make the \
         writer reliable, or the reader best effort"
    )]
    Reliability,
    /// The reader wants more durability than the writer offers.
    #[error(
        "durability: the reader requests {}, the writer offers {}: give the writer {} (or \
         more), or the reader less",
        durability_word(*requested),
        durability_word(*offered),
        durability_word(*requested)
    )]
    Durability {
        /// Offered.
        offered: Durability,
        /// Requested.
        requested: Durability,
    },
    /// The writer's deadline period is longer than the reader's.
    #[error(
        "deadline: the writer offers {}, the reader requests {}: give the writer a deadline of {} or less",
        period(*offered),
        period(*requested),
        period(*requested)
    )]
    Deadline {
        /// The writer's.
        offered: Duration,
        /// The reader's.
        requested: Duration,
    },
    /// Liveliness kind or lease incompatible.
    #[error("liveliness: writer offers less than the reader requests")]
    Liveliness,
    /// Ownership kinds differ.
    #[error(
        "ownership: the writer is {}, the reader {}: make both EXCLUSIVE (a writer's strength, \
         a reader's exclusive) or both SHARED",
        ownership_word(*writer_exclusive),
        ownership_word(!*writer_exclusive)
    )]
    Ownership {
        /// The writer is the exclusive one (else the reader is).
        writer_exclusive: bool,
    },
    /// No common partition. Not an incompatibility DDS reports (DDS 1.4
    /// §2.2.3.13: partitions separate endpoints on purpose): see
    /// [`Incompatible::is_reported`].
    #[error(
        "no common partition: the writer is in {}, the reader in {}",
        partition_list(writer),
        partition_list(reader)
    )]
    Partition {
        /// The writer's partitions (none: the default partition "").
        writer: Vec<String>,
        /// The reader's.
        reader: Vec<String>,
    },
    /// The reader does not accept the data representation the writer uses
    /// (the first it offers).
    #[error(
        "data representation: the writer writes {used} (offers {}), the reader accepts {}: \
         let the reader accept {used}, or have the writer write {}",
        RepresentationList(offered),
        RepresentationList(accepted),
        RepresentationList(accepted).or_list()
    )]
    DataRepresentation {
        /// What the writer writes: the first it offers.
        used: RepresentationName,
        /// Writer's (first is what it uses).
        offered: Vec<i16>,
        /// Reader's.
        accepted: Vec<i16>,
    },
}

/// A QoS period as people write it: `200ms`, `1s`, `infinite`.
fn period(d: Duration) -> String {
    match d.to_std() {
        Some(d) => format!("{d:?}"),
        None => "infinite".into(),
    }
}

fn durability_word(d: Durability) -> &'static str {
    match d {
        Durability::Volatile => "VOLATILE",
        Durability::TransientLocal => "TRANSIENT_LOCAL",
        Durability::Transient => "TRANSIENT",
        Durability::Persistent => "PERSISTENT",
    }
}

fn ownership_word(exclusive: bool) -> &'static str {
    if exclusive {
        "EXCLUSIVE"
    } else {
        "SHARED"
    }
}

/// Partitions as a list; none is the default partition `""`.
fn partition_list(p: &[String]) -> String {
    if p.is_empty() {
        "[\"\"] (the default)".into()
    } else {
        format!("{p:?}")
    }
}

fn keyed_word(keyed: bool) -> &'static str {
    if keyed {
        "keyed (WITH_KEY)"
    } else {
        "not keyed (NO_KEY)"
    }
}

/// A `DataRepresentationId_t` (DDS-XTypes 1.3 §7.6.3.1.1) by its name:
/// `XCDR1` (0), `XML` (1), `XCDR2` (2); any other as its number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RepresentationName(pub i16);

impl std::fmt::Display for RepresentationName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            XCDR1 => f.write_str("XCDR1"),
            XML => f.write_str("XML"),
            XCDR2 => f.write_str("XCDR2"),
            n => write!(f, "representation {n}"),
        }
    }
}

/// `XCDR_DATA_REPRESENTATION`: XCDR version 1.
pub const XCDR1: i16 = 0;
/// `XML_DATA_REPRESENTATION`.
pub const XML: i16 = 1;
/// `XCDR2_DATA_REPRESENTATION`: XCDR version 2.
pub const XCDR2: i16 = 2;

/// A list of data representations by name: `[XCDR1, XCDR2]`.
struct RepresentationList<'a>(&'a [i16]);

impl RepresentationList<'_> {
    /// `XCDR1` or `XCDR1 or XCDR2`.
    fn or_list(&self) -> String {
        let v: Vec<String> = self
            .0
            .iter()
            .map(|r| RepresentationName(*r).to_string())
            .collect();
        v.join(" or ")
    }
}

impl std::fmt::Display for RepresentationList<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("[")?;
        for (i, r) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            write!(f, "{}", RepresentationName(*r))?;
        }
        f.write_str("]")
    }
}

fn liveliness_rank(k: LivelinessKind) -> u8 {
    match k {
        LivelinessKind::Automatic => 0,
        LivelinessKind::ManualByParticipant => 1,
        LivelinessKind::ManualByTopic => 2,
    }
}

/// A bracket expression at the start of `p` (`[abc]`, `[a-z]`, `[!x]` or
/// `[^x]`, POSIX fnmatch): whether it takes byte `c`, and its length;
/// `None` when `p` does not start with a complete one (an unclosed `[` is
/// an ordinary character).
fn bracket(p: &[u8], c: u8) -> Option<(bool, usize)> {
    if p.first() != Some(&b'[') {
        return None;
    }
    let mut i = 1;
    let negate = matches!(p.get(i), Some(b'!' | b'^'));
    if negate {
        i += 1;
    }
    let mut hit = false;
    let mut first = true;
    loop {
        let &x = p.get(i)?;
        if x == b']' && !first {
            return Some((hit != negate, i + 1));
        }
        first = false;
        if p.get(i + 1) == Some(&b'-') && p.get(i + 2).is_some_and(|e| *e != b']') {
            hit |= (x..=p[i + 2]).contains(&c);
            i += 3;
        } else {
            hit |= x == c;
            i += 1;
        }
    }
}

/// fnmatch-style match used for partitions (`*`, `?`, `[...]`):
/// linear-time greedy matching with backtracking to the last `*`, so
/// names from the network cannot make it explode.
fn wildcard(pattern: &str, name: &str) -> bool {
    let (p, n) = (pattern.as_bytes(), name.as_bytes());
    let (mut pi, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        let one = match p.get(pi) {
            Some(b'?') => Some(1),
            Some(b'[') => match bracket(&p[pi..], n[ni]) {
                Some((true, len)) => Some(len),
                Some((false, _)) => None,
                None => (n[ni] == b'[').then_some(1),
            },
            Some(b'*') | None => None,
            Some(c) => (*c == n[ni]).then_some(1),
        };
        if let Some(len) = one {
            pi += len;
            ni += 1;
        } else if pi < p.len() && p[pi] == b'*' {
            star = Some((pi, ni));
            pi += 1;
        } else if let Some((sp, sn)) = star {
            pi = sp + 1;
            ni = sn + 1;
            star = Some((sp, sn + 1));
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|c| *c == b'*')
}

impl Incompatible {
    /// Whether the mismatch is reported (an
    /// [`Event::IncompatibleQos`](crate::rtps::participant::Event::IncompatibleQos)):
    /// every reason but [`Incompatible::Partition`]. Endpoints in different
    /// partitions are kept apart on purpose; DDS raises no status for them
    /// (DDS 1.4 §2.2.3.13), nor do Cyclone DDS and Fast DDS, so a system of
    /// robots each in its own partition does not flood every reader with
    /// mismatches.
    pub fn is_reported(&self) -> bool {
        !matches!(self, Incompatible::Partition { .. })
    }
}

/// A partition name with wildcards (fnmatch's `*`, `?` and bracket
/// expressions).
fn has_wildcard(p: &str) -> bool {
    p.contains(['*', '?'])
        || p.as_bytes()
            .iter()
            .enumerate()
            .any(|(i, c)| *c == b'[' && bracket(&p.as_bytes()[i..], 0).is_some())
}

/// Whether the partitions of a writer and a reader have a name in common:
/// equal names, or a name matching the other side's wildcard pattern; two
/// patterns never match each other (DDS 1.4 §2.2.3.13), as in Cyclone DDS.
fn partitions_match(w: &[String], r: &[String]) -> bool {
    let norm = |v: &[String]| -> Vec<String> {
        if v.is_empty() {
            vec![String::new()]
        } else {
            v.to_vec()
        }
    };
    let (w, r) = (norm(w), norm(r));
    let pair = |a: &String, b: &String| match (has_wildcard(a), has_wildcard(b)) {
        (false, false) => a == b,
        (true, false) => wildcard(a, b),
        (false, true) => wildcard(b, a),
        (true, true) => false,
    };
    w.iter().any(|a| r.iter().any(|b| pair(a, b)))
}

/// Checks the requested/offered QoS rules for a writer and a reader.
pub fn check_qos(offered: &EndpointQos, requested: &EndpointQos) -> Result<(), Incompatible> {
    if matches!(requested.reliability, Reliability::Reliable(_))
        && matches!(offered.reliability, Reliability::BestEffort)
    {
        return Err(Incompatible::Reliability);
    }
    if offered.durability < requested.durability {
        return Err(Incompatible::Durability {
            offered: offered.durability,
            requested: requested.durability,
        });
    }
    if offered.deadline.longer_than(requested.deadline) {
        return Err(Incompatible::Deadline {
            offered: offered.deadline,
            requested: requested.deadline,
        });
    }
    if liveliness_rank(offered.liveliness.0) < liveliness_rank(requested.liveliness.0)
        || offered.liveliness.1.longer_than(requested.liveliness.1)
    {
        return Err(Incompatible::Liveliness);
    }
    if offered.exclusive_ownership != requested.exclusive_ownership {
        return Err(Incompatible::Ownership {
            writer_exclusive: offered.exclusive_ownership,
        });
    }
    if !partitions_match(&offered.partitions, &requested.partitions) {
        return Err(Incompatible::Partition {
            writer: offered.partitions.clone(),
            reader: requested.partitions.clone(),
        });
    }
    // The writer uses the first representation it offers; the reader must accept it.
    let used = offered
        .data_representation
        .first()
        .copied()
        .unwrap_or(XCDR1);
    let accepted = if requested.data_representation.is_empty() {
        vec![XCDR1]
    } else {
        requested.data_representation.clone()
    };
    if !accepted.contains(&used) {
        return Err(Incompatible::DataRepresentation {
            used: RepresentationName(used),
            offered: offered.data_representation.clone(),
            accepted,
        });
    }
    Ok(())
}

/// Checks topic, type and QoS of a writer against a reader.
pub fn check_match(writer: &EndpointData, reader: &EndpointData) -> Result<(), Incompatible> {
    if writer.topic_name != reader.topic_name {
        return Err(Incompatible::Topic {
            writer: writer.topic_name.clone(),
            reader: reader.topic_name.clone(),
        });
    }
    if writer.type_name != reader.type_name {
        return Err(Incompatible::Type {
            writer: writer.type_name.clone(),
            reader: reader.type_name.clone(),
        });
    }
    let (writer_keyed, reader_keyed) =
        (writer.guid.entity.is_keyed(), reader.guid.entity.is_keyed());
    if writer_keyed != reader_keyed {
        return Err(Incompatible::TopicKind {
            writer_keyed,
            reader_keyed,
        });
    }
    check_qos(&writer.qos, &reader.qos)
}

/// What changed in the participant table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ParticipantEvent {
    /// First SPDP from this participant.
    Found(GuidPrefix),
    /// Its SPDP data changed.
    Changed(GuidPrefix),
    /// Disposed, or its lease expired.
    Lost(GuidPrefix),
}

/// Discovered participants, with lease expiry driven by explicit time.
#[derive(Debug, Default)]
pub struct Participants {
    table: HashMap<GuidPrefix, (ParticipantData, Instant)>,
    /// When each participant was last heard from (any message, SPDP
    /// included): what asserts the liveliness of its AUTOMATIC writers.
    heard: HashMap<GuidPrefix, Instant>,
}

impl Participants {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// An SPDP announcement arrived at `now`.
    pub fn announce(&mut self, data: ParticipantData, now: Instant) -> Option<ParticipantEvent> {
        let prefix = data.guid_prefix;
        let lease = data
            .lease_duration
            .to_std()
            .unwrap_or(std::time::Duration::from_secs(86_400 * 365));
        // a lease from the network must not overflow the clock
        let expiry = now
            .checked_add(lease)
            .or_else(|| now.checked_add(std::time::Duration::from_secs(86_400 * 365)))
            .unwrap_or(now);
        self.heard.insert(prefix, now);
        match self.table.insert(prefix, (data.clone(), expiry)) {
            None => Some(ParticipantEvent::Found(prefix)),
            Some((old, _)) if old != data => Some(ParticipantEvent::Changed(prefix)),
            Some(_) => None,
        }
    }

    /// Any message from the participant arrived at `now`: its lease starts
    /// over, as Cyclone DDS does. Returns false if it is unknown.
    pub fn renew(&mut self, prefix: GuidPrefix, now: Instant) -> bool {
        let Some((data, expiry)) = self.table.get_mut(&prefix) else {
            return false;
        };
        let lease = data
            .lease_duration
            .to_std()
            .unwrap_or(std::time::Duration::from_secs(86_400 * 365));
        if let Some(t) = now.checked_add(lease) {
            *expiry = (*expiry).max(t);
        }
        if let Some(h) = self.heard.get_mut(&prefix) {
            *h = (*h).max(now);
        }
        true
    }

    /// When anything last came from the participant (`None`: unknown).
    pub fn heard(&self, prefix: &GuidPrefix) -> Option<Instant> {
        self.heard.get(prefix).copied()
    }

    /// The participants known, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = &ParticipantData> + '_ {
        self.table.values().map(|(d, _)| d)
    }

    /// The participant said goodbye (SPDP dispose).
    pub fn remove(&mut self, prefix: GuidPrefix) -> Option<ParticipantEvent> {
        self.heard.remove(&prefix);
        self.table
            .remove(&prefix)
            .map(|_| ParticipantEvent::Lost(prefix))
    }

    /// When the next lease expires.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.table.values().map(|(_, t)| *t).min()
    }

    /// Removes participants whose lease expired by `now`.
    pub fn handle_timeout(&mut self, now: Instant) -> Vec<ParticipantEvent> {
        let gone: Vec<GuidPrefix> = self
            .table
            .iter()
            .filter(|(_, (_, t))| *t <= now)
            .map(|(p, _)| *p)
            .collect();
        gone.into_iter().filter_map(|p| self.remove(p)).collect()
    }

    /// A participant's data.
    pub fn get(&self, prefix: &GuidPrefix) -> Option<&ParticipantData> {
        self.table.get(prefix).map(|(d, _)| d)
    }

    /// Number of known participants.
    pub fn len(&self) -> usize {
        self.table.len()
    }

    /// True if none are known.
    pub fn is_empty(&self) -> bool {
        self.table.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::super::discovery::History;
    use super::super::{ProtocolVersion, VendorId};
    use super::*;

    #[test]
    fn reasons_name_both_sides_and_the_fix_in_dds_words() {
        let ms100 = Duration::from_std(std::time::Duration::from_millis(100));
        assert_eq!(ms100.to_std(), Some(std::time::Duration::from_millis(100)));
        let d = Incompatible::Deadline {
            offered: Duration::INFINITE,
            requested: ms100,
        };
        assert_eq!(
            d.to_string(),
            "deadline: the writer offers infinite, the reader requests 100ms: give the writer a deadline of 100ms or less"
        );
        let d = Incompatible::Durability {
            offered: Durability::Volatile,
            requested: Durability::TransientLocal,
        };
        assert_eq!(
            d.to_string(),
            "durability: the reader requests TRANSIENT_LOCAL, the writer offers VOLATILE: give the writer TRANSIENT_LOCAL (or more), or the reader less"
        );
        assert!(Incompatible::Reliability
            .to_string()
            .ends_with("make the writer reliable, or the reader best effort"));
    }

    #[test]
    fn requested_offered_rules() {
        let w = EndpointQos::writer_default();
        let r = EndpointQos::reader_default();
        assert_eq!(check_qos(&w, &r), Ok(()));
        let mut be = w.clone();
        be.reliability = Reliability::BestEffort;
        let mut rel = r.clone();
        rel.reliability = Reliability::Reliable(Duration::ZERO);
        assert_eq!(check_qos(&be, &rel), Err(Incompatible::Reliability));
        assert_eq!(check_qos(&be, &r), Ok(()));
        let mut tl = r.clone();
        tl.durability = Durability::TransientLocal;
        assert!(matches!(
            check_qos(&w, &tl),
            Err(Incompatible::Durability { .. })
        ));
        let mut wd = w.clone();
        wd.durability = Durability::TransientLocal;
        wd.history = History::KeepLast(10);
        assert_eq!(check_qos(&wd, &tl), Ok(()));
        let mut dl = r.clone();
        dl.deadline = Duration {
            seconds: 1,
            fraction: 0,
        };
        let e = check_qos(&w, &dl).unwrap_err();
        assert!(matches!(e, Incompatible::Deadline { .. }));
        assert_eq!(
            e.to_string(),
            "deadline: the writer offers infinite, the reader requests 1s: give the writer a \
             deadline of 1s or less"
        );
        let mut ex = w.clone();
        ex.exclusive_ownership = true;
        let e = check_qos(&ex, &r).unwrap_err();
        assert_eq!(
            e,
            Incompatible::Ownership {
                writer_exclusive: true
            }
        );
        assert!(e
            .to_string()
            .starts_with("ownership: the writer is EXCLUSIVE, the reader SHARED"));
        let e = Incompatible::Partition {
            writer: vec![],
            reader: vec!["a".into()],
        };
        assert_eq!(
            e.to_string(),
            "no common partition: the writer is in [\"\"] (the default), the reader in [\"a\"]"
        );
        // Fast DDS 2.9 accepts only XCDR1: an XCDR2 writer does not match it
        let mut x2 = w.clone();
        x2.data_representation = vec![2];
        let e = check_qos(&x2, &r).unwrap_err();
        assert!(matches!(e, Incompatible::DataRepresentation { .. }));
        // the representations by name, and what to change on which side
        assert_eq!(
            e.to_string(),
            "data representation: the writer writes XCDR2 (offers [XCDR2]), the reader \
             accepts [XCDR1]: let the reader accept XCDR2, or have the writer write XCDR1"
        );
        let mut odd = r.clone();
        odd.data_representation = vec![0, 1, 7];
        assert!(check_qos(&x2, &odd)
            .unwrap_err()
            .to_string()
            .contains("accepts [XCDR1, XML, representation 7]"));
        let mut both = r.clone();
        both.data_representation = vec![0, 2];
        assert_eq!(check_qos(&x2, &both), Ok(()));
    }

    /// 300 ms as Cyclone DDS 11 writes it (fraction rounded up,
    /// 1288490189) and as Courier wrote it before (rounded down,
    /// 1288490188): a deadline or lease given alike on both sides matches
    /// whichever way each rounded (Courier refused a Cyclone writer's
    /// 300 ms deadline and 700 ms lease as longer than its own).
    #[test]
    fn durations_given_alike_match_however_the_peer_rounded_them() {
        let ms = |n| Duration::from_std(std::time::Duration::from_millis(n));
        assert_eq!(
            ms(300),
            Duration {
                seconds: 0,
                fraction: 1288490189
            },
            "rounded up, as Cyclone DDS"
        );
        assert_eq!(ms(100).fraction, 429496730);
        assert_eq!(ms(250).fraction, 1 << 30, "exact stays exact");
        assert_eq!(
            ms(1000),
            Duration {
                seconds: 1,
                fraction: 0
            }
        );
        for n in [1, 100, 300, 700, 999, 1300] {
            let d = ms(n);
            assert_eq!(d.to_std(), Some(std::time::Duration::from_millis(n)));
            let down = Duration {
                fraction: d.fraction.saturating_sub(1),
                ..d
            };
            assert_eq!(down.to_std(), d.to_std(), "{n} ms rounded down");
            // as a deadline and as a lease, offered rounded one way and
            // requested the other: they match both ways round
            for (o, r) in [(d, down), (down, d)] {
                let mut w = EndpointQos::writer_default();
                let mut rd = EndpointQos::reader_default();
                w.deadline = o;
                rd.deadline = r;
                w.liveliness.1 = o;
                rd.liveliness.1 = r;
                assert_eq!(check_qos(&w, &rd), Ok(()), "{n} ms");
            }
        }
        // a nanosecond longer is longer; infinity is longest
        let a = Duration::from_std(std::time::Duration::from_nanos(300_000_001));
        assert!(a.longer_than(ms(300)) && !ms(300).longer_than(a));
        assert!(Duration::INFINITE.longer_than(ms(1_000_000)));
        assert!(!Duration::INFINITE.longer_than(Duration::INFINITE));
        let negative = Duration {
            seconds: -1,
            fraction: 0,
        };
        assert!(Duration::ZERO.longer_than(negative));
    }

    #[test]
    fn partitions_use_wildcards() {
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert!(partitions_match(&[], &[]));
        assert!(!partitions_match(&s(&["a"]), &[]));
        assert!(partitions_match(&s(&["robot*"]), &s(&["robot1"])));
        assert!(partitions_match(&s(&["x", "r?"]), &s(&["r2"])));
        assert!(!partitions_match(&s(&["a"]), &s(&["b"])));
        // two patterns never match, not even equal ones (§2.2.3.13; Cyclone
        // DDS 11 matched neither pair, Courier matched both)
        assert!(!partitions_match(&s(&["sens*"]), &s(&["sens*"])));
        assert!(!partitions_match(&s(&["sens*"]), &s(&["se*"])));
        assert!(!partitions_match(&s(&["r?"]), &s(&["r*"])));
        assert!(partitions_match(&s(&["sens*", "x"]), &s(&["se*", "x"])));
        assert!(partitions_match(&s(&["a"]), &s(&["*"])));
        // hostile: many stars against a long name stays fast
        let p = "*a".repeat(200) + "b";
        assert!(!wildcard(&p, &"a".repeat(5000)));
        assert!(wildcard("*", ""));
        assert!(wildcard("a*b*c", "aXXbYYc"));
        assert!(!wildcard("a*b*c", "aXXbYY"));
        // POSIX fnmatch's bracket expressions (Fast DDS matches `[ab]c`
        // with `ac`; Courier took `[` literally, audit 19)
        assert!(wildcard("[ab]c", "ac") && wildcard("[ab]c", "bc"));
        assert!(!wildcard("[ab]c", "cc"));
        assert!(wildcard("robot[0-9]", "robot7") && !wildcard("robot[0-9]", "robotx"));
        assert!(wildcard("[!a]x", "bx") && !wildcard("[!a]x", "ax"));
        assert!(wildcard("[^a]x", "bx"));
        assert!(wildcard("[]]", "]"), "a ] first is a member");
        assert!(wildcard("[a-]", "-"), "a - last is a member");
        assert!(wildcard("*[xy]", "aaay") && !wildcard("*[xy]", "aaaz"));
        // an unclosed [ is an ordinary character
        assert!(wildcard("a[b", "a[b") && !wildcard("a[b", "ab"));
        assert!(partitions_match(&s(&["[ab]c"]), &s(&["ac"])));
        assert!(
            !partitions_match(&s(&["[ab]c"]), &s(&["a*"])),
            "two patterns"
        );
        assert!(
            partitions_match(&s(&["a[b"]), &s(&["a[b"])),
            "no pattern: equal names"
        );
    }

    #[test]
    fn leases_expire_on_explicit_time() {
        let t0 = Instant::now();
        let mut p = Participants::new();
        let data = ParticipantData {
            guid_prefix: GuidPrefix([9; 12]),
            protocol_version: ProtocolVersion::V2_5,
            vendor: VendorId::CYCLONE,
            domain_id: Some(0),
            default_unicast: vec![],
            default_multicast: vec![],
            metatraffic_unicast: vec![],
            metatraffic_multicast: vec![],
            lease_duration: Duration {
                seconds: 10,
                fraction: 0,
            },
            builtin_endpoints: 0,
            entity_name: None,
        };
        assert_eq!(
            p.announce(data.clone(), t0),
            Some(ParticipantEvent::Found(data.guid_prefix))
        );
        assert_eq!(
            p.announce(data.clone(), t0 + std::time::Duration::from_secs(5)),
            None
        );
        assert!(p
            .handle_timeout(t0 + std::time::Duration::from_secs(14))
            .is_empty());
        assert_eq!(
            p.handle_timeout(t0 + std::time::Duration::from_secs(15)),
            [ParticipantEvent::Lost(data.guid_prefix)]
        );
        assert!(p.is_empty());
    }
}

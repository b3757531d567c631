//! Pattern subscriptions: a reader per publication whose topic and type
//! names match fnmatch patterns, made as publications are discovered.

use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};
use std::time::Instant;

use crate::rtps::discovery::{Durability, EndpointData, EndpointQos, Reliability};
use crate::rtps::participant::EndpointConfig;
use crate::rtps::Guid;

use super::{Domain, Event, PatternId, ReaderId, Role};

/// What a publication offers that a pattern reader must copy to match it.
#[derive(Debug, Clone)]
pub(super) struct Offer {
    pub(super) keyed: bool,
    pub(super) exclusive: bool,
    pub(super) partitions: Vec<String>,
    /// What the pattern reader may ask of it (see [`Grade`]).
    pub(super) grade: Grade,
}

impl Offer {
    pub(super) fn of(e: &EndpointData) -> Self {
        Offer {
            keyed: e.guid.entity.is_keyed(),
            exclusive: e.qos.exclusive_ownership,
            partitions: e.qos.partitions.clone(),
            grade: Grade::of(&e.qos),
        }
    }
}

/// How much a pattern reader asks of the publications of its topic: as
/// much as each offers, as `ros2 bag record` does, so that a recorder gets
/// what a reliable publication repairs and the history a transient-local
/// one keeps for late joiners; never more than one of them offers, or it
/// would not match that one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Grade {
    reliable: bool,
    /// Transient-local (or more) and reliable: its history comes.
    durable: bool,
}

impl Grade {
    pub(super) fn of(q: &EndpointQos) -> Grade {
        let reliable = matches!(q.reliability, Reliability::Reliable(_));
        Grade {
            reliable,
            durable: reliable && q.durability >= Durability::TransientLocal,
        }
    }

    /// What both `self` and `other` offer.
    fn meet(self, other: Grade) -> Grade {
        Grade {
            reliable: self.reliable && other.reliable,
            durable: self.durable && other.durable,
        }
    }
}

pub(super) struct Pattern {
    topic: String,
    type_name: String,
    qos: EndpointQos,
    /// The reader of each (topic, type) pair that has one.
    have: HashMap<(String, String), Matched>,
}

/// A pattern's reader of one (topic, type) pair.
struct Matched {
    reader: Guid,
    grade: Grade,
    /// The publications (remote and local writers) of the pair it was
    /// made or kept for: when the last of them is gone, so is the reader
    /// ([`Event::PatternUnmatched`]). Kept, a recorder on a domain where
    /// processes come and go with topics of their own held a reader per
    /// topic ever seen, announced to every participant that joined.
    publications: HashSet<Guid>,
}

impl Domain {
    /// Subscribes to every topic whose name matches `topic` and whose type
    /// name matches `type_name` (fnmatch patterns: `*`, `?`, `[…]`, see
    /// [`fnmatch`]): a reader with `qos` is made for each matching
    /// publication, remote or local, now and as they are discovered
    /// ([`Event::PatternMatched`]). Each reader takes its publication's
    /// ownership kind and partitions, which DDS needs equal to match, and
    /// its reliability and durability (`qos`'s own are not
    /// used): a later publication of the same topic that offers less gets
    /// the reader replaced by one that asks less
    /// (`PatternMatched::replaces`). A reader whose publications are all
    /// gone (deleted, or lost with their participant) is deleted
    /// ([`Event::PatternUnmatched`]); one is made again if another comes.
    pub fn create_pattern(
        &mut self,
        topic: &str,
        type_name: &str,
        qos: EndpointQos,
        now: Instant,
    ) -> PatternId {
        let id = PatternId(self.next_id());
        self.patterns.insert(
            id,
            Pattern {
                topic: topic.to_string(),
                type_name: type_name.to_string(),
                qos,
                have: HashMap::new(),
            },
        );
        let mut known: Vec<(String, String, Offer, Guid)> = self
            .p
            .publications()
            .map(|e| {
                let offer = Offer::of(e);
                (e.topic_name.clone(), e.type_name.clone(), offer, e.guid)
            })
            .collect();
        for (g, w) in &self.writers {
            known.push((w.topic.clone(), w.type_name.clone(), w.offer.clone(), *g));
        }
        for (t, ty, offer, g) in known {
            self.pattern_match(id, &t, &ty, &offer, g, now);
        }
        self.drain(now);
        id
    }

    /// Deletes a pattern subscription and every reader it made; false if
    /// there is no such pattern.
    pub fn delete_pattern(&mut self, pattern: PatternId, now: Instant) -> bool {
        let Some(pat) = self.patterns.remove(&pattern) else {
            return false;
        };
        for m in pat.have.into_values() {
            self.remove_reader(m.reader, now);
        }
        self.drain(now);
        true
    }

    /// Offers publication `publication` (a remote or local writer) to
    /// every pattern.
    pub(super) fn offer_to_patterns(
        &mut self,
        topic: &str,
        type_name: &str,
        offer: &Offer,
        publication: Guid,
        now: Instant,
    ) {
        let ids: Vec<PatternId> = self.patterns.keys().copied().collect();
        for id in ids {
            self.pattern_match(id, topic, type_name, offer, publication, now);
        }
    }

    /// A publication is gone (its writer deleted, or lost with its
    /// participant): the pattern readers left with no publication are
    /// deleted.
    pub(super) fn withdraw_from_patterns(&mut self, publication: Guid, now: Instant) {
        let mut unmatched = Vec::new();
        for (id, pat) in self.patterns.iter_mut() {
            pat.have.retain(|(topic, type_name), m| {
                let last = m.publications.remove(&publication) && m.publications.is_empty();
                if last {
                    unmatched.push((*id, m.reader, topic.clone(), type_name.clone()));
                }
                !last
            });
        }
        for (pattern, reader, topic, type_name) in unmatched {
            self.remove_reader(reader, now);
            self.events.push_back(Event::PatternUnmatched {
                pattern,
                reader: ReaderId(reader),
                topic,
                type_name,
            });
        }
    }

    /// Creates the reader of pattern `id` for publication `publication`
    /// of `topic` if it matches.
    fn pattern_match(
        &mut self,
        id: PatternId,
        topic: &str,
        type_name: &str,
        offer: &Offer,
        publication: Guid,
        now: Instant,
    ) {
        let Some(pat) = self.patterns.get_mut(&id) else {
            return;
        };
        if !fnmatch(&pat.topic, topic) || !fnmatch(&pat.type_name, type_name) {
            return;
        }
        let key = (topic.to_string(), type_name.to_string());
        let (grade, replaces) = match pat.have.get_mut(&key) {
            None => (offer.grade, None),
            // it asks no more than this one offers: it matches it too
            Some(m) if m.grade.meet(offer.grade) == m.grade => {
                m.publications.insert(publication);
                return;
            }
            // a weaker publication: a reader that asks less replaces it
            // (what it took stays taken; the new one takes what comes)
            Some(m) => (m.grade.meet(offer.grade), Some(m.reader)),
        };
        let mut qos = pat.qos.clone();
        qos.exclusive_ownership = offer.exclusive;
        qos.partitions = offer.partitions.clone();
        qos.reliability = if grade.reliable {
            // (a reader's max blocking time means nothing; DDS's default)
            EndpointQos::writer_default().reliability
        } else {
            Reliability::BestEffort
        };
        qos.durability = if grade.durable {
            Durability::TransientLocal
        } else {
            Durability::Volatile
        };
        let cfg = EndpointConfig::reader(topic, type_name)
            .keyed(offer.keyed)
            .qos(qos);
        let mut publications = HashSet::new();
        if let Some(old) = replaces {
            self.remove_reader(old, now);
            if let Some(m) = self
                .patterns
                .get_mut(&id)
                .and_then(|pat| pat.have.remove(&key))
            {
                publications = m.publications;
            }
        }
        publications.insert(publication);
        if let Ok(g) = self.add_reader(cfg, Role::Pattern(id), now) {
            if let Some(pat) = self.patterns.get_mut(&id) {
                let m = Matched {
                    reader: g,
                    grade,
                    publications,
                };
                pat.have.insert(key, m);
            }
            self.events.push_back(Event::PatternMatched {
                pattern: id,
                reader: ReaderId(g),
                topic: topic.to_string(),
                type_name: type_name.to_string(),
                replaces: replaces.map(ReaderId),
            });
        }
    }
}

/// fnmatch(3)-style matching: `*`, `?`, `[abc]`, `[a-z]`, `[!x]`, `\` escapes.
pub fn fnmatch(pattern: &str, name: &str) -> bool {
    let p: Vec<char> = pattern.chars().collect();
    let n: Vec<char> = name.chars().collect();
    // iterative matcher with backtracking to the last `*`
    let (mut pi, mut ni) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while ni < n.len() {
        if pi < p.len() {
            match p[pi] {
                '*' => {
                    star = Some((pi, ni));
                    pi += 1;
                    continue;
                }
                '?' => {
                    pi += 1;
                    ni += 1;
                    continue;
                }
                '[' => {
                    if let Some((ok, next)) = class(&p, pi, n[ni]) {
                        if ok {
                            pi = next;
                            ni += 1;
                            continue;
                        }
                    } else if n[ni] == '[' {
                        pi += 1;
                        ni += 1;
                        continue;
                    }
                }
                '\\' if pi + 1 < p.len() => {
                    if p[pi + 1] == n[ni] {
                        pi += 2;
                        ni += 1;
                        continue;
                    }
                }
                c => {
                    if c == n[ni] {
                        pi += 1;
                        ni += 1;
                        continue;
                    }
                }
            }
        }
        match star {
            Some((sp, sn)) => {
                pi = sp + 1;
                ni = sn + 1;
                star = Some((sp, sn + 1));
            }
            None => return false,
        }
    }
    p[pi..].iter().all(|c| *c == '*')
}

/// A bracket expression at `p[i]`: whether `c` is in it, and the index after it.
fn class(p: &[char], i: usize, c: char) -> Option<(bool, usize)> {
    let mut j = i + 1;
    let negate = matches!(p.get(j), Some('!') | Some('^'));
    if negate {
        j += 1;
    }
    let mut hit = false;
    let mut first = true;
    while j < p.len() {
        if p[j] == ']' && !first {
            return Some((hit != negate, j + 1));
        }
        first = false;
        if j + 2 < p.len() && p[j + 1] == '-' && p[j + 2] != ']' {
            if p[j] <= c && c <= p[j + 2] {
                hit = true;
            }
            j += 3;
        } else {
            if p[j] == c {
                hit = true;
            }
            j += 1;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnmatch_like_libc() {
        for (p, n, m) in [
            ("*", "", true),
            ("*", "anything", true),
            ("Hello*", "HelloWorld", true),
            ("Hello*", "Hell", false),
            ("rq/*Request", "rq/add_two_intsRequest", true),
            ("?ello", "Hello", true),
            ("?ello", "ello", false),
            ("[HJ]ello", "Jello", true),
            ("[!HJ]ello", "Jello", false),
            ("[a-c]x", "bx", true),
            ("[a-c]x", "dx", false),
            ("a\\*b", "a*b", true),
            ("a\\*b", "axb", false),
            ("*a*b*c", "xxaxxbxxc", true),
            ("*a*b*c", "xxaxxcxxb", false),
            ("[", "[", true),
        ] {
            assert_eq!(fnmatch(p, n), m, "{p} ~ {n}");
        }
    }
}

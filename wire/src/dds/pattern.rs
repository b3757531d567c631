//! Pattern subscriptions: a reader per publication whose topic and type
//! names match fnmatch patterns, made as publications are discovered.

use foldhash::{HashSet, HashSetExt};
use std::time::Instant;

use crate::rtps::discovery::{EndpointData, EndpointQos};
use crate::rtps::participant::EndpointConfig;
use crate::rtps::Guid;

use super::{Domain, Event, PatternId, ReaderId, Role};

/// What a publication offers that a pattern reader must copy to match it.
#[derive(Debug, Clone)]
pub(super) struct Offer {
    pub(super) keyed: bool,
    pub(super) exclusive: bool,
    pub(super) partitions: Vec<String>,
}

impl Offer {
    pub(super) fn of(e: &EndpointData) -> Self {
        Offer {
            keyed: e.guid.entity.is_keyed(),
            exclusive: e.qos.exclusive_ownership,
            partitions: e.qos.partitions.clone(),
        }
    }
}

pub(super) struct Pattern {
    topic: String,
    type_name: String,
    qos: EndpointQos,
    /// (topic, type) pairs that have a reader already.
    have: HashSet<(String, String)>,
    pub(super) readers: Vec<Guid>,
}

impl Domain {
    /// Subscribes to every topic whose name matches `topic` and whose type
    /// name matches `type_name` (fnmatch patterns: `*`, `?`, `[…]`, see
    /// [`fnmatch`]): a reader with `qos` is made for each matching
    /// publication, remote or local, now and as they are discovered
    /// ([`Event::PatternMatched`]). Each reader takes its publication's
    /// ownership kind and partitions, which DDS needs equal to match.
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
                have: HashSet::new(),
                readers: Vec::new(),
            },
        );
        let mut known: Vec<(String, String, Offer)> = self
            .p
            .publications()
            .map(|e| (e.topic_name.clone(), e.type_name.clone(), Offer::of(e)))
            .collect();
        for w in self.writers.values() {
            known.push((w.topic.clone(), w.type_name.clone(), w.offer.clone()));
        }
        for (t, ty, offer) in known {
            self.pattern_match(id, &t, &ty, &offer, now);
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
        for g in pat.readers {
            self.remove_reader(g, now);
        }
        self.drain(now);
        true
    }

    /// Offers a publication to every pattern.
    pub(super) fn offer_to_patterns(
        &mut self,
        topic: &str,
        type_name: &str,
        offer: &Offer,
        now: Instant,
    ) {
        let ids: Vec<PatternId> = self.patterns.keys().copied().collect();
        for id in ids {
            self.pattern_match(id, topic, type_name, offer, now);
        }
    }

    /// Creates the reader of pattern `id` for a publication of `topic` if
    /// it matches.
    fn pattern_match(
        &mut self,
        id: PatternId,
        topic: &str,
        type_name: &str,
        offer: &Offer,
        now: Instant,
    ) {
        let Some(pat) = self.patterns.get(&id) else {
            return;
        };
        if !fnmatch(&pat.topic, topic) || !fnmatch(&pat.type_name, type_name) {
            return;
        }
        let key = (topic.to_string(), type_name.to_string());
        if pat.have.contains(&key) {
            return;
        }
        let mut qos = pat.qos.clone();
        qos.exclusive_ownership = offer.exclusive;
        qos.partitions = offer.partitions.clone();
        let cfg = EndpointConfig::reader(topic, type_name)
            .keyed(offer.keyed)
            .qos(qos);
        if let Ok(g) = self.add_reader(cfg, Role::Pattern(id), now) {
            if let Some(pat) = self.patterns.get_mut(&id) {
                pat.have.insert(key);
                pat.readers.push(g);
            }
            self.events.push_back(Event::PatternMatched {
                pattern: id,
                reader: ReaderId(g),
                topic: topic.to_string(),
                type_name: type_name.to_string(),
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

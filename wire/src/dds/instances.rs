//! How a keyed reader names the instances of its samples, also when its
//! writers' key hashes come in different XCDR versions: see
//! [`InstanceKeys`].

use foldhash::{HashMap, HashMapExt};

use crate::cdr::{RepresentationId, Version};
use crate::rtps::participant::{ChangeKind, KeyHash, ReceivedSample};
use crate::IpcMessage;

/// At most this many digest aliases per reader (see [`InstanceKeys`]).
pub const MAX_KEY_HASH_ALIASES: usize = 16_384;

/// What a keyed reader knows of its type's instances from encoded bytes
/// ([`Domain::set_instance_keys`](super::Domain::set_instance_keys)): how
/// to find the instance of a sample whose writer sent no key hash, and how
/// to name one instance alike whichever XCDR version its writers write.
/// [`InstanceKeys::of`] makes them for a type.
///
/// A writer computes the key hash (`PID_KEY_HASH`) in the XCDR version of
/// its data, as Cyclone DDS and Fast DDS do (see [`KeyHash`]), and for
/// some keys the two versions' hashes of one instance differ (`@key long
/// id; @key long long stamp;`: XCDR1 aligns `stamp` to 8, XCDR2 to 4). A
/// reader whose writers write different versions would then keep two
/// instances for one: a dispose from one writer would not dispose what the
/// other wrote, exclusive ownership would let both through, a deadline
/// would run per half.
///
/// So a reader told its keys names every instance in one *canonical*
/// version: the version of the first change it takes while it holds no
/// instance. A change in that version (the payload's encapsulation header
/// says, or for a change with no payload the data representation its
/// writer announced) is named by its hash as it comes, as without keys:
/// nothing is decoded or hashed again, so a reader whose writers all write
/// one version pays nothing. A change in the other version is named by the
/// canonical hash of the same key:
///
/// 1. from its hash, when that holds the key itself (the type's key fits
///    16 bytes in the writer's version): the key is read back from it and
///    hashed in the canonical version ([`translate`](Self::translate)),
///    without touching the payload;
/// 2. else from its payload, a sample or a dispose or unregister with the
///    serialized key ([`hash_in`](Self::hash_in)): the hash it came with
///    (an MD5 digest) is then remembered as an *alias* of the canonical
///    one;
/// 3. else (a dispose or unregister with a digest and no key, as Fast DDS
///    sends them) through the aliases: a writer's hash-only change of an
///    instance finds the canonical hash its earlier samples gave. A digest
///    with no alias (the writer wrote no sample of the instance that this
///    reader took, or the aliases were full) stays as it came: the change
///    lands on an instance of its own, as every change of the other
///    version did before readers named instances canonically.
///
/// Aliases are bounded: one per instance, dropped when the reader forgets
/// the instance (no writer has it any more), at most
/// [`MAX_KEY_HASH_ALIASES`] in all; past that new ones are not remembered
/// (case 3). A reader that holds no instance chooses its canonical version
/// anew with the next change, so one whose writers of the first version
/// have all gone stops renaming.
#[derive(Clone, Copy)]
pub struct InstanceKeys {
    /// The key hash in XCDR version `version` of a payload of the reader's
    /// type: a sample (`false`) or the serialized key of a dispose or
    /// unregister (`true`), with its encapsulation header, whatever version
    /// the payload itself is in; `None` if it does not decode.
    /// [`cdr::key_hash_of_payload_in`](crate::cdr::key_hash_of_payload_in)
    /// is one.
    pub hash_in: fn(&[u8], bool, Version) -> Option<[u8; 16]>,
    /// The key hash in version `to` of the instance whose key hash in
    /// version `from` is `hash`, when that hash holds the key; `None` for
    /// an MD5 digest (or bytes that are no key).
    /// [`cdr::translate_key_hash`](crate::cdr::translate_key_hash) is one.
    pub translate: fn(&[u8; 16], Version, Version) -> Option<[u8; 16]>,
}

impl InstanceKeys {
    /// The instance keys of `T`'s CDR payloads.
    ///
    /// ```
    /// use courier_wire::cdr::{self, Encoding, Version};
    /// use courier_wire::dds::InstanceKeys;
    /// let keys = InstanceKeys::of::<u64>();
    /// let sample = cdr::to_vec(&7u64, Encoding::Xcdr1Le);
    /// // a type without key fields has no instances to tell apart
    /// assert_eq!((keys.hash_in)(&sample, false, Version::Xcdr2), None);
    /// ```
    pub fn of<T: IpcMessage>() -> Self {
        InstanceKeys {
            hash_in: crate::cdr::key_hash_of_payload_in::<T>,
            translate: crate::cdr::translate_key_hash::<T>,
        }
    }
}

impl std::fmt::Debug for InstanceKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("InstanceKeys(..)")
    }
}

/// The XCDR version of a payload, from its encapsulation header.
fn payload_version(data: &[u8]) -> Option<Version> {
    let id = u16::from_be_bytes([*data.first()?, *data.get(1)?]);
    Some(RepresentationId::from_u16(id)?.encoding().version())
}

/// A reader's naming of instances (see [`InstanceKeys`]).
pub(super) struct Instances {
    keys: Option<InstanceKeys>,
    /// The version instances are named in; `None` until the first change
    /// whose version is known.
    canonical: Option<Version>,
    /// Digest key hash of the other version → canonical hash.
    aliases: HashMap<[u8; 16], [u8; 16]>,
    /// Canonical hash → its alias: what goes when the instance goes.
    alias_of: HashMap<[u8; 16], [u8; 16]>,
    cap: usize,
    /// Changes named by decoding or hashing again (their version is not
    /// the canonical one): none while every writer writes one version.
    pub(super) renamed: u64,
}

impl Instances {
    pub(super) fn new() -> Self {
        Instances::with_cap(MAX_KEY_HASH_ALIASES)
    }

    fn with_cap(cap: usize) -> Self {
        Instances {
            keys: None,
            canonical: None,
            aliases: HashMap::new(),
            alias_of: HashMap::new(),
            cap,
            renamed: 0,
        }
    }

    pub(super) fn set_keys(&mut self, keys: InstanceKeys) {
        self.keys = Some(keys);
    }

    /// The instance of `s`, canonically named; `s.key_hash`, when its
    /// writer sent none, becomes what it would have sent (the hash in the
    /// payload's version), as the shell reports it. `writer_version`: the
    /// version of its writer's data, as announced. `empty`: the reader
    /// holds no instance, so the canonical version may be chosen anew.
    pub(super) fn identify(
        &mut self,
        s: &mut ReceivedSample,
        writer_version: Option<Version>,
        empty: bool,
    ) -> [u8; 16] {
        let Some(keys) = self.keys else {
            return s.key_hash.map_or([0; 16], |k| k.0);
        };
        let key_only = s.kind != ChangeKind::Alive;
        let in_payload = payload_version(s.data());
        let version = in_payload.or(writer_version);
        if empty {
            self.canonical = None;
            self.aliases.clear();
            self.alias_of.clear();
        }
        if self.canonical.is_none() {
            self.canonical = version;
        }
        let sent = s.key_hash.map(|k| k.0);
        if sent.is_none() {
            // what its writer would have sent
            s.key_hash = in_payload
                .and_then(|v| (keys.hash_in)(s.data(), key_only, v))
                .map(KeyHash);
        }
        let own = s.key_hash.map(|k| k.0);
        let (version, canonical) = match (version, self.canonical) {
            (Some(v), Some(c)) if v != c => (v, c),
            // the canonical version (or one unknown): as it comes
            _ => return own.unwrap_or([0; 16]),
        };
        self.renamed += 1;
        // 1. a hash that holds the key: no payload to decode again
        if let Some(c) = own.and_then(|h| (keys.translate)(&h, version, canonical)) {
            return c;
        }
        // 2. the payload
        let data = s.data();
        let from_payload = if data.is_empty() {
            None
        } else {
            (keys.hash_in)(data, key_only, canonical)
        };
        match (from_payload, sent) {
            (Some(c), Some(h)) => {
                // a digest the writer may send alone later
                self.alias(h, c);
                c
            }
            (Some(c), None) => c,
            // 3. a digest alone
            (None, Some(h)) => self.aliases.get(&h).copied().unwrap_or(h),
            (None, None) => own.unwrap_or([0; 16]),
        }
    }

    /// Whether dispose `s` carries its writer's whole sample rather than
    /// the serialized key (Cyclone DDS's `write_dispose` sends the sample
    /// with the dispose flag and no key hash): its payload decodes as a
    /// sample and not as a key. Known only with the reader's keys, and
    /// looked at only when no key hash came (a dispose named by its hash
    /// costs nothing more); a payload that decodes as both (a type all
    /// key) is taken as the key.
    pub(super) fn carries_sample(&self, s: &ReceivedSample) -> bool {
        let Some(keys) = self.keys else {
            return false;
        };
        if s.key_hash.is_some()
            || !matches!(
                s.kind,
                ChangeKind::Disposed | ChangeKind::DisposedUnregistered
            )
        {
            return false;
        }
        let data = s.data();
        let Some(v) = payload_version(data) else {
            return false;
        };
        (keys.hash_in)(data, true, v).is_none() && (keys.hash_in)(data, false, v).is_some()
    }

    /// Remembers that `sent` (a hash of the other version that does not
    /// hold the key) names instance `canonical`.
    fn alias(&mut self, sent: [u8; 16], canonical: [u8; 16]) {
        if sent == canonical || self.aliases.get(&sent) == Some(&canonical) {
            return;
        }
        if let Some(old) = self.alias_of.remove(&canonical) {
            self.aliases.remove(&old);
        }
        if let Some(other) = self.aliases.remove(&sent) {
            self.alias_of.remove(&other);
        }
        if self.aliases.len() >= self.cap {
            return;
        }
        self.aliases.insert(sent, canonical);
        self.alias_of.insert(canonical, sent);
    }

    /// The reader forgot `instance`: so does its alias.
    pub(super) fn forget(&mut self, instance: &[u8; 16]) {
        if let Some(sent) = self.alias_of.remove(instance) {
            self.aliases.remove(&sent);
        }
    }

    /// Aliases held (tests).
    #[cfg(test)]
    pub(super) fn aliases(&self) -> usize {
        debug_assert_eq!(self.aliases.len(), self.alias_of.len());
        self.aliases.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::{self, Encoding};
    use crate::rtps::participant::{guid_prefix, Change, Config, EndpointConfig};
    use std::cell::Cell;
    use std::time::{Instant, SystemTime};

    /// A key of three members: `@key long id; @key long long stamp; @key
    /// long extra;` written as a bare tuple, its XCDR1 hash an MD5 digest
    /// (the key can take 20 bytes), its XCDR2 hash the key (16).
    type Key = (i32, i64, i32);

    fn form(k: Key, v: Version) -> Vec<u8> {
        let mut w = cdr::Writer::key_hash_form_in(v);
        w.write_i32(k.0);
        w.write_i64(k.1);
        w.write_i32(k.2);
        w.into_vec()
    }

    fn hash(k: Key, v: Version) -> [u8; 16] {
        KeyHash::from_key(&form(k, v), v == Version::Xcdr1).0
    }

    /// A payload: the encapsulation header, then the key, 16 bytes
    /// whatever the version (the fields read back by position).
    fn payload(k: Key, v: Version) -> Vec<u8> {
        let mut b = cdr::Writer::with_header(
            Encoding::new(v, cdr::Endianness::Big),
            cdr::Extensibility::Final,
        )
        .into_vec();
        b.extend_from_slice(&k.0.to_be_bytes());
        b.extend_from_slice(&k.1.to_be_bytes());
        b.extend_from_slice(&k.2.to_be_bytes());
        b
    }

    fn key_of(data: &[u8]) -> Option<Key> {
        let b = data.get(4..20)?;
        Some((
            i32::from_be_bytes(b[..4].try_into().ok()?),
            i64::from_be_bytes(b[4..12].try_into().ok()?),
            i32::from_be_bytes(b[12..].try_into().ok()?),
        ))
    }

    thread_local! {
        /// Calls of the key functions on this thread.
        static CALLS: Cell<u32> = const { Cell::new(0) };
    }

    fn hash_in(data: &[u8], _key_only: bool, v: Version) -> Option<[u8; 16]> {
        CALLS.with(|c| c.set(c.get() + 1));
        Some(hash(key_of(data)?, v))
    }

    fn translate(h: &[u8; 16], from: Version, to: Version) -> Option<[u8; 16]> {
        CALLS.with(|c| c.set(c.get() + 1));
        // only the XCDR2 hash is the key itself
        (from == Version::Xcdr2).then(|| {
            let k = (
                i32::from_be_bytes(h[..4].try_into().unwrap()),
                i64::from_be_bytes(h[4..12].try_into().unwrap()),
                i32::from_be_bytes(h[12..].try_into().unwrap()),
            );
            hash(k, to)
        })
    }

    fn keys() -> InstanceKeys {
        InstanceKeys { hash_in, translate }
    }

    fn calls() -> u32 {
        CALLS.with(Cell::get)
    }

    /// The changes as a reader receives them, through a participant's
    /// local delivery (only a participant makes a `ReceivedSample`): each
    /// from the first writer, or the second when its flag says so.
    fn received(changes: &[(Change<'static>, bool)]) -> Vec<ReceivedSample> {
        use crate::rtps::participant::{Event, Participant};
        let now = Instant::now();
        let cfg = Config::udpv4(0, 0, guid_prefix([3; 10]), [127, 0, 0, 1]).unwrap();
        let mut p = Participant::new(cfg, now, SystemTime::UNIX_EPOCH);
        let r = p
            .create_reader(EndpointConfig::reader("K", "T").keyed(true), now)
            .unwrap();
        let w = p
            .create_writer(EndpointConfig::writer("K", "T").keyed(true), now)
            .unwrap();
        let w2 = p
            .create_writer(EndpointConfig::writer("K", "T").keyed(true), now)
            .unwrap();
        for (c, second) in changes {
            p.write(if *second { w2 } else { w }, c.clone(), now)
                .unwrap();
        }
        let mut out = Vec::new();
        while let Some(e) = p.poll_event() {
            if let Event::SampleReceived(s) = e {
                assert_eq!(s.reader, r);
                out.push(s);
            }
        }
        out
    }

    fn sample(k: Key, v: Version, with_hash: bool) -> Change<'static> {
        let c = Change::alive_owned(payload(k, v));
        if with_hash {
            c.with_key_hash(KeyHash(hash(k, v)))
        } else {
            c
        }
    }

    /// While every change is of the canonical version nothing is decoded
    /// or hashed again: the hashes sent name the instances.
    #[test]
    fn one_version_costs_nothing() {
        let mut ins = Instances::new();
        ins.set_keys(keys());
        let changes: Vec<_> = (0..20)
            .map(|i| (sample((i, 1, 2), Version::Xcdr1, true), false))
            .chain([(
                Change::dispose(&[], KeyHash(hash((3, 1, 2), Version::Xcdr1))),
                false,
            )])
            .collect();
        let before = calls();
        for (i, mut s) in received(&changes).into_iter().enumerate() {
            let sent = s.key_hash.unwrap().0;
            // hash-only changes take the writer's announced version
            let got = ins.identify(&mut s, Some(Version::Xcdr1), i == 0);
            assert_eq!(got, sent);
        }
        assert_eq!(calls(), before, "no key function called");
        assert_eq!((ins.renamed, ins.aliases()), (0, 0));
    }

    /// A change of the other version is named canonically: a hash that
    /// holds the key without the payload, a digest from the payload (then
    /// remembered), a hash-only digest through that alias, an unknown one
    /// as it came.
    #[test]
    fn the_other_version_is_named_canonically() {
        let mut ins = Instances::new();
        ins.set_keys(keys());
        let k = (7, 0x0102_0304_0506_0708, -7);
        let x1 = hash(k, Version::Xcdr1);
        let x2 = hash(k, Version::Xcdr2);
        assert_ne!(x1, x2);
        let unknown = hash((9, 9, 9), Version::Xcdr1);
        let changes = [
            (sample(k, Version::Xcdr2, false), true),
            (sample(k, Version::Xcdr1, true), false),
            (Change::dispose(&[], KeyHash(x1)), false),
            (Change::dispose(&[], KeyHash(unknown)), false),
        ];
        let got: Vec<[u8; 16]> = received(&changes)
            .into_iter()
            .enumerate()
            .map(|(i, mut s)| {
                let v = if s.data().is_empty() {
                    Some(Version::Xcdr1)
                } else {
                    None
                };
                ins.identify(&mut s, v, i == 0)
            })
            .collect();
        assert_eq!(got, [x2, x2, x2, unknown]);
        assert_eq!(ins.aliases(), 1);
        assert_eq!(ins.renamed, 3);
        // XCDR1 canonical: the XCDR2 hash (the key) names it without the payload
        let mut ins = Instances::new();
        ins.set_keys(keys());
        let changes = [
            (sample(k, Version::Xcdr1, true), false),
            (Change::dispose(&[], KeyHash(x2)), true),
        ];
        let got: Vec<[u8; 16]> = received(&changes)
            .into_iter()
            .enumerate()
            .map(|(i, mut s)| ins.identify(&mut s, Some(Version::Xcdr2), i == 0))
            .collect();
        assert_eq!(got, [x1, x1]);
        assert_eq!(ins.aliases(), 0, "no digest to remember");
    }

    /// Aliases go with their instance, and never exceed the cap: past it a
    /// new one is not remembered and a hash-only change of its instance
    /// keeps the hash it came with.
    #[test]
    fn aliases_are_bounded() {
        let mut ins = Instances::with_cap(4);
        ins.set_keys(keys());
        let key = |i: i32| (i, 1, 2);
        let mut changes = vec![(sample(key(100), Version::Xcdr2, true), true)];
        changes.extend((0..6).map(|i| (sample(key(i), Version::Xcdr1, true), false)));
        let mut named = Vec::new();
        for (i, mut s) in received(&changes).into_iter().enumerate() {
            named.push(ins.identify(&mut s, None, i == 0));
        }
        assert_eq!(ins.aliases(), 4, "capped");
        // the first four are known, the last two not
        for i in 0..6 {
            let mut s = received(&[(
                Change::dispose(&[], KeyHash(hash(key(i), Version::Xcdr1))),
                false,
            )])
            .pop()
            .unwrap();
            let got = ins.identify(&mut s, Some(Version::Xcdr1), false);
            if i < 4 {
                assert_eq!(got, hash(key(i), Version::Xcdr2), "{i}");
            } else {
                assert_eq!(got, hash(key(i), Version::Xcdr1), "{i}: as it came");
            }
        }
        // forgetting an instance frees its alias
        ins.forget(&hash(key(0), Version::Xcdr2));
        assert_eq!(ins.aliases(), 3);
        let mut s = received(&[(sample(key(5), Version::Xcdr1, true), false)])
            .pop()
            .unwrap();
        ins.identify(&mut s, None, false);
        assert_eq!(ins.aliases(), 4, "room for a new one");
        // a reader that holds no instance chooses anew, and starts empty
        let mut s = received(&[(sample(key(1), Version::Xcdr1, true), false)])
            .pop()
            .unwrap();
        assert_eq!(
            ins.identify(&mut s, None, true),
            hash(key(1), Version::Xcdr1)
        );
        assert_eq!(ins.aliases(), 0);
        assert_eq!(named[0], hash(key(100), Version::Xcdr2));
    }
}

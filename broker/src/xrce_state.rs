//! `xrce-agent --state <file>`: every client's session, objects,
//! READ_DATA and reliable input positions kept in a redb database, so that
//! an agent killed and started again serves its clients as before
//! ([`Bridge::restore`](courier_wire::xrce::bridge::Bridge::restore)).
//! One record per client, written whenever what it holds changes
//! (sessions, CREATE, DELETE, READ_DATA), and one small record of its
//! input positions (table `inputs`), written after the samples DDS took
//! and before the client's ACKNACK says so (one transaction per turn of
//! the agent's loop, for every client that moved); both committed
//! durably: they survive `kill -9` and power loss alike.
//!
//! An input positions record: `XAP1`, then per reliable input stream its
//! id and the sequence number (u16 LE) of the last message whose samples
//! DDS took. A file without it (an older agent's) restores the client's
//! streams from its HEARTBEAT.
//!
//! A record: `XAS1`, the client key (4 bytes), session id, MTU (u16 LE),
//! the client's address (`0` UDP: transport index, IPv4, port LE; `1`
//! TCP: none, the client reconnects; `2` serial: transport index, serial
//! address), then an XRCE message whose submessages are the CREATEs of its
//! objects in creation order and its READ_DATAs.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use courier_wire::xrce::bridge::ClientState;
use courier_wire::xrce::{
    BaseObjectRequest, ClientKey, Create, Message, MessageHeader, Payload, SeqNum, StreamId,
    Submessage,
};
use redb::{Database, ReadableTable, TableDefinition};

use super::xrce_agent::Peer;

const CLIENTS: TableDefinition<u32, &[u8]> = TableDefinition::new("clients");
const INPUTS: TableDefinition<u32, &[u8]> = TableDefinition::new("inputs");
const MAGIC: &[u8; 4] = b"XAS1";
const INPUTS_MAGIC: &[u8; 4] = b"XAP1";

/// A client's reliable input positions.
pub(crate) type Positions = Vec<(StreamId, SeqNum)>;

/// The state file. A write that fails (a full disk, a file system gone
/// read-only) leaves the database unusable: the store then closes it,
/// stops saving (one error line), and opens it again at most once a
/// second; once it is open again the agent saves every session anew
/// ([`Store::reopened`]).
pub(crate) struct Store {
    path: PathBuf,
    db: Option<Database>,
    /// When to try opening it again, while it is closed.
    retry_at: Instant,
    /// Opened again after a failure, and no write has worked since: a
    /// failure then is the same trouble (not said again), a success is
    /// said once.
    retrying: bool,
}

/// Writes are off until the file can be opened again (said once).
#[derive(Debug)]
pub(crate) struct Closed;

/// Opens (or creates) the state file; the clients it holds.
pub(crate) fn open(path: &Path) -> Result<(Store, Vec<ClientState<Peer>>), String> {
    open_with(path, |p: &Path| Database::create(p))
}

/// [`open`], with what makes the database. A file this call created and
/// could not make a database of (a full disk) is removed again: left, it
/// would be refused as damaged at every later start, and an agent
/// restarted by a supervisor would stay down until someone deletes it.
/// One another agent holds is left alone.
fn open_with(
    path: &Path,
    create: impl Fn(&Path) -> Result<Database, redb::DatabaseError> + std::panic::RefUnwindSafe,
) -> Result<(Store, Vec<ClientState<Peer>>), String> {
    let existed = std::fs::symlink_metadata(path).is_ok();
    let was_empty = std::fs::metadata(path).is_ok_and(|m| m.len() == 0);
    let mut in_use = false;
    let opened = open_made(path, create, &mut in_use);
    if opened.is_err() && !existed && !in_use {
        let _ = std::fs::remove_file(path);
    }
    if opened.is_ok() && was_empty {
        // (truncated by hand or by a disk that filled before anything was
        // written): not silently a fresh start
        tracing::warn!(
            "state file {} was empty: the agent starts without saved sessions",
            path.display()
        );
    }
    opened
}

/// `in_use`: set when another agent holds the file.
fn open_made(
    path: &Path,
    create: impl Fn(&Path) -> Result<Database, redb::DatabaseError> + std::panic::RefUnwindSafe,
    in_use: &mut bool,
) -> Result<(Store, Vec<ClientState<Peer>>), String> {
    let fail = |e: &dyn std::fmt::Display| format!("state file {}: {e}", path.display());
    let damaged = |e: &dyn std::fmt::Display| {
        format!(
            "state file {} is damaged or not an agent's state file ({e}); move it away to \
             start without the saved sessions",
            path.display()
        )
    };
    // redb asserts (panics) on some truncated files instead of failing:
    // caught, without the panic's message and backtrace on stderr before
    // the error that says what to do
    // (one opener at a time swaps the process's hook, or two could leave
    // the quiet one in place)
    static HOOK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let opened = {
        let _one = HOOK.lock().unwrap_or_else(|e| e.into_inner());
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let opened = std::panic::catch_unwind(|| create(path));
        std::panic::set_hook(hook);
        opened
    };
    let db = match opened {
        Ok(Ok(db)) => db,
        Ok(Err(redb::DatabaseError::Storage(redb::StorageError::Corrupted(e)))) => {
            return Err(damaged(&e))
        }
        Ok(Err(redb::DatabaseError::Storage(redb::StorageError::Io(e))))
            if matches!(
                e.kind(),
                std::io::ErrorKind::InvalidData | std::io::ErrorKind::UnexpectedEof
            ) =>
        {
            return Err(damaged(&e))
        }
        Ok(Err(e @ redb::DatabaseError::DatabaseAlreadyOpen)) => {
            *in_use = true;
            return Err(fail(&e));
        }
        Ok(Err(e)) => return Err(fail(&e)),
        Err(_) => return Err(damaged(&"the database library gave up reading it")),
    };
    let mut states = Vec::new();
    {
        let tx = db.begin_write().map_err(|e| fail(&e))?;
        {
            // the tables exist from now on
            let t = tx.open_table(CLIENTS).map_err(|e| fail(&e))?;
            let inputs = tx.open_table(INPUTS).map_err(|e| fail(&e))?;
            for row in t.iter().map_err(|e| fail(&e))? {
                let (k, v) = row.map_err(|e| fail(&e))?;
                match decode(v.value()) {
                    Some(mut s) => {
                        if let Some(p) = inputs.get(k.value()).map_err(|e| fail(&e))? {
                            match decode_positions(p.value()) {
                                Some(p) => s.inputs = p,
                                None => tracing::warn!(
                                    "state file {}: the input positions of client 0x{:08X} \
                                     are damaged; its streams take the client's",
                                    path.display(),
                                    k.value()
                                ),
                            }
                        }
                        states.push(s)
                    }
                    None => tracing::warn!(
                        "state file {}: the record of client 0x{:08X} is damaged; it is left out",
                        path.display(),
                        k.value()
                    ),
                }
            }
        }
        tx.commit().map_err(|e| fail(&e))?;
    }
    let store = Store {
        path: path.to_path_buf(),
        db: Some(db),
        retry_at: Instant::now(),
        retrying: false,
    };
    Ok((store, states))
}

impl Store {
    /// Runs a write transaction; a failure closes the database (said
    /// once, with what it means), and nothing is written until
    /// [`Store::reopened`].
    fn write(
        &mut self,
        what: &str,
        f: impl FnOnce(&Database) -> Result<(), String>,
    ) -> Result<(), Closed> {
        let db = self.db.as_ref().ok_or(Closed)?;
        if let Err(e) = f(db) {
            if !self.retrying {
                tracing::error!(
                    "state file {}: {what}: {e}; sessions are not saved until it can be \
                     written again (retried every second): a restart meanwhile would not \
                     restore them as they are",
                    self.path.display()
                );
            }
            self.retrying = true;
            self.db = None;
            self.retry_at = Instant::now() + Duration::from_secs(1);
            return Err(Closed);
        }
        if std::mem::take(&mut self.retrying) {
            tracing::warn!(
                "state file {}: writable again; every session is saved anew",
                self.path.display()
            );
        }
        Ok(())
    }

    /// While writes are off: opens the file again if it is time to try;
    /// whether it is open again (the caller then saves every session, and
    /// forgets those [`Store::saved_clients`] has that it does not).
    pub(crate) fn reopened(&mut self, now: Instant) -> bool {
        if self.db.is_some() || now < self.retry_at {
            return false;
        }
        self.retry_at = now + Duration::from_secs(1);
        match Database::create(&self.path) {
            Ok(db) => {
                // (said once a write works: opening works on a full disk)
                self.db = Some(db);
                true
            }
            Err(_) => false,
        }
    }

    /// The clients the file holds.
    pub(crate) fn saved_clients(&self) -> Vec<ClientKey> {
        let Some(db) = &self.db else {
            return Vec::new();
        };
        let read = || -> Result<Vec<ClientKey>, String> {
            let tx = db.begin_read().map_err(text)?;
            let t = tx.open_table(CLIENTS).map_err(text)?;
            let mut keys = Vec::new();
            for row in t.iter().map_err(text)? {
                keys.push(ClientKey::from(row.map_err(text)?.0.value()));
            }
            Ok(keys)
        };
        read().unwrap_or_default()
    }

    /// Saves (or replaces) a client's record and input positions.
    pub(crate) fn save(&mut self, s: &ClientState<Peer>) -> Result<(), Closed> {
        self.write("saving a session", |db| save(db, s))
    }

    /// Saves the input positions of the clients that moved, in one
    /// durable transaction (done when this returns Ok).
    pub(crate) fn save_positions(
        &mut self,
        moved: &[(ClientKey, Positions)],
    ) -> Result<(), Closed> {
        self.write("input positions", |db| save_positions(db, moved))
    }

    /// Forgets a client.
    pub(crate) fn remove(&mut self, client: ClientKey) -> Result<(), Closed> {
        self.write("forgetting a session", |db| remove(db, client))
    }
}

/// Saves (or replaces) a client's record and input positions.
fn save(db: &Database, s: &ClientState<Peer>) -> Result<(), String> {
    let bytes = encode(s);
    let tx = db.begin_write().map_err(text)?;
    {
        let mut t = tx.open_table(CLIENTS).map_err(text)?;
        t.insert(u32::from(s.client), bytes.as_slice())
            .map_err(text)?;
        let mut t = tx.open_table(INPUTS).map_err(text)?;
        t.insert(u32::from(s.client), encode_positions(&s.inputs).as_slice())
            .map_err(text)?;
    }
    tx.commit().map_err(text)
}

fn save_positions(db: &Database, moved: &[(ClientKey, Positions)]) -> Result<(), String> {
    let tx = db.begin_write().map_err(text)?;
    {
        let mut t = tx.open_table(INPUTS).map_err(text)?;
        for (client, p) in moved {
            t.insert(u32::from(*client), encode_positions(p).as_slice())
                .map_err(text)?;
        }
    }
    tx.commit().map_err(text)
}

fn remove(db: &Database, client: ClientKey) -> Result<(), String> {
    let tx = db.begin_write().map_err(text)?;
    {
        let mut t = tx.open_table(CLIENTS).map_err(text)?;
        t.remove(u32::from(client)).map_err(text)?;
        let mut t = tx.open_table(INPUTS).map_err(text)?;
        t.remove(u32::from(client)).map_err(text)?;
    }
    tx.commit().map_err(text)
}

fn text(e: impl std::fmt::Display) -> String {
    e.to_string()
}

fn encode(s: &ClientState<Peer>) -> Vec<u8> {
    let mut v = MAGIC.to_vec();
    v.extend_from_slice(&s.client.0);
    v.push(s.session_id);
    v.extend_from_slice(&s.mtu.to_le_bytes());
    match s.addr {
        Peer::Udp(i, SocketAddr::V4(a)) => {
            v.extend_from_slice(&[0, i]);
            v.extend_from_slice(&a.ip().octets());
            v.extend_from_slice(&a.port().to_le_bytes());
        }
        Peer::Serial(i, src) => v.extend_from_slice(&[2, i, src]),
        Peer::Tcp(_) | Peer::Udp(_, SocketAddr::V6(_)) => v.push(1),
    }
    let mut subs: Vec<Submessage> = s
        .objects
        .iter()
        .map(|(id, object)| {
            Submessage::new(Payload::Create(Create {
                request: BaseObjectRequest::new(0, *id),
                object: object.clone(),
            }))
        })
        .collect();
    subs.extend(
        s.reads
            .iter()
            .map(|r| Submessage::new(Payload::ReadData(r.clone()))),
    );
    let m = Message::new(MessageHeader::new(0x80, StreamId::NONE, 0), subs);
    // objects too large for one message are kept as far as they go
    v.extend(m.to_vec().unwrap_or_default());
    v
}

fn encode_positions(p: &[(StreamId, SeqNum)]) -> Vec<u8> {
    let mut v = INPUTS_MAGIC.to_vec();
    for (id, seq) in p {
        v.push(id.0);
        v.extend_from_slice(&seq.0.to_le_bytes());
    }
    v
}

fn decode_positions(b: &[u8]) -> Option<Positions> {
    let rest = b.strip_prefix(INPUTS_MAGIC)?;
    if rest.len() % 3 != 0 {
        return None;
    }
    rest.chunks_exact(3)
        .map(|c| {
            let id = StreamId(c[0]);
            id.is_reliable()
                .then(|| (id, SeqNum(u16::from_le_bytes([c[1], c[2]]))))
        })
        .collect()
}

fn decode(b: &[u8]) -> Option<ClientState<Peer>> {
    let rest = b.strip_prefix(MAGIC)?;
    let key: [u8; 4] = rest.get(..4)?.try_into().ok()?;
    let session_id = *rest.get(4)?;
    let mtu = u16::from_le_bytes(rest.get(5..7)?.try_into().ok()?);
    let (addr, rest) = match *rest.get(7)? {
        0 => {
            let i = *rest.get(8)?;
            let ip: [u8; 4] = rest.get(9..13)?.try_into().ok()?;
            let port = u16::from_le_bytes(rest.get(13..15)?.try_into().ok()?);
            (
                Peer::Udp(
                    i,
                    SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::from(ip), port)),
                ),
                rest.get(15..)?,
            )
        }
        // a TCP client comes back on a new connection: until then, an
        // address no connection has
        1 => (
            Peer::Tcp(u64::MAX - u64::from(u32::from_be_bytes(key))),
            rest.get(8..)?,
        ),
        2 => (Peer::Serial(*rest.get(8)?, *rest.get(9)?), rest.get(10..)?),
        _ => return None,
    };
    let m = Message::decode(rest).ok()?;
    let mut objects = Vec::new();
    let mut reads = Vec::new();
    for s in m.submessages {
        match s.payload {
            Payload::Create(c) => objects.push((c.request.object_id, c.object)),
            Payload::ReadData(r) => reads.push(r),
            _ => return None,
        }
    }
    Some(ClientState {
        client: ClientKey(key),
        session_id,
        mtu,
        addr,
        objects,
        reads,
        // kept in their own table (they move with every sample)
        inputs: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier_wire::xrce::{
        DeliveryControl, ObjectId, ObjectKind, ObjectVariant, ReadData, Representation,
    };

    /// A state file this start created and could not make a database of
    /// (the disk filled up) is removed, so that the next start, once
    /// there is room, begins afresh (audit 16: a 1.5 MB file was left and
    /// every later start refused it as damaged). One that was there
    /// before, or that another agent holds, stays.
    #[test]
    fn a_state_file_left_half_made_by_a_failed_start_is_removed() {
        let dir = std::env::temp_dir().join(format!("xrce-state-half-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("agent.redb");
        let _ = std::fs::remove_file(&path);
        fn full(p: &Path) -> Result<Database, redb::DatabaseError> {
            std::fs::write(p, [0u8; 4096]).unwrap();
            Err(redb::DatabaseError::Storage(redb::StorageError::Io(
                std::io::Error::from_raw_os_error(libc::ENOSPC),
            )))
        }
        fn held(p: &Path) -> Result<Database, redb::DatabaseError> {
            std::fs::write(p, [0u8; 16]).unwrap();
            Err(redb::DatabaseError::DatabaseAlreadyOpen)
        }
        let e = open_with(&path, full).err().expect("a full disk fails");
        assert!(e.contains("No space left"), "{e}");
        assert!(!path.exists(), "the half-made file is gone");
        // one that was there before stays
        std::fs::write(&path, b"old").unwrap();
        assert!(open_with(&path, full).is_err());
        assert!(path.exists());
        std::fs::remove_file(&path).unwrap();
        // and so does one another agent holds
        assert!(open_with(&path, held).is_err());
        assert!(path.exists());
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn records_round_trip() {
        let s = ClientState {
            client: ClientKey::from(0xAABB_CCDD),
            session_id: 0x81,
            mtu: 508,
            addr: Peer::Udp(1, "127.0.0.1:40000".parse().unwrap()),
            objects: vec![(
                ObjectId::new(1, ObjectKind::Participant),
                ObjectVariant::Participant {
                    representation: Representation::Xml("<dds/>".into()),
                    domain_id: 3,
                },
            )],
            reads: vec![ReadData {
                request: BaseObjectRequest::new(14, ObjectId::new(1, ObjectKind::DataReader)),
                preferred_stream_id: StreamId::RELIABLE,
                data_format: 0,
                content_filter: None,
                delivery_control: Some(DeliveryControl {
                    max_samples: u16::MAX,
                    ..DeliveryControl::default()
                }),
            }],
            inputs: Vec::new(),
        };
        assert_eq!(decode(&encode(&s)), Some(s.clone()));
        let p = vec![
            (StreamId::RELIABLE, SeqNum(7)),
            (StreamId(0x81), SeqNum(u16::MAX)),
        ];
        assert_eq!(decode_positions(&encode_positions(&p)), Some(p));
        assert_eq!(decode_positions(b"XAP1"), Some(Vec::new()));
        assert_eq!(decode_positions(b"XAP1\x80\x01"), None);
        assert_eq!(decode_positions(b"XAP1\x01\x01\x00"), None);
        let serial = ClientState {
            addr: Peer::Serial(0, 1),
            ..s.clone()
        };
        assert_eq!(decode(&encode(&serial)), Some(serial));
        let mut damaged = encode(&s);
        damaged.truncate(20);
        assert_eq!(decode(&damaged), None);
    }

    /// Input positions are saved with the record and on their own, read
    /// back with the client's state, and forgotten with the client.
    #[test]
    fn input_positions_survive_reopening() {
        let dir = std::env::temp_dir().join(format!("courier-pos-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.redb");
        let _ = std::fs::remove_file(&path);
        let st = ClientState {
            client: ClientKey::from(0x0102_0304),
            session_id: 0x81,
            mtu: 512,
            addr: Peer::Udp(0, "127.0.0.1:40001".parse().unwrap()),
            objects: Vec::new(),
            reads: Vec::new(),
            inputs: vec![(StreamId::RELIABLE, SeqNum(3))],
        };
        {
            let (mut store, states) = open(&path).unwrap();
            assert!(states.is_empty());
            store.save(&st).unwrap();
        }
        let moved = vec![(st.client, vec![(StreamId::RELIABLE, SeqNum(41))])];
        {
            let (mut store, states) = open(&path).unwrap();
            assert_eq!(states, vec![st.clone()]);
            store.save_positions(&moved).unwrap();
        }
        {
            let (mut store, states) = open(&path).unwrap();
            assert_eq!(states[0].inputs, moved[0].1);
            store.remove(st.client).unwrap();
        }
        assert!(open(&path).unwrap().1.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A write that fails closes the file, which writes nothing more until
    /// it opens again (at most once a second); the agent then saves every
    /// session anew. (What a full disk does: redb refuses every write after
    /// one I/O error until the database is opened again.)
    #[test]
    fn a_failed_write_closes_the_file_until_it_opens_again() {
        let dir = std::env::temp_dir().join(format!("courier-reopen-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.redb");
        let _ = std::fs::remove_file(&path);
        let st = ClientState {
            client: ClientKey::from(0x0A0B_0C0D),
            session_id: 0x81,
            mtu: 512,
            addr: Peer::Udp(0, "127.0.0.1:40002".parse().unwrap()),
            objects: Vec::new(),
            reads: Vec::new(),
            inputs: Vec::new(),
        };
        let (mut store, _) = open(&path).unwrap();
        assert!(store
            .write("a test", |_| Err("No space left on device".into()))
            .is_err());
        assert!(store.save(&st).is_err(), "closed: nothing is written");
        assert!(store.saved_clients().is_empty());
        let now = Instant::now();
        assert!(store.reopened(now + Duration::from_secs(2)));
        store.save(&st).unwrap();
        assert_eq!(store.saved_clients(), [st.client]);
        drop(store);
        assert_eq!(open(&path).unwrap().1, [st]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A truncated or foreign file is an error that says what to do, not a
    /// panic (redb asserts on some truncations).
    #[test]
    fn a_damaged_state_file_is_an_error_not_a_panic() {
        let dir = std::env::temp_dir().join(format!("courier-state-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.redb");
        drop(open(&path).unwrap());
        let whole = std::fs::read(&path).unwrap();
        for len in [100, 512, 4096, whole.len() / 2] {
            std::fs::write(&path, &whole[..len.min(whole.len())]).unwrap();
            let e = open(&path).err().expect("a damaged file");
            assert!(e.contains("move it away"), "{len} bytes: {e}");
        }
        std::fs::write(&path, vec![0x5a; 8192]).unwrap();
        let e = open(&path).err().expect("not a state file");
        assert!(e.contains("move it away"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

//! Stream links (TCP-like): reliable, ordered byte streams between two
//! ends, set up by a connect to a listening address and ended by a close
//! (EOF). The network never loses, duplicates or reorders stream bytes,
//! but it cuts and joins them as [`StreamFaults`] says, and it delays
//! them: what a node reads is any split of what its peer wrote.
//!
//! A link has two ends, each a [`StreamId`]; the bytes one end writes
//! travel in a pipe of their own to the other. An end belongs to a host
//! or, for ends made by [`Net::connect_raw`] and [`Net::listen_raw`], to
//! the test driving the network.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use super::{Net, Node};

/// One end of a stream link. The two ends of a link are `2k` and `2k + 1`
/// ([`StreamId::peer`]); ids are never reused within a network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StreamId(pub u64);

impl StreamId {
    /// The other end of the link.
    pub fn peer(self) -> StreamId {
        StreamId(self.0 ^ 1)
    }

    fn link(self) -> usize {
        usize::try_from(self.0 / 2).unwrap_or(usize::MAX)
    }

    fn side(self) -> usize {
        (self.0 % 2) as usize
    }
}

/// What a node asks the network to do with its streams
/// ([`Node::poll_stream`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StreamOp<A> {
    /// Open a connection to whoever listens at `to`; the answer comes to
    /// [`Node::handle_connect`] with the same `token`.
    Connect {
        /// Where.
        to: A,
        /// The node's own tag for this connect.
        token: u64,
    },
    /// Write bytes on one of its ends. Bytes written on an end that is
    /// closed, or whose peer is gone, are dropped.
    Write {
        /// The end.
        stream: StreamId,
        /// What.
        bytes: Vec<u8>,
    },
    /// Close one of its ends: what it wrote still arrives, then EOF; it
    /// reads nothing more.
    Close {
        /// The end.
        stream: StreamId,
    },
}

/// How much a node is handed per [`Node::handle_stream`] call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reads {
    /// Everything that has arrived, in one piece.
    Whole,
    /// Pieces of this many bytes (the last one shorter): a socket read
    /// with a buffer of this size.
    Chunks(usize),
    /// Pieces of 1 up to this many bytes, chosen at random.
    Random(usize),
}

/// What the network does to stream bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamFaults {
    /// Each write is cut into segments of 1 up to this many bytes (at
    /// random), each with its own delay: a frame arrives in parts, and the
    /// reader sees the first part before the rest exists. `usize::MAX`:
    /// writes travel whole.
    pub max_segment: usize,
    /// Least delay of a segment (and of a connect or EOF).
    pub min_delay: Duration,
    /// Most delay of a segment, in whole milliseconds; a segment never
    /// arrives before one written earlier on the same end.
    pub max_delay: Duration,
    /// How the reader is handed what has arrived.
    pub reads: Reads,
}

impl StreamFaults {
    /// A perfect network: writes travel whole and arrive at once, and the
    /// reader takes everything that has arrived; time stands still while
    /// streams alone run.
    pub fn none() -> Self {
        StreamFaults {
            max_segment: usize::MAX,
            min_delay: Duration::ZERO,
            max_delay: Duration::ZERO,
            reads: Reads::Whole,
        }
    }

    /// Writes cut into segments of up to `max` bytes, each 0 to 3 ms late,
    /// and read in pieces of up to `max` bytes: every frame boundary falls
    /// anywhere in a read, and frames of different connections interleave
    /// in time.
    pub fn rough(max: usize) -> Self {
        StreamFaults {
            max_segment: max.max(1),
            min_delay: Duration::ZERO,
            max_delay: Duration::from_millis(3),
            reads: Reads::Random(max.max(1)),
        }
    }
}

/// The bytes one end wrote, on their way to the other.
#[derive(Default)]
struct Pipe {
    /// Segments not yet read: when each arrives, and its bytes.
    segs: VecDeque<(Instant, Vec<u8>)>,
    /// Bytes of the first segment already read.
    offset: usize,
    /// Bytes not yet read.
    unread: usize,
    /// When the last segment arrives.
    last: Option<Instant>,
    /// The writer closed: EOF arrives then, after the last segment.
    fin: Option<Instant>,
    /// EOF handed over.
    eof_sent: bool,
    /// The bytes wait in the network ([`Net::hold`]).
    held: bool,
}

impl Pipe {
    fn clear(&mut self) {
        self.segs.clear();
        self.offset = 0;
        self.unread = 0;
    }

    /// When what is next to hand over arrives: bytes, else EOF.
    fn next(&self) -> Option<Instant> {
        match self.segs.front() {
            Some((t, _)) => Some(*t),
            None if !self.eof_sent => self.fin,
            None => None,
        }
    }

    /// Whether bytes have arrived by `now`.
    fn arrived(&self, now: Instant) -> bool {
        self.segs.front().is_some_and(|(t, _)| *t <= now)
    }

    /// Takes up to `n` bytes from the front: those arrived by `by`, or any.
    fn take(&mut self, mut n: usize, by: Option<Instant>) -> Vec<u8> {
        let mut out = Vec::new();
        while n > 0 {
            let Some((t, b)) = self.segs.front() else {
                break;
            };
            if by.is_some_and(|by| *t > by) {
                break;
            }
            let k = (b.len() - self.offset).min(n);
            out.extend_from_slice(&b[self.offset..self.offset + k]);
            self.offset += k;
            n -= k;
            if self.offset == b.len() {
                self.segs.pop_front();
                self.offset = 0;
            }
        }
        self.unread -= out.len();
        out
    }
}

/// One end of a link.
struct End {
    /// Its host, or `None` for the test's own ends.
    owner: Option<usize>,
    /// Not closed by its owner (nor reset).
    open: bool,
    /// What arrived at a test's end and was not taken yet.
    inbox: Vec<u8>,
    /// EOF arrived at a test's end.
    eof: bool,
}

impl End {
    fn new(owner: Option<usize>) -> End {
        End {
            owner,
            open: true,
            inbox: Vec::new(),
            eof: false,
        }
    }
}

struct Link {
    ends: [End; 2],
    /// `pipes[s]` carries what end `s` writes.
    pipes: [Pipe; 2],
}

/// A connect on its way.
struct Connecting<A> {
    due: Instant,
    from: usize,
    token: u64,
    to: A,
}

/// Every stream link of a network.
pub(super) struct Links<A> {
    links: Vec<Link>,
    connecting: Vec<Connecting<A>>,
    raw_listen: Vec<A>,
    accepted: Vec<(StreamId, A)>,
}

impl<A> Default for Links<A> {
    fn default() -> Self {
        Links {
            links: Vec::new(),
            connecting: Vec::new(),
            raw_listen: Vec::new(),
            accepted: Vec::new(),
        }
    }
}

impl<A> Links<A> {
    fn end(&self, s: StreamId) -> Option<&End> {
        self.links.get(s.link()).map(|l| &l.ends[s.side()])
    }

    fn end_mut(&mut self, s: StreamId) -> Option<&mut End> {
        self.links.get_mut(s.link()).map(|l| &mut l.ends[s.side()])
    }

    /// The pipe `s` writes into.
    fn pipe(&self, s: StreamId) -> Option<&Pipe> {
        self.links.get(s.link()).map(|l| &l.pipes[s.side()])
    }

    fn pipe_mut(&mut self, s: StreamId) -> Option<&mut Pipe> {
        self.links.get_mut(s.link()).map(|l| &mut l.pipes[s.side()])
    }

    /// A new link from `a` (side 0) to `b` (side 1); its two ends.
    fn open(&mut self, a: Option<usize>, b: Option<usize>) -> (StreamId, StreamId) {
        let k = self.links.len() as u64;
        self.links.push(Link {
            ends: [End::new(a), End::new(b)],
            pipes: [Pipe::default(), Pipe::default()],
        });
        (StreamId(2 * k), StreamId(2 * k + 1))
    }
}

impl<N: Node> Net<N> {
    /// Carries out stream operation `op` of host `i`.
    pub(super) fn apply(&mut self, i: usize, op: StreamOp<N::Addr>) {
        match op {
            StreamOp::Connect { to, token } => {
                let (min, max) = (self.stream_faults.min_delay, self.stream_faults.max_delay);
                let due = self.now + self.delay(min, max);
                self.streams.connecting.push(Connecting {
                    due,
                    from: i,
                    token,
                    to,
                });
            }
            StreamOp::Write { stream, bytes } => {
                if self.streams.end(stream).is_some_and(|e| e.owner == Some(i)) {
                    self.write(stream, &bytes);
                }
            }
            StreamOp::Close { stream } => {
                if self.streams.end(stream).is_some_and(|e| e.owner == Some(i)) {
                    self.close(stream);
                }
            }
        }
    }

    /// Puts `bytes` on the stream as if the owner of end `stream` wrote
    /// them, behind what it wrote before (faults apply): how a test
    /// writes on its own ends, or slips a frame into a node's stream.
    /// Dropped if the end is closed or its peer gone.
    pub fn write(&mut self, stream: StreamId, bytes: &[u8]) {
        let open = |e: Option<&End>| e.is_some_and(|e| e.open);
        if bytes.is_empty()
            || !open(self.streams.end(stream))
            || !open(self.streams.end(stream.peer()))
        {
            return;
        }
        if self.tapping {
            self.stream_tap.push((stream, bytes.to_vec()));
        }
        let f = self.stream_faults;
        let mut rest = bytes;
        while !rest.is_empty() {
            let n = if f.max_segment == usize::MAX {
                rest.len()
            } else {
                (1 + self.rand() as usize % f.max_segment.max(1)).min(rest.len())
            };
            let at = self.now + self.delay(f.min_delay, f.max_delay);
            let Some(p) = self.streams.pipe_mut(stream) else {
                return;
            };
            let at = p.last.map_or(at, |last| at.max(last));
            p.last = Some(at);
            p.segs.push_back((at, rest[..n].to_vec()));
            p.unread += n;
            rest = &rest[n..];
        }
    }

    /// Closes end `stream` as its owner would: what it wrote still
    /// arrives, then EOF; what comes to it is dropped.
    pub fn close(&mut self, stream: StreamId) {
        let Some(e) = self.streams.end_mut(stream) else {
            return;
        };
        if !e.open {
            return;
        }
        e.open = false;
        let (min, max) = (self.stream_faults.min_delay, self.stream_faults.max_delay);
        let at = self.now + self.delay(min, max);
        if let Some(p) = self.streams.pipe_mut(stream) {
            p.fin = Some(p.last.map_or(at, |last| at.max(last)));
        }
        if let Some(p) = self.streams.pipe_mut(stream.peer()) {
            p.clear();
        }
    }

    /// Host `i`'s process dies: it is down, and each of its connections
    /// is reset — what it wrote that was not read yet is lost, and its
    /// peers get EOF.
    pub fn crash(&mut self, i: usize) {
        self.hosts[i].up = false;
        let now = self.now;
        for l in &mut self.streams.links {
            for s in 0..2 {
                if l.ends[s].owner == Some(i) && l.ends[s].open {
                    l.ends[s].open = false;
                    l.pipes[s].clear();
                    l.pipes[s].held = false;
                    l.pipes[s].fin = Some(now);
                    l.pipes[1 - s].clear();
                }
            }
        }
    }

    /// Connects a stream end of the test's own, with address `from`, to
    /// whoever listens at `to` — at once, without delay. `None` if nobody
    /// listens there.
    pub fn connect_raw(&mut self, from: N::Addr, to: &N::Addr) -> Option<StreamId> {
        let host =
            (0..self.hosts.len()).find(|&h| self.hosts[h].up && self.hosts[h].node.listens(to));
        if host.is_none() && !self.streams.raw_listen.contains(to) {
            return None;
        }
        let (mine, theirs) = self.streams.open(None, host);
        self.accept(host, theirs, from);
        Some(mine)
    }

    /// End `theirs` of a new link, from `from`, is accepted by its
    /// listener: host `host`, or the test.
    fn accept(&mut self, host: Option<usize>, theirs: StreamId, from: N::Addr) {
        match host {
            Some(h) => {
                let now = self.now;
                self.hosts[h].node.handle_accept(theirs, from, now);
                self.pump_host(h);
            }
            None => self.streams.accepted.push((theirs, from)),
        }
    }

    /// Connections to `at` (from nodes or [`Net::connect_raw`]) are
    /// accepted by stream ends of the test's own, which
    /// [`Net::take_accepted`] hands out.
    pub fn listen_raw(&mut self, at: N::Addr) {
        self.streams.raw_listen.push(at);
    }

    /// The test's ends accepted since last asked, with the connecting
    /// node's address.
    pub fn take_accepted(&mut self) -> Vec<(StreamId, N::Addr)> {
        std::mem::take(&mut self.streams.accepted)
    }

    /// What arrived at the test's end `stream` since last asked.
    pub fn read(&mut self, stream: StreamId) -> Vec<u8> {
        self.streams
            .end_mut(stream)
            .map(|e| std::mem::take(&mut e.inbox))
            .unwrap_or_default()
    }

    /// Whether EOF arrived at the test's end `stream`.
    pub fn is_eof(&self, stream: StreamId) -> bool {
        self.streams.end(stream).is_some_and(|e| e.eof)
    }

    /// The host that owns end `stream` (`None`: the test's own, or no such end).
    pub fn owner(&self, stream: StreamId) -> Option<usize> {
        self.streams.end(stream).and_then(|e| e.owner)
    }

    /// Holds (or lets go of) the bytes end `stream` writes: while held
    /// they stay in the network, as if its peer did not read them.
    pub fn hold(&mut self, stream: StreamId, held: bool) {
        if let Some(p) = self.streams.pipe_mut(stream) {
            p.held = held;
        }
    }

    /// How many bytes end `stream` wrote that its peer has not read.
    pub fn unread(&self, stream: StreamId) -> usize {
        self.streams.pipe(stream).map_or(0, |p| p.unread)
    }

    /// The bytes end `stream` wrote that its peer has not read.
    pub fn pending(&self, stream: StreamId) -> Vec<u8> {
        let Some(p) = self.streams.pipe(stream) else {
            return Vec::new();
        };
        let mut out = Vec::with_capacity(p.unread);
        for (i, (_, b)) in p.segs.iter().enumerate() {
            out.extend_from_slice(&b[if i == 0 { p.offset } else { 0 }..]);
        }
        out
    }

    /// Hands up to `n` of the bytes end `stream` wrote to its peer now,
    /// as if they had arrived and were not held (in reads as
    /// [`StreamFaults::reads`] says); fewer if the peer stops reading.
    /// How many were handed over.
    pub fn push(&mut self, stream: StreamId, n: usize) -> usize {
        let mut done = 0;
        while done < n && self.unread(stream) > 0 {
            let Some(k) = self.read_size(stream.peer(), true) else {
                break;
            };
            done += self.hand_over(stream, k.min(n - done), None);
        }
        done
    }

    /// How many bytes the reader `to` takes next from its pipe, if it
    /// reads now (`usize::MAX`: all that arrived); `forced` ignores holds.
    fn read_size(&mut self, to: StreamId, forced: bool) -> Option<usize> {
        let from = to.peer();
        let end = self.streams.end(to)?;
        let pipe = self.streams.pipe(from)?;
        if !end.open || (pipe.held && !forced) {
            return None;
        }
        if let Some(h) = end.owner {
            let host = &self.hosts[h];
            if !host.runs() || !host.node.reads_stream(to) {
                return None;
            }
        }
        Some(match self.stream_faults.reads {
            Reads::Whole => usize::MAX,
            Reads::Chunks(k) => k.max(1),
            Reads::Random(k) => 1 + self.rand() as usize % k.max(1),
        })
    }

    /// Takes up to `n` bytes that end `from` wrote (arrived by `by`, or
    /// any) and hands them to its peer; how many.
    fn hand_over(&mut self, from: StreamId, n: usize, by: Option<Instant>) -> usize {
        let to = from.peer();
        let Some(bytes) = self.streams.pipe_mut(from).map(|p| p.take(n, by)) else {
            return 0;
        };
        match self.streams.end_mut(to) {
            Some(End {
                owner: None, inbox, ..
            }) => inbox.extend_from_slice(&bytes),
            Some(End { owner: Some(h), .. }) => {
                let h = *h;
                let now = self.now;
                self.hosts[h].node.handle_stream(to, &bytes, now);
                self.pump_host(h);
            }
            None => {}
        }
        bytes.len()
    }

    /// Hands every pipe's arrived bytes, and EOFs, to readers that read;
    /// drops bytes whose reader is gone. Whether anything moved.
    pub(super) fn deliver_streams(&mut self) -> bool {
        let now = self.now;
        let mut any = false;
        for l in 0..self.streams.links.len() {
            for side in 0..2u64 {
                let from = StreamId(2 * l as u64 + side);
                let to = from.peer();
                if self.streams.end(to).is_some_and(|e| !e.open) {
                    if let Some(p) = self.streams.pipe_mut(from) {
                        any |= p.unread > 0;
                        p.clear();
                    }
                    continue;
                }
                while self.streams.pipe(from).is_some_and(|p| p.arrived(now)) {
                    let Some(n) = self.read_size(to, false) else {
                        break;
                    };
                    any = true;
                    self.hand_over(from, n, Some(now));
                }
                any |= self.deliver_eof(from);
            }
        }
        any
    }

    /// Hands EOF to the peer of `from` if it is due and every byte has
    /// been read.
    fn deliver_eof(&mut self, from: StreamId) -> bool {
        let now = self.now;
        let to = from.peer();
        let Some(p) = self.streams.pipe_mut(from) else {
            return false;
        };
        if p.eof_sent || p.held || p.unread > 0 || p.fin.is_none_or(|t| t > now) {
            return false;
        }
        let owner = self.streams.end(to).and_then(|e| e.owner);
        if let Some(h) = owner {
            if !self.hosts[h].runs() || !self.hosts[h].node.reads_stream(to) {
                return false;
            }
        }
        if let Some(p) = self.streams.pipe_mut(from) {
            p.eof_sent = true;
        }
        match owner {
            None => {
                if let Some(e) = self.streams.end_mut(to) {
                    e.eof = true;
                }
            }
            Some(h) => {
                self.hosts[h].node.handle_eof(to, now);
                self.pump_host(h);
            }
        }
        true
    }

    /// Answers the connects that are due; whether any was.
    pub(super) fn connect_due(&mut self) -> bool {
        let now = self.now;
        let (due, rest): (Vec<_>, Vec<_>) = std::mem::take(&mut self.streams.connecting)
            .into_iter()
            .partition(|c| c.due <= now);
        self.streams.connecting = rest;
        let any = !due.is_empty();
        for c in due {
            let from_addr = self.hosts[c.from].node.address();
            let host = (0..self.hosts.len())
                .find(|&h| self.hosts[h].up && self.hosts[h].node.listens(&c.to));
            let raw = self.streams.raw_listen.contains(&c.to);
            let stream = if host.is_some() || raw {
                let (mine, theirs) = self.streams.open(Some(c.from), host);
                self.accept(host, theirs, from_addr);
                Some(mine)
            } else {
                None
            };
            if self.hosts[c.from].up {
                self.hosts[c.from].node.handle_connect(c.token, stream, now);
                self.pump_host(c.from);
            }
        }
        any
    }

    /// When the next connect, or the next bytes or EOF a reader will take,
    /// is due.
    pub(super) fn next_stream(&self) -> Option<Instant> {
        let connects = self.streams.connecting.iter().map(|c| c.due);
        let pipes = (0..2 * self.streams.links.len() as u64).filter_map(|s| {
            let from = StreamId(s);
            let to = from.peer();
            let p = self.streams.pipe(from)?;
            let end = self.streams.end(to)?;
            if p.held || !end.open {
                return None;
            }
            if let Some(h) = end.owner {
                let host = &self.hosts[h];
                if !host.runs() || !host.node.reads_stream(to) {
                    return None;
                }
            }
            p.next()
        });
        connects.chain(pipes).min()
    }
}

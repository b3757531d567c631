//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use courier_wire::ipc::module::{Connection, Event, ModuleConfig};

/// The bound on every wait.
pub const T: Duration = Duration::from_secs(20);

/// A TCP connection with a read timeout of [`T`].
pub fn tcp(addr: SocketAddr) -> TcpStream {
    let s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(T)).unwrap();
    s.set_nodelay(true).unwrap();
    s
}

/// Reads until EOF (bounded by the socket's read timeout); returns what
/// came before it.
pub fn read_to_eof(s: &mut impl Read) -> Vec<u8> {
    let mut all = Vec::new();
    s.read_to_end(&mut all)
        .expect("EOF within the read timeout");
    all
}

/// A blocking module client on its own socket.
pub struct Client<S: Read + Write> {
    pub conn: Connection,
    pub sock: S,
    buf: Vec<u8>,
}

impl<S: Read + Write> Client<S> {
    pub fn new(sock: S, name: &str) -> Self {
        let mut c = Client {
            conn: Connection::new(ModuleConfig::new(name, "localhost"), Instant::now()),
            sock,
            buf: vec![0; 1 << 16],
        };
        c.until(|e| matches!(e, Event::Connected));
        c
    }

    pub fn flush(&mut self) {
        while let Some(b) = self.conn.poll_transmit() {
            self.sock.write_all(&b).unwrap();
        }
    }

    /// Runs until an event satisfies `f` (returns it).
    pub fn until(&mut self, mut f: impl FnMut(&Event) -> bool) -> Event {
        let deadline = Instant::now() + T;
        loop {
            assert!(Instant::now() < deadline, "timed out");
            let e = self.conn.poll_event();
            self.flush();
            if let Some(e) = e {
                if f(&e) {
                    return e;
                }
                if let Event::Closed(err) = &e {
                    panic!("connection closed: {err:?}");
                }
                continue;
            }
            let n = self.sock.read(&mut self.buf).unwrap();
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
        }
    }

    /// Reads until no operation waits for central.
    pub fn settle(&mut self) {
        self.flush();
        while self.conn.is_waiting() {
            let n = self.sock.read(&mut self.buf).unwrap();
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
            while self.conn.poll_event().is_some() {}
            self.flush();
        }
    }

    /// A round trip through central.
    pub fn sync(&mut self) {
        let op = self.conn.is_module_connected("x").unwrap();
        self.until(|e| matches!(e, Event::ModuleConnected { op: o, .. } if *o == op));
    }
}

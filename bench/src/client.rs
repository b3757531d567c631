//! A blocking IPC module client for the examples: Courier's sans-I/O module
//! state machine (`courier::ipc::module`) on a plain TCP socket.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Instant;

use courier::ipc::module::{Connection, DeliveryKind, Event, ModuleConfig};

/// One module's connection to central.
pub struct Client {
    /// The protocol state machine.
    pub conn: Connection,
    sock: TcpStream,
    buf: Vec<u8>,
    out: Vec<u8>,
}

impl Client {
    /// Connects and completes the IPC handshake.
    pub fn connect(addr: &str, name: &str) -> Client {
        let sock = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect {addr}: {e}"));
        sock.set_nodelay(true).unwrap();
        let conn = Connection::new(ModuleConfig::new(name, "localhost"), Instant::now());
        let mut c = Client {
            conn,
            sock,
            buf: vec![0; 1 << 20],
            out: Vec::new(),
        };
        loop {
            if let Event::Connected = c.next_event() {
                return c;
            }
        }
    }

    #[allow(dead_code)]
    pub fn flush(&mut self) {
        self.out.clear();
        while let Some(b) = self.conn.poll_transmit() {
            self.out.extend_from_slice(&b);
        }
        if !self.out.is_empty() {
            self.sock.write_all(&self.out).expect("write to central");
        }
    }

    #[allow(dead_code)]
    pub fn next_event(&mut self) -> Event {
        loop {
            let e = self.conn.poll_event();
            // Processing may have produced acks or lookups: send them first.
            self.flush();
            if let Some(e) = e {
                return e;
            }
            let n = self.sock.read(&mut self.buf).expect("read from central");
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
        }
    }

    /// Reads until no operation waits for an answer from central (the
    /// first publish of a message looks its id up).
    #[allow(dead_code)]
    pub fn settle(&mut self) {
        self.flush();
        while self.conn.is_waiting() {
            let n = self.sock.read(&mut self.buf).expect("read from central");
            assert!(n > 0, "central closed the connection");
            self.conn.receive(&self.buf[..n], Instant::now());
            while self.conn.poll_event().is_some() {}
            self.flush();
        }
    }

    /// Waits for a user delivery of `msg` (other events are skipped).
    #[allow(dead_code)]
    pub fn delivery(&mut self) -> (u64, DeliveryKind, Vec<u8>) {
        loop {
            if let Event::Delivery {
                delivery,
                kind,
                data,
                ..
            } = self.next_event()
            {
                return (delivery, kind, data);
            }
        }
    }

    #[allow(dead_code)]
    pub fn reply(&mut self) -> Vec<u8> {
        loop {
            if let Event::Reply { data, .. } = self.next_event() {
                return data;
            }
        }
    }

    /// A query to central that is answered only after everything sent
    /// before it was processed.
    #[allow(dead_code)]
    pub fn sync(&mut self) {
        let op = self.conn.is_module_connected("nobody").unwrap();
        loop {
            if let Event::ModuleConnected { op: o, .. } = self.next_event() {
                if o == op {
                    return;
                }
            }
        }
    }

    #[allow(dead_code)]
    pub fn close(mut self) {
        // x_ipc_CloseMsg may need a lookup first: wait for it, then send.
        if self.conn.close().is_ok() {
            self.settle();
        }
        self.flush();
    }
}

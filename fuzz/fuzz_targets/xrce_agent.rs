//! Fuzzes `courier_wire::xrce::Agent`: up to four addresses send it the
//! fuzzer's own messages, CREATE_CLIENTs in both header forms, and the
//! messages of a real client machine (some dropped or corrupted), while
//! its host answers, sends samples large and small, and time passes (in
//! steps of up to 4 minutes: a client that answers nothing for 30 s is
//! taken for silent, its HEARTBEATs slowed, and the host then drops what
//! waits unsent for it, as the bridge does). Nothing may panic and the
//! agent's memory stays bounded.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::xrce::{
    Agent, AgentConfig, AgentEvent, BaseObjectRequest, Client, ClientConfig, ClientKey,
    ClientRepresentation, CreationMode, DeliveryControl, Message, MessageHeader, ObjectId,
    ObjectKind, ObjectVariant, Payload, Representation, StatusCode, StreamId, Submessage,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let t0 = Instant::now();
    let mut now = t0;
    let cfg = AgentConfig { max_clients: 4, ..AgentConfig::default() };
    let mut agent: Agent<u8> = Agent::new(cfg, t0, SystemTime::UNIX_EPOCH);
    let mut client = Client::new(ClientConfig::new(0xAAAA_0001));
    client.connect(t0);
    let mut to_agent: Vec<Vec<u8>> = Vec::new();
    let mut to_client: Vec<Vec<u8>> = Vec::new();
    let mut reads: Vec<(ClientKey, BaseObjectRequest, StreamId)> = Vec::new();
    let mut bytes = data.iter().copied();
    let mut next = || bytes.next().unwrap_or(0);
    for _ in 0..data.len() {
        let op = next();
        let arg = next();
        let from = arg & 3;
        match op % 12 {
            0 => {
                let len = usize::from(next());
                let m: Vec<u8> = (0..len).map(|_| next()).collect();
                let _ = agent.handle_input(from, &m, now);
            }
            1 => {
                // CREATE_CLIENT, key and session chosen by the fuzzer
                let key = ClientKey::from(u32::from(next() % 6));
                let session = if arg & 4 == 0 { 0x81 } else { 0x01 } + (arg >> 6);
                let mut rep = ClientRepresentation::new(key, session, 64 + u16::from(next()) * 4);
                rep.version[0] = 1 + (arg >> 7);
                let m = Message::new(
                    MessageHeader::create_client(session, key),
                    vec![Submessage::new(Payload::CreateClient(rep))],
                );
                if let Ok(m) = m.to_vec() {
                    let _ = agent.handle_input(from, &m, now);
                }
            }
            2 => {
                // the client machine's messages, some lost, one corrupted
                for (i, mut m) in to_agent.drain(..).enumerate() {
                    if (arg >> (i % 8)) & 1 == 1 {
                        continue;
                    }
                    if i == 0 && op & 0x80 != 0 && !m.is_empty() {
                        let at = usize::from(next()) % m.len();
                        m[at] ^= next() | 1;
                    }
                    let _ = agent.handle_input(0, &m, now);
                }
            }
            3 => {
                for m in to_client.drain(..) {
                    let _ = client.handle_input(&m, now);
                }
            }
            4 => {
                let kind = [ObjectKind::Participant, ObjectKind::DataWriter, ObjectKind::DataReader][usize::from(arg % 3)];
                let id = ObjectId::new(1, kind);
                let rep = Representation::Xml(String::new());
                let p = ObjectId::new(1, ObjectKind::Participant);
                let v = match kind {
                    ObjectKind::Participant => ObjectVariant::Participant { representation: rep, domain_id: 0 },
                    ObjectKind::DataWriter => ObjectVariant::DataWriter { representation: rep, publisher_id: p },
                    _ => ObjectVariant::DataReader { representation: rep, subscriber_id: p },
                };
                let _ = client.create(id, v, CreationMode::REPLACE, now);
            }
            5 => {
                let len = usize::from(next()) * usize::from(next() % 100 + 1);
                let s = if arg & 1 == 0 { StreamId::RELIABLE } else { StreamId::BEST_EFFORT };
                let _ = client.write(ObjectId::new(1, ObjectKind::DataWriter), s, &vec![arg; len], now);
            }
            6 => {
                let s = if arg & 1 == 0 { StreamId::RELIABLE } else { StreamId(arg | 1) };
                let dc = DeliveryControl { max_samples: 0xFFFF, ..Default::default() };
                let _ = client.read(ObjectId::new(1, ObjectKind::DataReader), StreamId::RELIABLE, s, Some(dc), now);
            }
            7 => {
                now += if op & 0x80 == 0 {
                    Duration::from_millis(u64::from(arg) * 10)
                } else {
                    Duration::from_secs(u64::from(arg))
                };
                agent.handle_timeout(now);
                client.handle_timeout(now);
            }
            8 => {
                // the host sends a sample to every reader, up to 20 kB
                // (from a silent client's reader, what waits unsent goes
                // instead, once)
                let len = usize::from(arg) * 80;
                for (c, r, s) in &reads {
                    if op & 0x80 != 0 && agent.client_silent(*c, now) {
                        agent.drop_unsent(*c);
                        assert_eq!(agent.drop_unsent(*c), 0, "unsent messages left after drop_unsent");
                        continue;
                    }
                    let _ = agent.send_data(*c, *r, *s, &vec![op; len], now);
                }
            }
            9 => client.ping(now),
            10 => client.connect(now),
            _ => {
                let code = if arg & 1 == 0 { StatusCode::OK } else { StatusCode(arg) };
                while let Some(e) = agent.poll_event() {
                    match e {
                        AgentEvent::Create { client, request, reply_stream, .. }
                        | AgentEvent::Delete { client, request, reply_stream } => {
                            let _ = agent.reply_status(client, request, code, reply_stream, now);
                        }
                        AgentEvent::Read { client, read } if reads.len() < 8 => {
                            reads.push((client, read.request, read.preferred_stream_id));
                        }
                        AgentEvent::ClientDeleted { client } => reads.retain(|r| r.0 != client),
                        _ => {}
                    }
                }
            }
        }
        while let Some((to, m)) = agent.poll_transmit() {
            if to == 0 && to_client.len() < 256 {
                to_client.push(m);
            }
        }
        while let Some(m) = client.poll_transmit() {
            if to_agent.len() < 256 {
                to_agent.push(m);
            }
        }
        while client.poll_event().is_some() {}
        assert!(agent.buffered_bytes() < 32 << 20, "agent holds {} bytes", agent.buffered_bytes());
    }
});

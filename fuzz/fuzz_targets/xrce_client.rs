//! Fuzzes `courier_wire::xrce::Client`: the fuzzer's bytes are a script of
//! commands (create, delete, write, read, request, reply, ping, time sync,
//! reconnect, recreate, disconnect), passing time, messages of its own
//! and messages of a real agent machine, some of them dropped or
//! corrupted. Nothing may panic and the client's memory stays bounded.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::xrce::{
    Agent, AgentConfig, AgentEvent, Client, ClientConfig, CreationMode, DeliveryControl,
    ObjectId, ObjectKind, ObjectVariant, Representation, SampleIdentity, StatusCode, StreamId,
};
use libfuzzer_sys::fuzz_target;

const KINDS: [ObjectKind; 8] = [
    ObjectKind::Participant,
    ObjectKind::Topic,
    ObjectKind::Publisher,
    ObjectKind::Subscriber,
    ObjectKind::DataWriter,
    ObjectKind::DataReader,
    ObjectKind::Requester,
    ObjectKind::Replier,
];

fn variant(kind: ObjectKind, b: u8) -> ObjectVariant {
    let rep = match b % 3 {
        0 => Representation::Xml("<dds/>".into()),
        1 => Representation::Reference("ref".into()),
        _ => Representation::Binary(vec![0, 0]),
    };
    let parent = ObjectId::new(1, ObjectKind::Participant);
    match kind {
        ObjectKind::Participant => ObjectVariant::Participant { representation: rep, domain_id: 0 },
        ObjectKind::Topic => ObjectVariant::Topic { representation: rep, participant_id: parent },
        ObjectKind::Publisher => ObjectVariant::Publisher { representation: rep, participant_id: parent },
        ObjectKind::Subscriber => ObjectVariant::Subscriber { representation: rep, participant_id: parent },
        ObjectKind::DataWriter => ObjectVariant::DataWriter { representation: rep, publisher_id: parent },
        ObjectKind::DataReader => ObjectVariant::DataReader { representation: rep, subscriber_id: parent },
        ObjectKind::Requester => ObjectVariant::Requester { representation: rep, participant_id: parent },
        _ => ObjectVariant::Replier { representation: rep, participant_id: parent },
    }
}

fuzz_target!(|data: &[u8]| {
    let t0 = Instant::now();
    let mut now = t0;
    let mut cfg = ClientConfig::new(0xCCCC_DDDD);
    cfg.streams.max_backlog = 16 * 1024;
    cfg.streams.max_reassembly = 16 * 1024;
    if data.first().is_some_and(|b| b & 1 == 1) {
        cfg.session_id = 0x01;
    }
    let mut c = Client::new(cfg);
    let mut agent: Agent<u8> = Agent::new(AgentConfig::default(), t0, SystemTime::UNIX_EPOCH);
    let mut to_agent: Vec<Vec<u8>> = Vec::new();
    let mut to_client: Vec<Vec<u8>> = Vec::new();
    let mut bytes = data.iter().copied();
    let mut next = || bytes.next().unwrap_or(0);
    for _ in 0..data.len() {
        let op = next();
        let arg = next();
        let stream = if arg & 0x80 != 0 { StreamId::RELIABLE } else { StreamId::BEST_EFFORT };
        let object = ObjectId::new(u16::from(arg & 3), KINDS[usize::from(arg >> 2) % 8]);
        match op % 16 {
            0 => c.connect(now),
            1 => {
                let _ = c.create(object, variant(object.kind().unwrap_or(ObjectKind::Topic), arg), CreationMode::from_flags(arg), now);
            }
            2 => {
                let _ = c.delete(object, now);
            }
            3 => {
                let len = usize::from(next()) * usize::from(next() % 80 + 1);
                let _ = c.write(object, stream, &vec![arg; len], now);
            }
            4 => {
                let dc = DeliveryControl { max_samples: u16::from(arg), ..Default::default() };
                let _ = c.read(object, StreamId::RELIABLE, stream, (arg & 1 == 1).then_some(dc), now);
            }
            5 => {
                let _ = c.request(object, stream, &[arg; 8], now);
                let _ = c.reply(object, stream, &SampleIdentity::default(), &[arg; 8], now);
            }
            6 => c.ping(now),
            7 => {
                let _ = c.sync_time(now, SystemTime::UNIX_EPOCH + Duration::from_secs(u64::from(arg)));
            }
            8 => {
                let _ = c.recreate_objects(now);
            }
            9 => {
                let _ = c.disconnect(now);
            }
            10 => {
                now += Duration::from_millis(u64::from(arg) * 10);
                c.handle_timeout(now);
                agent.handle_timeout(now);
            }
            11 => {
                // a message of the fuzzer's own
                let len = usize::from(arg);
                let m: Vec<u8> = (0..len).map(|_| next()).collect();
                let _ = c.handle_input(&m, now);
            }
            12 => {
                // the agent's messages, one of them corrupted
                for (i, mut m) in to_client.drain(..).enumerate() {
                    if i == usize::from(arg % 8) && !m.is_empty() {
                        let at = usize::from(next()) % m.len();
                        m[at] ^= next() | 1;
                    }
                    let _ = c.handle_input(&m, now);
                }
            }
            13 => {
                // the client's messages to the agent, some lost
                for (i, m) in to_agent.drain(..).enumerate() {
                    if (arg >> (i % 8)) & 1 == 0 {
                        let _ = agent.handle_input(0, &m, now);
                    }
                }
            }
            14 => to_client.retain(|_| next() & 1 == 0),
            _ => {
                // the agent's host says yes, or no, to everything
                let code = if arg & 1 == 0 { StatusCode::OK } else { StatusCode(arg) };
                while let Some(e) = agent.poll_event() {
                    match e {
                        AgentEvent::Create { client, request, reply_stream, .. }
                        | AgentEvent::Delete { client, request, reply_stream } => {
                            let _ = agent.reply_status(client, request, code, reply_stream, now);
                        }
                        AgentEvent::Read { client, read } => {
                            let _ = agent.send_data(client, read.request, read.preferred_stream_id, &[arg; 40], now);
                        }
                        _ => {}
                    }
                }
            }
        }
        while let Some(m) = c.poll_transmit() {
            if to_agent.len() < 256 {
                to_agent.push(m);
            }
        }
        while let Some((_, m)) = agent.poll_transmit() {
            if to_client.len() < 256 {
                to_client.push(m);
            }
        }
        while c.poll_event().is_some() {}
        assert!(c.buffered_bytes() < 1 << 20, "client holds {} bytes", c.buffered_bytes());
    }
});

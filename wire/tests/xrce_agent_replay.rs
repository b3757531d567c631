//! Replay for the agent half: the agent machine is fed the eProsima
//! clients' captured messages at the captured times, with a host that
//! answers every CREATE and DELETE with OK and relays every sample written
//! to every reader; what it sends each client must be what eProsima's
//! agent sent, message for message.
//!
//! Compared: every message but ACKNACK and HEARTBEAT, in order, byte for
//! byte (STATUS_AGENT, STATUS on the reliable stream and on stream 0, DATA,
//! FRAGMENT cuts, INFO). Not compared: ACKNACKs and HEARTBEATs, whose number
//! and moment depend on the eProsima agent's threads and on how long Fast
//! DDS took to create an entity (it answers a HEARTBEAT that arrived after
//! a message before that message, and heartbeats while a CREATE blocks it
//! for 340 ms) — their rules are tested in `xrce_streams.rs`.

use std::collections::BTreeMap;
use std::time::{Duration, Instant, SystemTime};

use courier_wire::xrce::{
    Agent, AgentConfig, AgentEvent, BaseObjectRequest, ClientKey, StatusCode, StreamId,
};

mod xrce_captures;
use xrce_captures::{hex, is_stream_control, records};

#[derive(Default)]
struct Host {
    reads: Vec<(ClientKey, BaseObjectRequest, StreamId)>,
}

impl Host {
    fn serve(&mut self, a: &mut Agent<u16>, now: Instant) {
        while let Some(e) = a.poll_event() {
            match e {
                AgentEvent::Create {
                    client,
                    request,
                    reply_stream,
                    ..
                }
                | AgentEvent::Delete {
                    client,
                    request,
                    reply_stream,
                } => a
                    .reply_status(client, request, StatusCode::OK, reply_stream, now)
                    .unwrap(),
                AgentEvent::Read { client, read } => {
                    self.reads
                        .push((client, read.request, read.preferred_stream_id))
                }
                AgentEvent::Write { data, .. } => {
                    for (c, r, s) in &self.reads {
                        a.send_data(*c, *r, *s, &data, now).unwrap();
                    }
                }
                AgentEvent::ClientDeleted { client } => self.reads.retain(|r| r.0 != client),
                _ => {}
            }
        }
    }
}

/// Replays `capture`; returns how many messages were compared per port.
fn replay(capture: &str) -> BTreeMap<u16, usize> {
    let recs = records(capture);
    let t0 = Instant::now();
    let mut a: Agent<u16> = Agent::new(AgentConfig::default(), t0, SystemTime::UNIX_EPOCH);
    let mut host = Host::default();
    let mut got: BTreeMap<u16, Vec<Vec<u8>>> = BTreeMap::new();
    let mut drain = |a: &mut Agent<u16>, host: &mut Host, now| loop {
        host.serve(a, now);
        let mut any = false;
        while let Some((to, m)) = a.poll_transmit() {
            any = true;
            if !is_stream_control(&m) {
                got.entry(to).or_default().push(m);
            }
        }
        if !any {
            break;
        }
    };
    for r in recs.iter().filter(|r| r.c2a) {
        let now = t0 + Duration::from_secs_f64(r.t);
        if a.poll_timeout().is_some_and(|d| d <= now) {
            a.handle_timeout(now);
        }
        a.handle_input(r.port, &r.bytes, now)
            .unwrap_or_else(|e| panic!("{capture} #{}: {e}", r.n));
        drain(&mut a, &mut host, now);
    }
    let mut compared = BTreeMap::new();
    for port in recs
        .iter()
        .map(|r| r.port)
        .collect::<std::collections::BTreeSet<_>>()
    {
        let want: Vec<(u32, &Vec<u8>)> = recs
            .iter()
            .filter(|r| !r.c2a && r.port == port && !is_stream_control(&r.bytes))
            .map(|r| (r.n, &r.bytes))
            .collect();
        let ours = got.remove(&port).unwrap_or_default();
        for (i, (n, w)) in want.iter().enumerate() {
            let g = ours
                .get(i)
                .unwrap_or_else(|| panic!("{capture} #{n}: the agent sent nothing"));
            assert_eq!(hex(g), hex(w), "{capture} #{n} (port {port})");
        }
        assert_eq!(
            ours.len(),
            want.len(),
            "{capture} port {port}: extra messages"
        );
        compared.insert(port, want.len());
    }
    compared
}

#[test]
fn xml_reliable_pubsub_through_the_agent_machine() {
    let c = replay("udp_xml_reliable_pubsub");
    // sub: STATUS_AGENT, 4 STATUS, 3 DATA, STATUS(delete); pub: STATUS_AGENT, 4 STATUS, STATUS(delete)
    assert_eq!(c.into_values().collect::<Vec<_>>(), [6, 9]);
}

#[test]
fn binary_entities_through_the_agent_machine() {
    let c = replay("udp_binary_entities");
    assert_eq!(c.into_values().collect::<Vec<_>>(), [11]);
}

#[test]
fn fragmented_1200_byte_samples_through_the_agent_machine() {
    // the subscriber gets both samples cut 500/500/208 exactly as captured
    let c = replay("udp_fragmentation_large_sample");
    assert_eq!(c.into_values().collect::<Vec<_>>(), [6, 12]);
}

#[test]
fn pings_through_the_agent_machine() {
    let c = replay("udp_ping");
    assert_eq!(c.into_values().collect::<Vec<_>>(), [3]);
}

#[test]
fn client_key_sessions_through_the_agent_machine() {
    let c = replay("udp_session_with_client_key_binary");
    assert_eq!(c.into_values().collect::<Vec<_>>(), [9, 6]);
}

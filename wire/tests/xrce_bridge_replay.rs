//! Replay through the whole agent host: the [`Bridge`] (agent machine +
//! one DDS Domain, entities made for real) is fed the eProsima clients'
//! captured messages at the captured times; what it sends each client must
//! be what eProsima's agent (with Fast DDS behind it) sent, message for
//! message: STATUS_AGENT, the STATUS of every CREATE and DELETE as the
//! entities really came out, DATA that went through DDS (a writer and a
//! reader of the same Domain match in process), FRAGMENT cuts, INFO.
//!
//! Not compared, as in `xrce_agent_replay.rs`: ACKNACK and HEARTBEAT.
//! Two documented differences:
//! - request/reply: the replier sees each request's sample identity, the
//!   request writer's GUID and sequence number in *this* Domain instead of
//!   Fast DDS's; those 24 bytes are compared masked, and the replier's
//!   captured replies, which echo Fast DDS's identity, are fed back with
//!   the bridge's (as the real replier would have echoed it);
//! - best effort: eProsima's agent lost the first sample while Fast DDS
//!   discovery ran (`protocols/xrce.md` §14); the bridge's writer and reader
//!   share one long-lived Domain, so it delivers that sample too.

use std::collections::BTreeMap;
use std::time::{Duration, Instant, SystemTime};

use courier_wire::dds::Domain;
use courier_wire::rtps::participant::{guid_prefix, Config};
use courier_wire::xrce::bridge::{Bridge, BridgeConfig, BridgeEvent};
use courier_wire::xrce::{Message, Payload};

mod xrce_captures;
use xrce_captures::{hex, is_stream_control, records};

/// Replays `capture`; returns how many messages were compared per port.
/// `mask` blanks bytes of DATA payloads that legitimately differ.
fn replay(capture: &str, mask: impl Fn(&mut [u8])) -> BTreeMap<u16, usize> {
    replay_with(capture, mask, false)
}

fn is_data(m: &[u8]) -> bool {
    Message::decode(m).is_ok_and(|m| {
        matches!(
            m.submessages.first().map(|s| &s.payload),
            Some(Payload::Data(_))
        )
    })
}

/// `lenient`: a client may get samples eProsima's agent lost at the start
/// (the first DATA of a port beyond the captured count are dropped before
/// comparing, and messages' sequence numbers are not compared).
fn replay_with(capture: &str, mask: impl Fn(&mut [u8]), lenient: bool) -> BTreeMap<u16, usize> {
    let recs = records(capture);
    let t0 = Instant::now();
    let cfg = Config::udpv4(0, 0, guid_prefix([7; 10]), [127, 0, 0, 1]).unwrap();
    let domain = Domain::new(cfg, t0, SystemTime::UNIX_EPOCH);
    let mut b: Bridge<u16> =
        Bridge::new(BridgeConfig::default(), domain, t0, SystemTime::UNIX_EPOCH);
    let mut got: BTreeMap<u16, Vec<Vec<u8>>> = BTreeMap::new();
    // captured replier DATA in order per port, to pair with ours
    let mut theirs: BTreeMap<u16, Vec<Vec<u8>>> = BTreeMap::new();
    for r in recs
        .iter()
        .filter(|r| !r.c2a && !is_stream_control(&r.bytes))
    {
        theirs.entry(r.port).or_default().push(r.bytes.clone());
    }
    let mut identities: Vec<([u8; 24], [u8; 24])> = Vec::new();
    let mut drain = |b: &mut Bridge<u16>, identities: &mut Vec<([u8; 24], [u8; 24])>| {
        while let Some((to, m)) = b.poll_transmit() {
            if !is_stream_control(&m) {
                let list = got.entry(to).or_default();
                let i = list.len();
                if let (Some(ours), Some(cap)) = (
                    replier_identity(&m),
                    theirs
                        .get(&to)
                        .and_then(|t| t.get(i))
                        .and_then(|c| replier_identity(c)),
                ) {
                    identities.push((cap, ours));
                }
                list.push(m);
            }
        }
        while b.poll_datagram().is_some() {}
        while let Some(e) = b.poll_event() {
            if let BridgeEvent::Created {
                reason: Some(r), ..
            } = e
            {
                panic!("{capture}: {r}");
            }
        }
    };
    for r in recs.iter().filter(|r| r.c2a) {
        let now = t0 + Duration::from_secs_f64(r.t);
        while let Some(t) = b.poll_timeout().filter(|t| *t <= now) {
            b.handle_timeout(t);
            drain(&mut b, &mut identities);
        }
        let mut bytes = r.bytes.clone();
        for (cap, ours) in &identities {
            if let Some(at) = bytes.windows(24).position(|w| w == cap) {
                bytes[at..at + 24].copy_from_slice(ours);
            }
        }
        b.handle_input(r.port, &bytes, now)
            .unwrap_or_else(|e| panic!("{capture} #{}: {e}", r.n));
        drain(&mut b, &mut identities);
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
        let mut ours = got.remove(&port).unwrap_or_default();
        if lenient {
            let theirs_data = want.iter().filter(|w| is_data(w.1)).count();
            let mut extra = ours
                .iter()
                .filter(|m| is_data(m))
                .count()
                .saturating_sub(theirs_data);
            ours.retain(|m| {
                if extra > 0 && is_data(m) {
                    extra -= 1;
                    false
                } else {
                    true
                }
            });
        }
        for (i, (n, w)) in want.iter().enumerate() {
            let mut g = ours
                .get(i)
                .unwrap_or_else(|| panic!("{capture} #{n}: the agent sent nothing"))
                .clone();
            let mut w = (*w).clone();
            mask(&mut g);
            mask(&mut w);
            if lenient {
                g[2..4].fill(0);
                w[2..4].fill(0);
            }
            assert_eq!(hex(&g), hex(&w), "{capture} #{n} (port {port})");
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

fn same(_: &mut [u8]) {}

#[test]
fn xml_reliable_pubsub_through_the_bridge() {
    let c = replay("udp_xml_reliable_pubsub", same);
    assert_eq!(c.into_values().collect::<Vec<_>>(), [6, 9]);
}

#[test]
fn xml_best_effort_pubsub_through_the_bridge() {
    // sample 1, which eProsima's agent lost, comes first; the rest as captured
    let c = replay_with("udp_xml_besteffort_pubsub", same, true);
    assert!(c.values().all(|n| *n > 0), "{c:?}");
}

#[test]
fn binary_entities_through_the_bridge() {
    let c = replay("udp_binary_entities", same);
    assert_eq!(c.into_values().collect::<Vec<_>>(), [11]);
}

#[test]
fn fragmented_1200_byte_samples_through_the_bridge() {
    let c = replay("udp_fragmentation_large_sample", same);
    assert_eq!(c.into_values().collect::<Vec<_>>(), [6, 12]);
}

#[test]
fn pings_through_the_bridge() {
    let c = replay("udp_ping", same);
    assert_eq!(c.into_values().collect::<Vec<_>>(), [3]);
}

#[test]
fn client_key_sessions_through_the_bridge() {
    let c = replay("udp_session_with_client_key_binary", same);
    assert_eq!(c.into_values().collect::<Vec<_>>(), [9, 6]);
}

/// Where the sample identity in front of a replier's DATA starts.
fn identity_at(m: &[u8]) -> Option<usize> {
    let msg = Message::decode(m).ok()?;
    let header = if msg.header.client_key.is_some() {
        8
    } else {
        4
    };
    match msg.submessages.first().map(|s| &s.payload) {
        Some(Payload::Data(d)) if d.request.object_id.kind_bits() == 0x8 => {
            (m.len() >= header + 8 + 24).then_some(header + 8)
        }
        _ => None,
    }
}

fn replier_identity(m: &[u8]) -> Option<[u8; 24]> {
    let at = identity_at(m)?;
    m[at..at + 24].try_into().ok()
}

/// Blanks the sample identity in front of a replier's DATA, and the
/// request id in front of a requester's (the replay answers the first
/// request, which eProsima's agent lost, with the captured answer to the
/// second: the ids are one apart).
fn identity_guid(m: &mut [u8]) {
    if let Some(at) = identity_at(m) {
        m[at..at + 24].fill(0);
    }
    let Ok(msg) = Message::decode(m) else { return };
    let header = if msg.header.client_key.is_some() {
        8
    } else {
        4
    };
    if let Some(Payload::Data(d)) = msg.submessages.first().map(|s| &s.payload) {
        if d.request.object_id.kind_bits() == 0x7 && m.len() >= header + 10 {
            m[header + 8..header + 10].fill(0);
        }
    }
}

#[test]
fn request_reply_through_the_bridge() {
    // the first request, which eProsima's agent lost, is answered too
    let c = replay_with("udp_request_reply", identity_guid, true);
    assert!(c.values().all(|n| *n > 0), "{c:?}");
}

//! XRCE stream rules one by one: serial sequence numbers and wraparound,
//! windows, the ACKNACK bitmap, what is resent, HEARTBEAT timing, and
//! where fragments are cut (checked against the captures).

use std::time::{Duration, Instant};

use courier_wire::xrce::stream::{
    BestEffortInput, BestEffortOutput, Received, ReliableInput, ReliableOutput,
};
use courier_wire::xrce::{
    AckNack, BaseObjectRequest, Data, Heartbeat, Message, MessageHeader, ObjectId, Payload, SeqNum,
    StreamConfig, StreamId, Submessage,
};

const R: StreamId = StreamId::RELIABLE;

fn session() -> MessageHeader {
    MessageHeader::new(0x81, StreamId::NONE, 0)
}

fn write(n: u32, len: usize) -> Vec<u8> {
    let mut data = n.to_le_bytes().to_vec();
    data.resize(len.max(4), 0xAB);
    let s = Submessage::new(Payload::WriteData(Data {
        request: BaseObjectRequest::new(10, ObjectId(0x0015)),
        data,
    }));
    let mut v = Vec::new();
    s.encode(&mut v, 0).unwrap();
    v.resize((v.len() + 3) & !3, 0);
    v
}

fn ack(first: u16, bits: u16) -> AckNack {
    let mut a = AckNack {
        first_unacked: first,
        nack_bitmap: [0; 2],
        stream_id: R,
    };
    a.set_nack_bits(bits);
    a
}

fn seq_of(m: &[u8]) -> u16 {
    u16::from_le_bytes([m[2], m[3]])
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 32) as u32
    }
}

#[test]
fn sequence_numbers_compare_serially_and_wrap() {
    let s = SeqNum;
    assert!(s(1).is_after(s(0)));
    assert!(s(0).is_after(s(0xFFFF)));
    assert!(!s(0xFFFF).is_after(s(0)));
    assert!(s(0x7FFF).is_after(s(0)));
    // exactly 2^15 apart, each is "after" the other (uxr_seq_num_cmp)
    assert!(s(0x8000).is_after(s(0)) && s(0).is_after(s(0x8000)));
    assert!(!s(0x8001).is_after(s(0)));
    assert!(s(0).is_after(s(0x8001)));
    assert_eq!(s(0xFFFF).wrapping_add(2), s(1));
    assert_eq!(s(1).wrapping_sub(2), s(0xFFFF));
    assert_eq!(s(3).since(s(0xFFFE)), 5);
    assert_eq!(SeqNum::INITIAL_LAST.wrapping_add(1), s(0));
}

/// Sends `n` messages through a lossy, reordering link (both ways) and
/// returns what came out of the input stream.
fn lossy_loop(n: u32, cfg: StreamConfig, seed: u64) -> Vec<u32> {
    let mut rng = Rng(seed | 1);
    let t0 = Instant::now();
    let mut out = ReliableOutput::new(&session(), R, cfg);
    let mut input = ReliableInput::new(R, cfg);
    let mut next = 0;
    let mut got = Vec::new();
    let mut in_flight: Vec<(u32, Vec<u8>)> = Vec::new();
    let mut acks: Vec<(u32, AckNack)> = Vec::new();
    let mut t = 0u32;
    while got.len() < n as usize {
        t += 1;
        assert!(t < 50 * n + 10_000, "stuck at {} of {n}", got.len());
        let now = t0 + Duration::from_millis(u64::from(t));
        while next < n && out.push(write(next, 8), Some(next as u16)).is_ok() {
            next += 1;
            if next % 7 == 0 {
                break;
            }
        }
        while let Some(m) = out.poll_transmit(now) {
            if rng.next() % 100 >= 30 {
                in_flight.push((t + 1 + rng.next() % 20, m));
            }
        }
        if let Some(hb) = out.poll_heartbeat(now) {
            input.on_heartbeat(&hb);
            if rng.next() % 100 >= 30 {
                acks.push((t + 1 + rng.next() % 20, input.acknack()));
            }
        }
        let (due, later): (Vec<_>, Vec<_>) = in_flight.drain(..).partition(|(at, _)| *at <= t);
        in_flight = later;
        for (_, m) in due {
            let msg = Message::decode(&m).unwrap();
            let seq = SeqNum(msg.header.sequence_nr);
            input.receive(seq, msg, m.len());
            while let Some(msg) = input.next_message() {
                let mut errs = Vec::new();
                for s in input.unpack(msg, &mut errs) {
                    let Payload::WriteData(d) = s.payload else {
                        panic!()
                    };
                    got.push(u32::from_le_bytes(d.data[..4].try_into().unwrap()));
                }
                assert!(errs.is_empty(), "{errs:?}");
            }
            if rng.next() % 100 >= 30 {
                acks.push((t + 1 + rng.next() % 20, input.acknack()));
            }
        }
        let (due, later): (Vec<_>, Vec<_>) = acks.drain(..).partition(|(at, _)| *at <= t);
        acks = later;
        for (_, a) in due {
            out.on_acknack(&a, now);
        }
        assert!(out.buffered() <= 16 * cfg.mtu + cfg.max_backlog);
    }
    got
}

#[test]
fn reliable_streams_deliver_in_order_through_loss_and_sequence_wraparound() {
    let mut cfg = StreamConfig::client();
    cfg.max_backlog = 4096;
    let n = 70_000; // past 65 535: sequence numbers wrap
    let got = lossy_loop(n, cfg, 7);
    assert!(got.iter().copied().eq(0..n), "out of order or incomplete");
    // the agent's rules (one submessage per message, exact resends)
    let got = lossy_loop(
        5_000,
        StreamConfig {
            max_backlog: 4096,
            ..StreamConfig::agent()
        },
        9,
    );
    assert!(got.iter().copied().eq(0..5_000));
}

#[test]
fn the_window_holds_at_most_depth_unacknowledged_messages() {
    let now = Instant::now();
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::agent());
    for i in 0..40 {
        out.push(write(i, 8), None).unwrap();
    }
    let sent: Vec<u16> = std::iter::from_fn(|| out.poll_transmit(now))
        .map(|m| seq_of(&m))
        .collect();
    assert_eq!(sent, (0..16).collect::<Vec<_>>());
    out.on_acknack(&ack(5, 0), now);
    let sent: Vec<u16> = std::iter::from_fn(|| out.poll_transmit(now))
        .map(|m| seq_of(&m))
        .collect();
    assert_eq!(sent, (16..21).collect::<Vec<_>>());
    // an ACKNACK of what was never sent is ignored
    out.on_acknack(&ack(30, 0), now);
    assert_eq!(out.last_acked(), SeqNum(4));
}

#[test]
fn acknack_bitmaps_are_laid_out_as_the_captures_show() {
    let cfg = StreamConfig::client();
    let m = |seq: u16| {
        let b = Message::new(MessageHeader::new(0x81, R, seq), vec![])
            .to_vec()
            .unwrap();
        (Message::decode(&b).unwrap(), b.len())
    };
    let mut input = ReliableInput::new(R, cfg);
    for s in [0, 1] {
        let (msg, len) = m(s);
        assert_eq!(input.receive(SeqNum(s), msg, len), Received::Accepted);
        input.next_message().unwrap();
    }
    // udp_reliable_loss_recovery #35: HEARTBEAT 2..2 with 2 lost
    input.on_heartbeat(&Heartbeat {
        first_unacked: 2,
        last_unacked: 2,
        stream_id: R,
    });
    let a = input.acknack();
    assert_eq!((a.first_unacked, a.nack_bitmap), (2, [0x00, 0x01]));
    // 3, 4 and 12 arrive, 2 and 5..=11 are missing: bit i <-> 2 + i
    for s in [3, 4, 12] {
        let (msg, len) = m(s);
        input.receive(SeqNum(s), msg, len);
    }
    let a = input.acknack();
    assert_eq!(a.nack_bits(), 0b0011_1111_1001);
    assert_eq!(a.nack_bitmap, [0x03, 0xF9], "high byte first");
    // duplicates and messages beyond the window
    let (msg, len) = m(3);
    assert_eq!(input.receive(SeqNum(3), msg, len), Received::Duplicate);
    let (msg, len) = m(1);
    assert_eq!(input.receive(SeqNum(1), msg, len), Received::Duplicate);
    let (msg, len) = m(18);
    assert_eq!(input.receive(SeqNum(18), msg, len), Received::OutOfWindow);
    // a HEARTBEAT from a sender that no longer holds 2..=4 moves the window
    input.on_heartbeat(&Heartbeat {
        first_unacked: 5,
        last_unacked: 12,
        stream_id: R,
    });
    let a = input.acknack();
    assert_eq!((a.first_unacked, a.nack_bits()), (5, 0b0111_1111));
}

#[test]
fn the_client_resends_everything_unacked_the_agent_exactly_what_is_nacked() {
    let now = Instant::now();
    for (cfg, want) in [
        (StreamConfig::client(), vec![2, 3, 4, 5]),
        (StreamConfig::agent(), vec![2, 4]),
    ] {
        let mut out = ReliableOutput::new(&session(), R, StreamConfig { pack: false, ..cfg });
        for i in 0..6 {
            out.push(write(i, 8), None).unwrap();
        }
        while out.poll_transmit(now).is_some() {}
        out.on_acknack(&ack(2, 0b101), now);
        let again: Vec<u16> = std::iter::from_fn(|| out.poll_transmit(now))
            .map(|m| seq_of(&m))
            .collect();
        assert_eq!(again, want);
    }
}

#[test]
fn heartbeats_every_period_while_unacked_and_the_client_slides_them() {
    let t0 = Instant::now();
    let ms = |n| t0 + Duration::from_millis(n);
    // the agent: every 200 ms after the first send, whatever arrives
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::agent());
    out.push(write(0, 8), None).unwrap();
    out.poll_transmit(t0).unwrap();
    out.touch(ms(150));
    assert_eq!(out.poll_timeout(), Some(ms(200)));
    assert!(out.poll_heartbeat(ms(199)).is_none());
    let hb = out.poll_heartbeat(ms(200)).unwrap();
    assert_eq!((hb.first_unacked, hb.last_unacked), (0, 0));
    assert_eq!(out.poll_timeout(), Some(ms(400)));
    out.on_acknack(&ack(1, 0), ms(250));
    assert_eq!(out.poll_timeout(), None, "nothing unacked: no heartbeat");
    // the client: 100 ms after the last thing heard, at most 200 ms after the last heartbeat
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::client());
    out.push(write(0, 8), None).unwrap();
    out.poll_transmit(t0).unwrap();
    out.touch(ms(50));
    assert_eq!(out.poll_timeout(), Some(ms(150)));
    out.touch(ms(120));
    out.touch(ms(190));
    assert_eq!(out.poll_timeout(), Some(ms(200)), "capped at two periods");
    assert!(out.poll_heartbeat(ms(200)).is_some());
    // an ACKNACK re-arms it
    out.on_acknack(&ack(0, 0), ms(230));
    assert_eq!(out.poll_timeout(), Some(ms(330)));
}

/// A client that acknowledges nothing for 30 s while messages wait (one
/// that died without DELETE) gets a HEARTBEAT every 5 s from the agent,
/// not every 200 ms (audit 17: a thousand dead clients kept an agent at
/// 10 % CPU); any ACKNACK brings the period back. The client's streams
/// keep their period.
#[test]
fn a_silent_peer_gets_heartbeats_ever_less_often_until_it_answers() {
    let t0 = Instant::now();
    let s = |n: u64| t0 + Duration::from_secs(n);
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::agent());
    out.push(write(0, 8), None).unwrap();
    out.poll_transmit(t0).unwrap();
    // every 200 ms for the first 30 s
    let mut beats = Vec::new();
    let mut now = t0;
    while now < s(60) {
        now = out.poll_timeout().unwrap();
        assert!(out.poll_heartbeat(now).is_some());
        beats.push(now);
    }
    let before = beats.iter().filter(|t| **t < s(30)).count();
    let after = beats.iter().filter(|t| **t >= s(30)).count();
    assert_eq!(before, 149, "every 200 ms while it may just be slow");
    assert!(
        (5..=7).contains(&after),
        "{after} heartbeats in the last 30 s"
    );
    assert!(beats
        .windows(2)
        .filter(|w| w[0] >= s(31))
        .all(|w| w[1] - w[0] == Duration::from_secs(5)));
    // it answers (acknowledging nothing new): the period is back
    let t = now + Duration::from_millis(10);
    out.on_acknack(&ack(0, 0), t);
    assert_eq!(out.poll_timeout(), Some(t + Duration::from_millis(200)));

    // everything acknowledged, then a minute of quiet with nothing to
    // send: a new message is not taken for a silent peer
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::agent());
    out.push(write(0, 8), None).unwrap();
    out.poll_transmit(t0).unwrap();
    out.on_acknack(&ack(1, 0), s(1));
    // (one acknowledging what was never sent, ignored)
    out.on_acknack(&ack(9, 0), s(2));
    out.push(write(1, 8), None).unwrap();
    out.poll_transmit(s(62)).unwrap();
    assert_eq!(out.poll_timeout(), Some(s(62) + Duration::from_millis(200)));

    // the client's streams always beat at their period
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::client());
    out.push(write(0, 8), None).unwrap();
    out.poll_transmit(t0).unwrap();
    let mut now = t0;
    while now < s(40) {
        now = out.poll_timeout().unwrap();
        out.poll_heartbeat(now).unwrap();
    }
    assert_eq!(out.poll_timeout(), Some(now + Duration::from_millis(100)));
}

fn fragment_sizes(m: &[u8]) -> Vec<(u8, usize)> {
    Message::decode(m)
        .unwrap()
        .submessages
        .iter()
        .map(|s| {
            let mut v = Vec::new();
            s.encode(&mut v, 0).unwrap();
            (s.id() as u8, v.len())
        })
        .collect()
}

#[test]
fn fragments_are_cut_where_the_peers_cut_them() {
    let now = Instant::now();
    // a 1200-byte sample: WRITE_DATA of 1208 bytes -> 500 + 500 + 208 (§10)
    let big = write(1, 1200);
    assert_eq!(big.len(), 1208);
    for cfg in [StreamConfig::client(), StreamConfig::agent()] {
        let mut out = ReliableOutput::new(&session(), R, cfg);
        out.push(big.clone(), Some(7)).unwrap();
        let msgs: Vec<Vec<u8>> = std::iter::from_fn(|| out.poll_transmit(now)).collect();
        let lens: Vec<usize> = msgs.iter().map(Vec::len).collect();
        assert_eq!(lens, [508, 508, 216]);
        assert_eq!(msgs[0][..8], [0x81, 0x80, 0, 0, 0x0D, 0x01, 0xF4, 0x01]);
        assert_eq!(msgs[2][..8], [0x81, 0x80, 2, 0, 0x0D, 0x03, 0xD0, 0x00]);
        // the tag comes back when the last fragment is acknowledged
        out.on_acknack(&ack(2, 0), now);
        assert_eq!(out.take_acked().count(), 0);
        out.on_acknack(&ack(3, 0), now);
        assert_eq!(out.take_acked().collect::<Vec<_>>(), [7]);
    }
    // the client puts the first fragment behind what the open message holds
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::client());
    out.push(write(0, 80), None).unwrap();
    out.push(big.clone(), None).unwrap();
    out.push(write(2, 8), None).unwrap();
    let msgs: Vec<Vec<u8>> = std::iter::from_fn(|| out.poll_transmit(now)).collect();
    let lens: Vec<usize> = msgs.iter().map(Vec::len).collect();
    assert_eq!(lens, [508, 508, 320]);
    assert_eq!(fragment_sizes(&msgs[0]), [(0x07, 88), (0x0D, 416)]);
    // the last fragment's message takes the next submessage too
    assert_eq!(fragment_sizes(&msgs[2]), [(0x0D, 300), (0x07, 16)]);
    // and a 20 000-byte sample goes through a 16-message window
    let mut out = ReliableOutput::new(&session(), R, StreamConfig::client());
    let mut input = ReliableInput::new(R, StreamConfig::client());
    out.push(write(3, 20_000), None).unwrap();
    let mut whole = Vec::new();
    for round in 0.. {
        assert!(round < 10);
        let mut n = 0;
        while let Some(m) = out.poll_transmit(now) {
            n += 1;
            let msg = Message::decode(&m).unwrap();
            input.receive(SeqNum(msg.header.sequence_nr), msg, m.len());
        }
        assert!(n <= 16);
        while let Some(msg) = input.next_message() {
            whole.extend(input.unpack(msg, &mut Vec::new()));
        }
        out.on_acknack(&input.acknack(), now);
        if out.is_idle() {
            break;
        }
    }
    let Payload::WriteData(d) = &whole[0].payload else {
        panic!()
    };
    assert_eq!(d.data.len(), 20_000);
}

#[test]
fn best_effort_streams_take_only_newer_messages_and_refuse_what_does_not_fit() {
    let mut input = BestEffortInput::default();
    let taken: Vec<u16> = [0u16, 2, 1, 2, 5, 3, 0x8006, 6]
        .into_iter()
        .filter(|s| input.accept(SeqNum(*s)))
        .collect();
    assert_eq!(taken, [0, 2, 5, 6]);
    let mut out = BestEffortOutput::new(&session(), StreamId::BEST_EFFORT, StreamConfig::client());
    out.push(&write(0, 8)).unwrap();
    out.push(&write(1, 8)).unwrap();
    let m = out.poll_transmit().unwrap();
    assert_eq!(m[..4], [0x81, 0x01, 0, 0]);
    assert_eq!(Message::decode(&m).unwrap().submessages.len(), 2, "packed");
    assert!(out.push(&write(2, 600)).is_err());
    out.push(&write(3, 8)).unwrap();
    assert_eq!(out.poll_transmit().unwrap()[..4], [0x81, 0x01, 1, 0]);
}

/// A submessage larger than all a reliable stream may queue can never go:
/// it is refused at once (`NeverFits`, naming the options), where a full
/// backlog (`Backlog`) means "wait for room". Before, both were `Backlog`,
/// so a sender waited its whole timeout for room that could never be.
#[test]
fn a_submessage_larger_than_the_stream_may_queue_is_refused_at_once() {
    use courier_wire::xrce::stream::StreamError;
    let mut cfg = StreamConfig::agent();
    cfg.max_backlog = 4096;
    let mut out = ReliableOutput::new(&session(), R, cfg);
    let e = out.push(vec![0; 5000], None).unwrap_err();
    assert!(
        matches!(
            e,
            StreamError::NeverFits {
                len: 5000,
                max: 4096,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("raise the session's history= or mtu="),
        "{e}"
    );
    out.push(vec![0; 3000], None).unwrap();
    let e = out.push(vec![0; 3000], None).unwrap_err();
    assert!(matches!(e, StreamError::Backlog { .. }), "{e:?}");
}

/// A HEARTBEAT is used only if its first is at most last + 1 in serial
/// order: across the wrap-around is fine, "first 500, last 3" is not.
#[test]
fn heartbeats_whose_first_is_after_last_plus_one_are_ignored() {
    let hb = |first, last| Heartbeat {
        first_unacked: first,
        last_unacked: last,
        stream_id: R,
    };
    let mut input = ReliableInput::new(R, StreamConfig::client());
    assert!(!input.on_heartbeat(&hb(500, 3)));
    assert!(!input.on_heartbeat(&hb(5, 0xFFF0)));
    assert_eq!(input.acknack().first_unacked, 0, "nothing skipped");
    assert_eq!(input.last_handled(), SeqNum::INITIAL_LAST);
    // first = last + 1: the sender holds nothing, all before first is gone
    assert!(input.on_heartbeat(&hb(4, 3)));
    assert_eq!(input.last_handled(), SeqNum(3));
    // a range across the wrap-around
    let mut input = ReliableInput::new(R, StreamConfig::client());
    input.restore(SeqNum(0xFFF0));
    assert!(input.on_heartbeat(&hb(0xFFFA, 2)));
    assert_eq!(input.last_handled(), SeqNum(0xFFF9));
    assert!(input.on_heartbeat(&hb(0, 0xFFFF)));
    assert_eq!(input.last_handled(), SeqNum(0xFFFF));
}

//! Direct links (ipc.md §8), through the API a shell calls, by hand.

use courier_wire::ipc::frame::{Header, MsgClass};
use courier_wire::ipc::module::{DeliveryKind, Event, LinkId};
use courier_wire::ipc::Writer;

use crate::script::{by_hand, frame, reply_frame, str_data, Central};

#[test]
fn direct_publish_waits_for_receivers_and_links() {
    let mut c = by_hand(false);
    let op = c.publish("dmsg", b"xy", -1).unwrap();
    c.answer_lookup("dmsg", -116, 15, "{int, <byte:1>}", "string");
    // lookup of x_ipc_directMsgQuery, then the query itself
    let f = c.answer_direct_msg_query_lookup();
    assert_eq!(f.len(), 1);
    assert_eq!(
        (f[0].header.intent, f[0].data.clone()),
        (147, str_data("dmsg"))
    );
    let mut w = Writer::new();
    w.write_i32(2);
    w.write_i32(2);
    for (id, port, host) in [(198, 8000, "a"), (197, 8001, "b")] {
        w.write_i32(id);
        w.write_i32(0);
        w.write_i32(0);
        w.write_i32(port);
        w.write_str(host);
        w.write_str("mod");
    }
    c.send(&reply_frame(f[0].header.msg_ref, &w.into_vec()));
    // V_watch_dmsg subscription (registerHandler was looked up at connect)
    let f = c.frames();
    assert_eq!(f.len(), 1);
    assert_eq!(f[0].header.intent, 166);
    assert!(
        c.poll_direct_transmit().is_none(),
        "held until the links are up"
    );
    let mut links = Vec::new();
    while let Some(e) = c.poll_event() {
        if let Event::DirectConnect { link, port, .. } = e {
            links.push((link, port));
        }
    }
    assert_eq!(links, vec![(LinkId(1), 8000), (LinkId(2), 8001)]);
    c.direct_link_up(LinkId(1));
    assert!(c.poll_direct_transmit().is_none());
    c.direct_link_up(LinkId(2));
    let (l1, b1) = c.poll_direct_transmit().unwrap();
    let (l2, b2) = c.poll_direct_transmit().unwrap();
    assert_eq!((l1, l2), (LinkId(2), LinkId(1)), "last handler first");
    let h1 = Header::decode(&b1).unwrap();
    let h2 = Header::decode(&b2).unwrap();
    assert_eq!((h1.intent, h2.intent), (197, 198));
    assert_eq!(h1.msg_ref, h2.msg_ref);
    let mut want = 2i32.to_ne_bytes().repeat(2);
    want.extend_from_slice(b"xy");
    assert_eq!(&b1[28..], &want[..]);
    assert_eq!(c.poll_event(), Some(Event::Published { op }));
    assert!(c.frames().is_empty(), "nothing went to central");
    // second publish: receivers known, links up: immediate
    c.publish("dmsg", b"z", -1).unwrap();
    assert!(c.poll_direct_transmit().is_some());
    while c.poll_direct_transmit().is_some() {}
    while c.poll_event().is_some() {}
    // the link to 8000 closes (its module left, and another may take the
    // port): the next send links anew instead of writing to the dead link
    c.direct_link_closed(LinkId(1));
    let op = c.publish("dmsg", b"w", -1).unwrap();
    assert!(
        c.poll_direct_transmit().is_none(),
        "held until linked again"
    );
    let mut relinked = Vec::new();
    while let Some(e) = c.poll_event() {
        if let Event::DirectConnect { link, port, .. } = e {
            relinked.push((link, port));
        }
    }
    assert_eq!(relinked, vec![(LinkId(3), 8000)]);
    c.direct_link_up(LinkId(3));
    let mut to = Vec::new();
    while let Some((l, b)) = c.poll_direct_transmit() {
        if Header::decode(&b).is_ok_and(|h| h.msg_ref != 0) {
            to.push(l);
        }
    }
    assert_eq!(to, vec![LinkId(2), LinkId(3)]);
    assert_eq!(c.poll_event(), Some(Event::Published { op }));
}

#[test]
fn incoming_direct_query_is_answered_on_its_link_without_success() {
    let mut c = by_hand(true);
    c.subscribe("dq", "HND-dq").unwrap();
    c.take_registration();
    let link = c.accept_direct();
    let q = frame(198, MsgClass::Query, -1, 9, &[], &[0; 8]);
    let b = frame(198, MsgClass::Broadcast, -1, 10, &[], &[0; 8]);
    c.receive_direct(link, &q[..5]).unwrap();
    let mut rest = q[5..].to_vec();
    rest.extend_from_slice(&b);
    c.receive_direct(link, &rest).unwrap();
    assert_eq!(c.poll_event(), None);
    // The handler lookup goes to central.
    c.answer_lookup("dq", -120, 15, "{int, <byte:1>}", "int");
    let Some(Event::Delivery {
        delivery: dq,
        kind: DeliveryKind::Query,
        dispatch_ref: 9,
        ..
    }) = c.poll_event()
    else {
        panic!()
    };
    let Some(Event::Delivery {
        delivery: db,
        kind: DeliveryKind::Broadcast,
        ..
    }) = c.poll_event()
    else {
        panic!()
    };
    c.ack(db).unwrap();
    assert!(c.frames().is_empty(), "no Success for direct deliveries");
    c.respond(dq, "dq", b"ok").unwrap();
    let (l, bytes) = c.poll_direct_transmit().unwrap();
    assert_eq!(l, link);
    let h = Header::decode(&bytes).unwrap();
    assert_eq!(
        (h.intent, h.dispatch_ref, h.msg_ref, h.class_id.class()),
        (-4, 9, 9, 11)
    );
    // garbage on a link is reported, the central connection stays up
    assert!(c.receive_direct(link, &[0xff; 28]).is_err());
    assert!(c.is_connected());
}

/// Frames half received on the direct links a module accepted hold at most
/// about two of its largest frame, all links together (audit 20: six raw
/// connections to a module's direct listener, each holding 200 MiB of a
/// 255 MiB frame, took it to 1.2 GB): the link that goes over is refused
/// (the shell closes it), and its memory goes with it; a frame that fits
/// still arrives on another link.
#[test]
fn frames_in_progress_on_direct_links_are_bounded_all_together() {
    let mut cfg = courier_wire::ipc::module::ModuleConfig::new("module2", "127.1");
    cfg.max_frame = 100_000;
    let mut c = crate::script::by_hand_with(cfg);
    let head = |len: i32| {
        Header {
            class_total: 0,
            msg_total: len,
            parent_ref: -1,
            intent: 7,
            class_id: courier_wire::ipc::frame::ClassId::native(MsgClass::Broadcast),
            dispatch_ref: 1,
            msg_ref: 1,
        }
        .encode()
        .to_vec()
    };
    let big = head(90_000);
    let most = vec![1u8; 80_000];
    let (a, b, d) = (c.accept_direct(), c.accept_direct(), c.accept_direct());
    for l in [a, b] {
        c.receive_direct(l, &big).unwrap();
        c.receive_direct(l, &most).unwrap();
    }
    // a and b hold 160 000 of the 206 250 allowed: d's 80 000 go over
    c.receive_direct(d, &big).unwrap();
    let e = c.receive_direct(d, &most).unwrap_err();
    assert!(
        e.to_string()
            .contains("frames being received on direct links"),
        "{e}"
    );
    c.direct_link_closed(d);
    // a whole frame on another link is taken, and a's frame completes
    let e2 = c.accept_direct();
    let mut small = head(100);
    small.extend_from_slice(&[2u8; 100]);
    c.receive_direct(e2, &small).unwrap();
    c.receive_direct(a, &[1u8; 10_000]).unwrap();
}

/// A query to a direct message with one receiver at port 8000: the op,
/// the link it went out on, and its msgRef.
fn direct_query(
    c: &mut courier_wire::ipc::module::Connection,
) -> (courier_wire::ipc::module::OpId, LinkId, i32) {
    let op = c.query("dq2", b"xy".to_vec(), -1).unwrap();
    c.answer_lookup("dq2", -116, 3, "{int, <byte:1>}", "string");
    let f = c.answer_direct_msg_query_lookup();
    let mut w = Writer::new();
    w.write_i32(1);
    w.write_i32(1);
    w.write_i32(198);
    w.write_i32(0);
    w.write_i32(0);
    w.write_i32(8000);
    w.write_str("a");
    w.write_str("mod");
    c.send(&reply_frame(f[0].header.msg_ref, &w.into_vec()));
    c.frames();
    let mut link = None;
    while let Some(e) = c.poll_event() {
        if let Event::DirectConnect { link: l, .. } = e {
            link = Some(l);
        }
    }
    let link = link.expect("a link to the receiver");
    c.direct_link_up(link);
    let (l, bytes) = c.poll_direct_transmit().unwrap();
    assert_eq!(l, link);
    (op, link, Header::decode(&bytes).unwrap().msg_ref)
}

/// A module's direct listener takes connections from anyone (audit 22: a
/// stranger sent replies for msgRefs 1..400 and `courier call` printed
/// its forged answer; the real one was dropped). Only the link a query
/// went out on answers it; a reply on another link, or from central, is
/// ignored.
#[test]
fn a_direct_query_is_answered_only_on_its_link() {
    let mut c = by_hand(true);
    let (op, link, r) = direct_query(&mut c);
    let stranger = c.accept_direct();
    c.receive_direct(stranger, &reply_frame(r, &str_data("forged")))
        .unwrap();
    c.send(&reply_frame(r, &str_data("from central")));
    assert_eq!(c.poll_event(), None, "neither is taken");
    c.receive_direct(link, &reply_frame(r, &str_data("real")))
        .unwrap();
    match c.poll_event() {
        Some(Event::Reply { query, data, .. }) => {
            assert_eq!(query, op);
            assert_eq!(data, str_data("real"));
        }
        other => panic!("{other:?}"),
    }
    // a second answer on the right link is a late one: ignored
    c.receive_direct(link, &reply_frame(r, &str_data("again")))
        .unwrap();
    assert_eq!(c.poll_event(), None);
    assert!(c.is_connected());
}

/// A frame for one of central's handlers that came on a direct link ended
/// the whole session when it did not decode (audit 22: 32 bytes for the
/// broadcast-list handler, "undecodable string list from central"); a
/// frame naming another message was delivered as the handler's. Both
/// close the link only, and say why.
#[test]
fn link_frames_for_central_handlers_or_other_messages_close_the_link_only() {
    let mut c = by_hand(true);
    c.subscribe("dq", "HND-dq").unwrap();
    c.take_registration();
    // handler ids central's own handlers took at connect
    let mut refused = 0;
    for internal in (1..1000).filter(|i| *i != 198) {
        let link = c.accept_direct();
        let f = frame(internal, MsgClass::Broadcast, -1, 5, &[], &[0; 4]);
        match c.receive_direct(link, &f) {
            Ok(()) => {} // an id nobody has: dropped
            Err(e) => {
                refused += 1;
                let e = e.to_string();
                assert!(
                    e.starts_with("direct link: a frame for central's handler"),
                    "{e}"
                );
            }
        }
        c.direct_link_closed(link);
    }
    assert!(refused >= 1, "{refused}");
    assert!(c.is_connected());
    let mut cd = Writer::new();
    cd.write_str("other");
    let link = c.accept_direct();
    let f = frame(198, MsgClass::Broadcast, -1, 6, &cd.into_vec(), &[0; 8]);
    assert_eq!(
        c.receive_direct(link, &f).unwrap_err().to_string(),
        "direct link: a frame of message other for handler HND-dq of message dq"
    );
    assert!(c.is_connected());
    assert_eq!(c.poll_event(), None, "nothing delivered");
}

/// Deliveries from central waiting to be processed are bounded by what an
/// honest central sends: the module's capacity and 1024 sent ahead (audit
/// 22: a central that did not wait for acknowledgements while a handler
/// lookup went unanswered took a module to 4 GB in 6 s within the
/// 65 536-frame bound). Past it the connection is given up, saying why; a
/// central within it is served.
#[test]
fn deliveries_beyond_capacity_and_send_ahead_close_the_connection() {
    use courier_wire::ipc::module::MAX_SENT_AHEAD;
    let mut c = by_hand(false);
    c.subscribe("m", "HND-m").unwrap();
    c.take_registration();
    c.set_capacity(3).unwrap();
    c.frames();
    assert_eq!(c.capacity(), 3);
    let body = vec![0u8; 8];
    // the first starts the handler lookup (never answered): it holds the
    // rest in the inbox
    c.send(&frame(198, MsgClass::Broadcast, -1, 1, &[], &body));
    assert_eq!(c.poll_event(), None);
    let allowed = 3 + MAX_SENT_AHEAD as i32;
    for r in 0..allowed {
        c.send(&frame(198, MsgClass::Broadcast, -1, r + 2, &[], &body));
        assert!(c.is_connected(), "{r}: within what central may send");
    }
    c.send(&frame(
        198,
        MsgClass::Broadcast,
        -1,
        allowed + 2,
        &[],
        &body,
    ));
    assert!(!c.is_connected());
    let mut closed = None;
    while let Some(e) = c.poll_event() {
        if let Event::Closed(e) = e {
            closed = e;
        }
    }
    let e = closed.expect("closed with an error").to_string();
    assert!(
        e.contains("central sent more than 1027 deliveries this module has not taken yet"),
        "{e}"
    );
}

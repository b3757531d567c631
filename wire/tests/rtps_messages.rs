//! RTPS message codec against datagrams sent by Cyclone DDS 0.10/11 and Fast
//! DDS 2.9 (`tests/fixtures/rtps/*.hex`, extracted from the captures in
//! shared/fixtures/rtps by tools/rtps-fixtures/extract.py; the expected field
//! values are tshark's decodes of the same frames).

use courier_wire::rtps::{
    id, AckNack, Data, DataFrag, EntityId, Error, FragmentNumberSet, Gap, GuidPrefix,
    HeartbeatFrag, InfoReply, InfoSrc, Locator, Message, NackFrag, ParameterList, ProtocolVersion,
    SequenceNumber, SequenceNumberSet, Submessage, Time, VendorId,
};

fn fixture(name: &str) -> Vec<u8> {
    let text = match name {
        "cyclone11_data_hb" => include_str!("fixtures/rtps/cyclone11_data_hb.hex"),
        "cyclone11_heartbeat" => include_str!("fixtures/rtps/cyclone11_heartbeat.hex"),
        "cyclone11_acknack" => include_str!("fixtures/rtps/cyclone11_acknack.hex"),
        "cyclone11_spdp" => include_str!("fixtures/rtps/cyclone11_spdp.hex"),
        "cyclone11_datafrag" => include_str!("fixtures/rtps/cyclone11_datafrag.hex"),
        "fastdds_spdp" => include_str!("fixtures/rtps/fastdds_spdp.hex"),
        "fastdds_heartbeat" => include_str!("fixtures/rtps/fastdds_heartbeat.hex"),
        "fastdds_acknack" => include_str!("fixtures/rtps/fastdds_acknack.hex"),
        "fastdds_data" => include_str!("fixtures/rtps/fastdds_data.hex"),
        "fastdds_datafrag_last" => include_str!("fixtures/rtps/fastdds_datafrag_last.hex"),
        "cyclone010_gap" => include_str!("fixtures/rtps/cyclone010_gap.hex"),
        "fastdds_gap" => include_str!("fixtures/rtps/fastdds_gap.hex"),
        other => panic!("no fixture {other}"),
    };
    let hex: String = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .collect::<String>();
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect()
}

const ALL: [&str; 12] = [
    "cyclone11_data_hb",
    "cyclone11_heartbeat",
    "cyclone11_acknack",
    "cyclone11_spdp",
    "cyclone11_datafrag",
    "fastdds_spdp",
    "fastdds_heartbeat",
    "fastdds_acknack",
    "fastdds_data",
    "fastdds_datafrag_last",
    "cyclone010_gap",
    "fastdds_gap",
];

fn eid(v: u32) -> EntityId {
    EntityId(v.to_be_bytes())
}

/// Every captured datagram parses and re-encodes to the identical bytes.
#[test]
fn captured_messages_round_trip() {
    for name in ALL {
        let b = fixture(name);
        let m = Message::parse(&b).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(m.to_vec(), b, "{name} did not re-encode identically");
    }
}

/// `encoded_len` is what `write` appends: for every submessage the peers
/// sent, and for the kinds the captures lack.
#[test]
fn encoded_len_is_the_written_length() {
    let check = |sm: &Submessage<'_>| {
        let mut out = vec![0xaa; 3];
        sm.write(&mut out, true);
        assert_eq!(sm.encoded_len(), out.len() - 3, "{sm:?}");
    };
    let mut n = 0;
    for name in ALL {
        let b = fixture(name);
        for sm in &Message::parse(&b).unwrap().submessages {
            check(sm);
            n += 1;
        }
    }
    assert!(n >= 40, "only {n} submessages in the captures");
    let (r, w) = (eid(0x1007), eid(0x1002));
    let sn = SequenceNumber(7);
    let short = SequenceNumberSet {
        base: sn,
        num_bits: 64,
        bitmap: vec![1], // fewer words than num_bits asks for: written as given
    };
    let loc = Locator::udpv4([127, 0, 0, 1], 7411);
    let qos = [0u8, 0x70, 4, 0, 1, 2, 3, 4, 1, 0, 0, 0];
    for sm in [
        Submessage::Data(Data {
            reader_id: r,
            writer_id: w,
            writer_sn: sn,
            inline_qos: Some(&qos),
            payload: Some(b"\0\x01\0\0abc"),
            key: false,
            non_standard: false,
        }),
        Submessage::Data(Data {
            reader_id: r,
            writer_id: w,
            writer_sn: sn,
            inline_qos: None,
            payload: None,
            key: false,
            non_standard: false,
        }),
        Submessage::DataFrag(DataFrag {
            reader_id: r,
            writer_id: w,
            writer_sn: sn,
            fragment_starting_num: 3,
            fragments_in_submessage: 2,
            fragment_size: 8,
            sample_size: 40,
            inline_qos: Some(&qos),
            payload: &[5; 16],
            key: false,
            non_standard: false,
        }),
        Submessage::HeartbeatFrag(HeartbeatFrag {
            reader_id: r,
            writer_id: w,
            writer_sn: sn,
            last_fragment_num: 9,
            count: 1,
        }),
        Submessage::NackFrag(NackFrag {
            reader_id: r,
            writer_id: w,
            writer_sn: sn,
            fragment_number_state: FragmentNumberSet {
                base: 1,
                num_bits: 40,
                bitmap: vec![u32::MAX, 1],
            },
            count: 2,
        }),
        Submessage::AckNack(AckNack {
            reader_id: r,
            writer_id: w,
            reader_sn_state: short.clone(),
            count: 3,
            final_flag: true,
        }),
        Submessage::Gap(Gap {
            reader_id: r,
            writer_id: w,
            gap_start: sn,
            gap_list: short,
            extra: vec![0; 4],
        }),
        Submessage::InfoTs(Some(Time {
            seconds: 1,
            fraction: 2,
        })),
        Submessage::InfoTs(None),
        Submessage::InfoDst(GuidPrefix([3; 12])),
        Submessage::InfoSrc(InfoSrc {
            version: ProtocolVersion { major: 2, minor: 3 },
            vendor: VendorId([1, 16]),
            guid_prefix: GuidPrefix([4; 12]),
        }),
        Submessage::InfoReply(InfoReply {
            unicast: vec![loc, loc],
            multicast: Some(vec![loc]),
        }),
        Submessage::InfoReply(InfoReply {
            unicast: vec![],
            multicast: None,
        }),
        Submessage::Pad,
        Submessage::Unknown {
            id: 0x80,
            flags: 1,
            body: &[1, 2, 3, 4, 5, 6, 7, 8],
        },
    ] {
        check(&sm);
    }
}

#[test]
fn cyclone11_user_data_with_piggybacked_heartbeat() {
    let b = fixture("cyclone11_data_hb");
    let m = Message::parse(&b).unwrap();
    assert_eq!(m.header.vendor, VendorId::CYCLONE);
    assert_eq!((m.header.version.major, m.header.version.minor), (2, 5));
    assert_eq!(m.submessages.len(), 3);
    assert!(matches!(m.submessages[0], Submessage::InfoTs(Some(_))));
    let Submessage::Data(d) = &m.submessages[1] else {
        panic!("{:?}", m.submessages[1])
    };
    assert_eq!(d.reader_id, EntityId::UNKNOWN);
    assert_eq!(d.writer_id, eid(0x0000_0203));
    assert_eq!(d.writer_sn, SequenceNumber(1));
    assert!(d.inline_qos.is_none());
    let payload = d.payload.unwrap();
    // CDR_LE encapsulation, then the HelloWorld sample
    assert_eq!(&payload[..4], &[0, 1, 0, 0]);
    assert!(payload.windows(18).any(|w| w == b"Hello from Cyclone"));
    let Submessage::Heartbeat(h) = &m.submessages[2] else {
        panic!()
    };
    assert_eq!(
        (h.first_sn, h.last_sn, h.count),
        (SequenceNumber(1), SequenceNumber(1), 2)
    );
    assert_eq!(h.writer_id, eid(0x0000_0203));
    assert!(!h.final_flag && !h.liveliness);
}

#[test]
fn first_heartbeat_and_final_acknack() {
    let m_hb = fixture("cyclone11_heartbeat");
    let m = Message::parse(&m_hb).unwrap();
    let hb = m
        .submessages
        .iter()
        .find_map(|s| match s {
            Submessage::Heartbeat(h) => Some(*h),
            _ => None,
        })
        .unwrap();
    assert_eq!(
        (hb.first_sn, hb.last_sn),
        (SequenceNumber(1), SequenceNumber(0))
    );
    for name in ["cyclone11_acknack", "fastdds_acknack"] {
        let b = fixture(name);
        let m = Message::parse(&b).unwrap();
        let a = m
            .submessages
            .iter()
            .find_map(|s| match s {
                Submessage::AckNack(a) => Some(a.clone()),
                _ => None,
            })
            .unwrap_or_else(|| panic!("{name}: no ACKNACK"));
        assert!(a.final_flag, "{name}");
        assert_eq!(
            a.reader_sn_state,
            SequenceNumberSet::empty(SequenceNumber(1)),
            "{name}"
        );
    }
}

#[test]
fn fast_dds_vendor_submessage_is_skipped_and_kept() {
    let b = fixture("fastdds_spdp");
    let m = Message::parse(&b).unwrap();
    assert_eq!(m.header.vendor, VendorId::EPROSIMA);
    assert!(m
        .submessages
        .iter()
        .any(|s| matches!(s, Submessage::Unknown { id: 0x80, .. })));
    // the SPDP DATA carries a PL_CDR_LE parameter list
    let d = m
        .submessages
        .iter()
        .find_map(|s| match s {
            Submessage::Data(d) => Some(d.clone()),
            _ => None,
        })
        .unwrap();
    assert_eq!(d.writer_id, EntityId::SPDP_WRITER);
    let p = d.payload.unwrap();
    assert_eq!(&p[..2], &[0x00, 0x03]);
    let (list, _) = ParameterList::parse(&p[4..], true).unwrap();
    // PID_PARTICIPANT_GUID (0x0050) holds the sender's prefix
    let guid = list.params.iter().find(|x| x.pid == 0x0050).unwrap();
    assert_eq!(&guid.value[..12], &m.header.guid_prefix.0);
}

#[test]
fn cyclone_fragments_ten_per_submessage() {
    let b = fixture("cyclone11_datafrag");
    let m = Message::parse(&b).unwrap();
    let f = m
        .submessages
        .iter()
        .find_map(|s| match s {
            Submessage::DataFrag(f) => Some(f.clone()),
            _ => None,
        })
        .unwrap();
    assert_eq!(f.writer_sn, SequenceNumber(6));
    assert_eq!(f.fragment_starting_num, 1);
    assert_eq!(f.fragments_in_submessage, 10);
    assert_eq!(f.fragment_size, 1344);
    assert_eq!(f.sample_size, 102_416);
    assert_eq!(f.payload.len(), 10 * 1344);
    assert!(m.submessages.iter().any(
        |s| matches!(s, Submessage::HeartbeatFrag(h) if h.last_fragment_num == 10 && h.writer_sn == SequenceNumber(6))
    ));
}

#[test]
fn gaps_from_both_vendors() {
    let b = fixture("fastdds_gap");
    let m = Message::parse(&b).unwrap();
    let g = m
        .submessages
        .iter()
        .find_map(|s| match s {
            Submessage::Gap(g) => Some(g.clone()),
            _ => None,
        })
        .unwrap();
    assert_eq!(g.reader_id, eid(0x0000_0104));
    assert_eq!(g.writer_id, eid(0x0000_0103));
    assert_eq!(g.gap_start, SequenceNumber(37));
    assert_eq!(g.gap_list, SequenceNumberSet::empty(SequenceNumber(42)));
    let b = fixture("cyclone010_gap");
    let m = Message::parse(&b).unwrap();
    assert_eq!((m.header.version.major, m.header.version.minor), (2, 1));
    assert!(m.submessages.iter().any(|s| matches!(
        s,
        Submessage::Gap(g) if g.gap_start == SequenceNumber(18) && g.gap_list.base == SequenceNumber(19)
    )));
}

#[test]
fn sequence_number_sets() {
    let s = SequenceNumberSet::from_members(
        SequenceNumber(100),
        70,
        [100, 131, 132, 169, 170, 99].map(SequenceNumber),
    );
    assert_eq!(s.bitmap.len(), 3);
    assert_eq!(
        s.iter().collect::<Vec<_>>(),
        [100, 131, 132, 169].map(SequenceNumber)
    );
}

/// Truncating a real datagram anywhere gives an error, never a panic, and
/// a mangled length never reads past the datagram.
#[test]
fn truncated_and_mangled_datagrams_are_errors() {
    for name in ALL {
        let b = fixture(name);
        let step = (b.len() / 400).max(1);
        for n in (0..b.len()).step_by(step) {
            // a cut inside a submessage header or body must fail; a cut exactly
            // between submessages is a valid shorter message
            let _ = Message::parse(&b[..n]);
        }
        assert!(matches!(
            Message::parse(&b[..19]),
            Err(Error::Truncated { .. })
        ));
        // every submessage length field set to 0xffff
        let mut m = b.clone();
        m[22] = 0xff;
        m[23] = 0xff;
        assert!(Message::parse(&m).is_err(), "{name}");
    }
    assert!(matches!(
        Message::parse(b"RTPX\x02\x01\x01\x10____________"),
        Err(Error::BadMagic(_))
    ));
    assert!(matches!(
        Message::parse(b"RTPS\x01\x00\x01\x10____________"),
        Err(Error::UnsupportedVersion(_))
    ));
}

#[test]
fn unknown_submessage_round_trips_in_its_own_byte_order() {
    let mut b = b"RTPS\x02\x03\x01\x0f".to_vec();
    b.extend_from_slice(&[7; 12]);
    // big-endian vendor submessage (E clear), length 4
    b.extend_from_slice(&[0x81, 0x00, 0x00, 0x04, 1, 2, 3, 4]);
    // little-endian INFO_TS with the I flag (no timestamp)
    b.extend_from_slice(&[id::INFO_TS, 0x03, 0, 0]);
    let m = Message::parse(&b).unwrap();
    assert_eq!(m.submessages.len(), 2);
    assert_eq!(m.submessages[1], Submessage::InfoTs(None));
    assert_eq!(m.to_vec(), b);
}

#[test]
fn parameter_lists_round_trip() {
    let mut out = Vec::new();
    ParameterList::write(&[(0x0005, b"abc"), (0x8001, &[1, 2, 3, 4])], true, &mut out);
    assert_eq!(
        out,
        [5, 0, 4, 0, b'a', b'b', b'c', 0, 1, 0x80, 4, 0, 1, 2, 3, 4, 1, 0, 0, 0]
    );
    let (l, used) = ParameterList::parse(&out, true).unwrap();
    assert_eq!(used, out.len());
    assert_eq!(l.params.len(), 2);
    assert!(ParameterList::parse(&out[..10], true).is_err());
}

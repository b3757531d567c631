//! SPDP/SEDP discovery data and disposals from Cyclone DDS 0.10/11 and Fast
//! DDS 2.9 (`tests/fixtures/rtps/*.hex`, from shared/fixtures/rtps by
//! tools/rtps-fixtures/extract.py; expected values are tshark's decodes).

use courier_wire::rtps::discovery::{
    payload_params, Disposal, Durability, EndpointData, EndpointQos, History, ParticipantData,
    Reliability,
};
use courier_wire::rtps::{Data, EntityId, Locator, Message, ProtocolVersion, Submessage, VendorId};

fn fixture(name: &str) -> Vec<u8> {
    let text = match name {
        "cyclone11_spdp" => include_str!("fixtures/rtps/cyclone11_spdp.hex"),
        "cyclone010_spdp" => include_str!("fixtures/rtps/cyclone010_spdp.hex"),
        "fastdds_spdp" => include_str!("fixtures/rtps/fastdds_spdp.hex"),
        "cyclone11_sedp_pub" => include_str!("fixtures/rtps/cyclone11_sedp_pub.hex"),
        "cyclone11_sedp_sub" => include_str!("fixtures/rtps/cyclone11_sedp_sub.hex"),
        "fastdds_sedp_pub" => include_str!("fixtures/rtps/fastdds_sedp_pub.hex"),
        "fastdds_sedp_sub" => include_str!("fixtures/rtps/fastdds_sedp_sub.hex"),
        "cyclone11_spdp_dispose" => include_str!("fixtures/rtps/cyclone11_spdp_dispose.hex"),
        "fastdds_spdp_dispose" => include_str!("fixtures/rtps/fastdds_spdp_dispose.hex"),
        "cyclone11_sedp_dispose" => include_str!("fixtures/rtps/cyclone11_sedp_dispose.hex"),
        "fastdds_sedp_dispose" => include_str!("fixtures/rtps/fastdds_sedp_dispose.hex"),
        other => panic!("no fixture {other}"),
    };
    let hex: String = text.lines().filter(|l| !l.starts_with('#')).collect();
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect()
}

/// The DATA submessages of a datagram written by the given built-in writer.
fn datas<'a>(m: &'a Message<'a>, writer: EntityId) -> Vec<(&'a Data<'a>, bool)> {
    m.submessages
        .iter()
        .zip(&m.little_endian)
        .filter_map(|(s, le)| match s {
            Submessage::Data(d) if d.writer_id == writer => Some((d, *le)),
            _ => None,
        })
        .collect()
}

#[test]
fn spdp_from_three_peers() {
    let lo = |port| Locator::udpv4([127, 0, 0, 1], port);
    for (name, vendor, version, lease, domain, endpoints) in [
        (
            "cyclone11_spdp",
            VendorId::CYCLONE,
            ProtocolVersion::V2_5,
            10,
            Some(0),
            0x0000_fc3f,
        ),
        (
            "cyclone010_spdp",
            VendorId::CYCLONE,
            ProtocolVersion::V2_1,
            10,
            Some(0),
            0x0000_fc3f,
        ),
        (
            "fastdds_spdp",
            VendorId::EPROSIMA,
            ProtocolVersion::V2_3,
            20,
            None,
            0x0c3f_0c3f,
        ),
    ] {
        let b = fixture(name);
        let m = Message::parse(&b).unwrap();
        let (d, _) = datas(&m, EntityId::SPDP_WRITER)[0];
        let p = ParticipantData::from_params(&payload_params(d.payload.unwrap()).unwrap())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(p.guid_prefix, m.header.guid_prefix, "{name}");
        assert_eq!((p.vendor, p.protocol_version), (vendor, version), "{name}");
        assert_eq!(p.lease_duration.seconds, lease, "{name}");
        assert_eq!(p.domain_id, domain, "{name}");
        assert_eq!(p.builtin_endpoints, endpoints, "{name}");
        assert_eq!(p.metatraffic_unicast, [lo(7410)], "{name}");
        assert_eq!(p.default_unicast, [lo(7411)], "{name}");
        // what we would announce for the same participant reads back the same
        let again =
            ParticipantData::from_params(&payload_params(&p.to_payload()).unwrap()).unwrap();
        assert_eq!(again, p, "{name}");
    }
    let b = fixture("fastdds_spdp");
    let m = Message::parse(&b).unwrap();
    let (d, _) = datas(&m, EntityId::SPDP_WRITER)[0];
    let p = ParticipantData::from_params(&payload_params(d.payload.unwrap()).unwrap()).unwrap();
    assert_eq!(p.entity_name.as_deref(), Some("RTPSParticipant"));
}

#[test]
fn sedp_from_cyclone_and_fast_dds() {
    for (name, writer_id, writer) in [
        (
            "cyclone11_sedp_pub",
            EntityId::SEDP_PUBLICATIONS_WRITER,
            true,
        ),
        (
            "cyclone11_sedp_sub",
            EntityId::SEDP_SUBSCRIPTIONS_WRITER,
            false,
        ),
        ("fastdds_sedp_pub", EntityId::SEDP_PUBLICATIONS_WRITER, true),
        (
            "fastdds_sedp_sub",
            EntityId::SEDP_SUBSCRIPTIONS_WRITER,
            false,
        ),
    ] {
        let b = fixture(name);
        let m = Message::parse(&b).unwrap();
        let found = datas(&m, writer_id);
        assert!(!found.is_empty(), "{name}: no SEDP DATA");
        let (d, _) = found[0];
        let e = EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), writer)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(e.topic_name, "HelloWorldTopic", "{name}");
        assert_eq!(e.type_name, "HelloWorld", "{name}");
        assert_eq!(e.guid.prefix, m.header.guid_prefix, "{name}");
        assert_eq!(e.guid.entity.is_writer(), writer, "{name}");
        assert!(
            matches!(e.qos.reliability, Reliability::Reliable(_)),
            "{name}"
        );
        assert_eq!(e.qos.durability, Durability::Volatile, "{name}");
        // Courier's own announcement of the same endpoint reads back identically
        let again = EndpointData::from_params(
            &payload_params(&e.to_payload(VendorId::CYCLONE, ProtocolVersion::V2_5)).unwrap(),
            writer,
        )
        .unwrap();
        assert_eq!(again, e, "{name}");
    }
    // Cyclone's reader offers both representations; Fast DDS sends none (XCDR1 implied)
    let b = fixture("cyclone11_sedp_sub");
    let m = Message::parse(&b).unwrap();
    let (d, _) = datas(&m, EntityId::SEDP_SUBSCRIPTIONS_WRITER)[0];
    let e = EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), false).unwrap();
    assert_eq!(e.qos.data_representation, [0, 2]);
    assert!(e.type_information.is_some());
    let b = fixture("fastdds_sedp_sub");
    let m = Message::parse(&b).unwrap();
    let (d, _) = datas(&m, EntityId::SEDP_SUBSCRIPTIONS_WRITER)[0];
    let e = EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), false).unwrap();
    assert_eq!(e.qos.data_representation, [0]);
    assert!(e.type_information.is_none());
}

/// Both disposal styles name the same kind of key: Cyclone's K-flag key
/// payload and Fast DDS's inline KEY_HASH.
#[test]
fn disposals_both_ways() {
    for name in [
        "cyclone11_spdp_dispose",
        "fastdds_spdp_dispose",
        "cyclone11_sedp_dispose",
        "fastdds_sedp_dispose",
    ] {
        let b = fixture(name);
        let m = Message::parse(&b).unwrap();
        let all: Vec<_> = m
            .submessages
            .iter()
            .zip(&m.little_endian)
            .filter_map(|(s, le)| match s {
                Submessage::Data(d) if d.writer_id.is_builtin() => Some((d, *le)),
                _ => None,
            })
            .collect();
        let disposals: Vec<Disposal> = all
            .iter()
            .filter_map(|(d, le)| Disposal::from_data(d.inline_qos, *le, d.payload, d.key).unwrap())
            .collect();
        assert!(
            !disposals.is_empty(),
            "{name}: no disposal found ({} DATA)",
            all.len()
        );
        for x in &disposals {
            assert!(x.status.disposed && x.status.unregistered, "{name}");
            // the key is a GUID of the sending participant
            assert_eq!(&x.key_hash[..12], &m.header.guid_prefix.0, "{name}");
        }
    }
}

#[test]
fn qos_defaults_and_hostile_parameters() {
    let w = EndpointQos::writer_default();
    assert!(matches!(w.reliability, Reliability::Reliable(_)));
    assert_eq!(w.history, History::KeepLast(1));
    // a PARTITION claiming a billion names is an error, not an allocation
    let mut p = vec![0x00, 0x03, 0, 0];
    p.extend_from_slice(&[0x29, 0x00, 8, 0, 0, 0xca, 0x9a, 0x3b, 0, 0, 0, 0]);
    p.extend_from_slice(&[0x05, 0x00, 8, 0, 2, 0, 0, 0, b'a', 0, 0, 0]);
    p.extend_from_slice(&[1, 0, 0, 0]);
    assert!(EndpointData::from_params(&payload_params(&p).unwrap(), true).is_err());
    // missing GUID / topic are clear errors
    let p = [0x00, 0x03, 0, 0, 1, 0, 0, 0];
    let e = EndpointData::from_params(&payload_params(&p).unwrap(), true).unwrap_err();
    assert!(e.to_string().contains("PID_ENDPOINT_GUID"), "{e}");
    assert!(ParticipantData::from_params(&payload_params(&p).unwrap()).is_err());
    assert!(payload_params(&[0, 1, 0, 0, 1, 0, 0, 0]).is_err());
}

/// `PID_DATA_REPRESENTATION` (0x0073) as Courier announces it: a reader that
/// accepts XCDR1 and XCDR2 sends the very bytes Cyclone DDS 11's reader sends
/// (cyclone11_sedp_sub: `73 00 08 00 | 02 00 00 00 | 00 00 02 00`), a writer
/// of XCDR2 one id.
#[test]
fn data_representation_parameter_golden() {
    let cyclone = fixture("cyclone11_sedp_sub");
    let both = [0x73, 0x00, 0x08, 0x00, 2, 0, 0, 0, 0, 0, 2, 0];
    assert!(
        cyclone.windows(both.len()).any(|w| w == both),
        "the fixture holds Cyclone 11's parameter"
    );
    let m = Message::parse(&cyclone).unwrap();
    let (d, _) = datas(&m, EntityId::SEDP_SUBSCRIPTIONS_WRITER)[0];
    let mut e =
        EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), false).unwrap();
    for (reps, want) in [
        (vec![0i16, 2], both.to_vec()),
        (
            vec![2],
            vec![0x73, 0x00, 0x08, 0x00, 1, 0, 0, 0, 2, 0, 0, 0],
        ),
        (
            vec![0],
            vec![0x73, 0x00, 0x08, 0x00, 1, 0, 0, 0, 0, 0, 0, 0],
        ),
    ] {
        e.qos.data_representation = reps.clone();
        let p = e.to_payload(VendorId::CYCLONE, ProtocolVersion::V2_5);
        let at = p
            .windows(4)
            .position(|w| w == [0x73, 0x00, 0x08, 0x00])
            .unwrap_or_else(|| panic!("{reps:?}: no PID_DATA_REPRESENTATION"));
        assert_eq!(p[at..at + 12], want[..], "{reps:?}");
    }
}

#[test]
fn a_duration_debugs_as_a_time() {
    use courier_wire::rtps::discovery::Duration;
    let d = Duration::from_std(std::time::Duration::from_millis(500));
    assert_eq!(format!("{d:?}"), "Duration(500ms)");
    assert_eq!(format!("{:?}", Duration::INFINITE), "Duration(INFINITE)");
    let neg = Duration {
        seconds: -1,
        fraction: 0,
    };
    assert_eq!(format!("{neg:?}"), "Duration { seconds: -1, fraction: 0 }");
}

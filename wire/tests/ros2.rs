//! ROS 2 names and the `ros_discovery_info` graph message.

use courier_wire::ros2::graph::{
    Gid, GidSize, NodeEntitiesInfo, ParticipantEntitiesInfo, MAX_NAME, TOPIC, TYPE_NAME,
};
use courier_wire::ros2::names::{dds_topic, dds_type, ros_topic, ros_type, Kind, Node};

#[test]
fn names_map_to_the_dds_names_every_dds_rmw_uses() {
    for (ros, kind, dds) in [
        ("/chatter", Kind::Topic, "rt/chatter"),
        (
            "/robot/arm/joint_states",
            Kind::Topic,
            "rt/robot/arm/joint_states",
        ),
        ("/add_two_ints", Kind::Request, "rq/add_two_intsRequest"),
        ("/add_two_ints", Kind::Reply, "rr/add_two_intsReply"),
        ("/ns/srv", Kind::Reply, "rr/ns/srvReply"),
    ] {
        assert_eq!(dds_topic(ros, kind).unwrap(), dds, "{ros}");
        assert_eq!(ros_topic(dds), Some((ros.to_string(), kind)), "{dds}");
    }
    for (ros, kind, dds) in [
        (
            "std_msgs/msg/String",
            Kind::Topic,
            "std_msgs::msg::dds_::String_",
        ),
        (
            "example_interfaces/srv/AddTwoInts",
            Kind::Request,
            "example_interfaces::srv::dds_::AddTwoInts_Request_",
        ),
        (
            "example_interfaces/srv/AddTwoInts",
            Kind::Reply,
            "example_interfaces::srv::dds_::AddTwoInts_Response_",
        ),
    ] {
        assert_eq!(dds_type(ros, kind).unwrap(), dds, "{ros}");
        assert_eq!(ros_type(dds), Some((ros.to_string(), kind)), "{dds}");
    }
    // DDS names that are not ROS 2's
    for dds in ["chatter", "rt/", "rq/add", "rt//x", "DCPSParticipant"] {
        assert_eq!(ros_topic(dds), None, "{dds}");
    }
    for dds in ["courier::Ping", "std_msgs::msg::String_", "a::b::dds_::C"] {
        assert_eq!(ros_type(dds), None, "{dds}");
    }
}

#[test]
fn relative_private_and_absolute_names_expand_as_rcl_expands_them() {
    let n = Node::new("/robot", "talker").unwrap();
    assert_eq!(n.expand("chatter").unwrap(), "/robot/chatter");
    assert_eq!(n.expand("/chatter").unwrap(), "/chatter");
    assert_eq!(n.expand("~/status").unwrap(), "/robot/talker/status");
    assert_eq!(n.expand("~").unwrap(), "/robot/talker");
    let root = Node::new("", "n").unwrap();
    assert_eq!(root.namespace(), "/");
    assert_eq!(root.expand("x/y").unwrap(), "/x/y");
    assert_eq!(root.to_string(), "/n");
    assert_eq!(n.to_string(), "/robot/talker");
}

#[test]
fn names_that_break_the_rules_say_which_rule() {
    let n = Node::new("/", "n").unwrap();
    for (name, why) in [
        ("2fast", "starts with a digit"),
        ("a b", "only letters"),
        ("a//b", "empty part"),
        ("a/", "empty part"),
        ("a__b", "`__` is reserved"),
    ] {
        let e = n.expand(name).unwrap_err();
        assert!(e.to_string().contains(why), "{name}: {e}");
        assert!(e.to_string().contains(name), "{name}: {e}");
    }
    assert!(Node::new("robot", "n")
        .unwrap_err()
        .to_string()
        .contains("start with `/`"));
    assert!(Node::new("/", "a/b")
        .unwrap_err()
        .to_string()
        .contains("`/`"));
    let e = dds_type("std_msgs/String", Kind::Topic).unwrap_err();
    assert!(e.to_string().contains("package/msg/Name"), "{e}");
    let e = dds_type("std_msgs/msg/String", Kind::Request).unwrap_err();
    assert!(e.to_string().contains("services have `srv` types"), "{e}");
    let e = dds_type("pkg/srv/Add", Kind::Topic).unwrap_err();
    assert!(e.to_string().contains("topics have `msg` types"), "{e}");
    assert!(
        dds_topic("chatter", Kind::Topic).is_err(),
        "relative names are expanded first"
    );
}

fn gid(b: u8) -> Gid {
    Gid([b; 16])
}

fn sample() -> ParticipantEntitiesInfo {
    ParticipantEntitiesInfo {
        gid: gid(0x11),
        node_entities_info_seq: vec![NodeEntitiesInfo {
            node_namespace: "/".into(),
            node_name: "talker".into(),
            reader_gid_seq: vec![gid(0x22)],
            writer_gid_seq: vec![],
        }],
    }
}

/// The layout of rmw_dds_common's messages (`Gid`: `char[16] data`, since
/// 2.0 / Iron; `char[24]` before), XCDR1 little-endian as the rmws write it.
#[test]
fn the_graph_message_has_rmw_dds_commons_layout() {
    assert_eq!(TOPIC, "ros_discovery_info");
    assert_eq!(
        TYPE_NAME,
        "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
    );
    let mut want = vec![0x00, 0x01, 0x00, 0x00];
    want.extend([0x11; 16]); // gid
    want.extend([1, 0, 0, 0]); // one node
    want.extend([2, 0, 0, 0, b'/', 0, 0, 0]); // namespace "/" + padding
    want.extend([7, 0, 0, 0]);
    want.extend(b"talker\0");
    want.push(0); // padding
    want.extend([1, 0, 0, 0]);
    want.extend([0x22; 16]); // readers
    want.extend([0, 0, 0, 0]); // writers
    let bytes = sample().encode(GidSize::Sixteen).unwrap();
    assert_eq!(bytes, want);
    assert_eq!(
        ParticipantEntitiesInfo::decode(&bytes).unwrap(),
        (sample(), GidSize::Sixteen)
    );

    // Humble: the same with each GID zero-padded to 24 bytes
    let humble = sample().encode(GidSize::TwentyFour).unwrap();
    assert_eq!(humble.len(), want.len() + 8 + 8);
    assert_eq!(&humble[4..20], &[0x11; 16]);
    assert_eq!(&humble[20..28], &[0; 8]);
    assert_eq!(
        ParticipantEntitiesInfo::decode(&humble).unwrap(),
        (sample(), GidSize::TwentyFour)
    );
}

#[test]
fn malformed_graph_messages_are_errors() {
    let good = sample().encode(GidSize::Sixteen).unwrap();
    for cut in 0..good.len() - 1 {
        assert!(
            ParticipantEntitiesInfo::decode(&good[..cut]).is_err(),
            "cut at {cut}"
        );
    }
    // a node count far beyond the data: refused before allocating
    let mut huge = good.clone();
    huge[20..24].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(ParticipantEntitiesInfo::decode(&huge).is_err());
    // names longer than ROS 2 allows: not encoded, not decoded
    let mut long = sample();
    long.node_entities_info_seq[0].node_name = "n".repeat(MAX_NAME + 1);
    let e = long.encode(GidSize::Sixteen).unwrap_err();
    assert!(e.to_string().contains("256"), "{e}");
}

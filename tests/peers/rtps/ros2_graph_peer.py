#!/usr/bin/env python3
"""A ROS 2 participant's graph traffic as rmw_cyclonedds puts it on the wire,
on Cyclone DDS 11 (the PyPI `cyclonedds` package): the `ros_discovery_info`
topic, type `rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_`, with the
field layout of rmw_dds_common's messages

    Gid.msg:                     char[16] data        (char[24] in Humble)
    NodeEntitiesInfo.msg:        string<=256 node_namespace
                                 string<=256 node_name
                                 Gid[] reader_gid_seq
                                 Gid[] writer_gid_seq
    ParticipantEntitiesInfo.msg: Gid gid
                                 NodeEntitiesInfo[] node_entities_info_seq

in plain CDR (XCDR1), written with the QoS rmw_cyclonedds gives it
(reliable, transient-local, keep last 1) and read with keep all. A GID is the
entity's DDS GUID, zero-padded to the GID size.

The peer is node --node /ns/name with a writer of --publish (a ROS 2 topic
name, DDS topic rt/..., type std_msgs::msg::dds_::String_) and a reader of
--subscribe, and publishes its ParticipantEntitiesInfo once. It prints every
other participant's sample it reads, with each GID resolved through DDS
discovery (DCPSPublication / DCPSSubscription) to its topic, as the ROS 2
graph tools do. With --malformed KIND it writes one broken sample instead:
  huge-count   the GID, then a node count of 0x7fffffff and nothing after it
  long-name    a node name of 300 bytes (ROS 2 allows 256)
  foreign      a GID naming a participant that is not the writer's

Loopback only (interface lo, no multicast, unicast SPDP to 127.0.0.1);
CYCLONEDDS_URI is removed before the library loads. Runs until its standard
input closes (or --timeout-s).

Output:
  ready <participant gid> writer <gid> reader <gid>
  graph <participant gid> known|unknown nodes <n>
  node <namespace> <name> writers <topic>=<gid>,... readers <topic>=<gid>,...
      (`-` for an empty list; `?` for a topic discovery does not know)
  done | timeout
Exit codes: 0 done, 1 DDS error, 2 timeout, 3 parent gone, 64 usage.
"""

import argparse
import sys
import threading
import time
from dataclasses import dataclass

# before the cyclonedds package loads: importing it drops CYCLONEDDS_URI
from peer_common import Clock, emit, loopback_domain

try:
    from cyclonedds.builtin import (  # noqa: E402
        BuiltinDataReader,
        BuiltinTopicDcpsParticipant,
        BuiltinTopicDcpsPublication,
        BuiltinTopicDcpsSubscription,
    )
    from cyclonedds.core import Policy, Qos  # noqa: E402
    from cyclonedds.domain import DomainParticipant  # noqa: E402
    from cyclonedds.idl import IdlStruct  # noqa: E402
    from cyclonedds.idl.annotations import final  # noqa: E402
    from cyclonedds.idl import types  # noqa: E402
    from cyclonedds.pub import DataWriter  # noqa: E402
    from cyclonedds.sub import DataReader  # noqa: E402
    from cyclonedds.topic import Topic  # noqa: E402
    from cyclonedds.util import duration  # noqa: E402
except ImportError as e:  # pragma: no cover
    print(f"ros2_graph_peer: the cyclonedds Python package (11.x) is missing: {e}", file=sys.stderr)
    sys.exit(1)

PROG = "ros2_graph_peer"
TOPIC = "ros_discovery_info"
TYPE = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"

def graph_types(gid_size, bounded=True):
    """rmw_dds_common's three messages with GIDs of gid_size bytes."""
    name_t = types.bounded_str[256] if bounded else str

    @dataclass
    @final
    class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: types.array[types.uint8, gid_size]

    @dataclass
    @final
    class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: name_t
        node_name: name_t
        reader_gid_seq: types.sequence[Gid]
        writer_gid_seq: types.sequence[Gid]

    @dataclass
    @final
    class ParticipantEntitiesInfo(IdlStruct, typename=TYPE):
        gid: Gid
        node_entities_info_seq: types.sequence[NodeEntitiesInfo]

    return Gid, NodeEntitiesInfo, ParticipantEntitiesInfo


@dataclass
@final
class HugeCount(IdlStruct, typename=TYPE):
    gid: types.array[types.uint8, 16]
    node_count: types.uint32


@dataclass
@final
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


def gid_bytes(entity, size):
    return entity.guid.bytes + bytes(size - 16)


def hexs(b):
    return bytes(b).hex()


def main():
    ap = argparse.ArgumentParser(prog=PROG, description="rmw-style ros_discovery_info peer (loopback only)")
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--node", required=True, help="/namespace/name")
    ap.add_argument("--publish", default="/py_chatter")
    ap.add_argument("--subscribe", default="/py_cmd")
    ap.add_argument("--gid-size", type=int, choices=[16, 24], default=16)
    ap.add_argument("--malformed", choices=["huge-count", "long-name", "foreign"])
    ap.add_argument("--timeout-s", type=float, default=60)
    o = ap.parse_args()
    if not 0 <= o.domain <= 232:
        ap.error("--domain must be 0..232")
    if not o.node.startswith("/"):
        ap.error("--node must be /namespace/name")
    ns, name = o.node.rsplit("/", 1)
    ns = ns or "/"

    stdin_closed = threading.Event()

    def watch_stdin():
        for _ in sys.stdin:
            pass
        stdin_closed.set()

    threading.Thread(target=watch_stdin, daemon=True).start()

    check = Clock(PROG, o.timeout_s).check

    dom = loopback_domain(o.domain)  # kept for the whole run
    dp = DomainParticipant(o.domain)
    me = gid_bytes(dp, o.gid_size)

    # rmw_cyclonedds's graph QoS; CDR v1 only, as its serializer writes
    base = [
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.Durability.TransientLocal,
        Policy.DataRepresentation(use_cdrv0_representation=True),
    ]
    wqos = Qos(*base, Policy.History.KeepLast(1))
    rqos = Qos(*base, Policy.History.KeepAll)

    pub_w = DataWriter(dp, Topic(dp, "rt" + o.publish, String))
    sub_r = DataReader(dp, Topic(dp, "rt" + o.subscribe, String))

    bounded = o.malformed != "long-name"
    Gid, NodeEntitiesInfo, ParticipantEntitiesInfo = graph_types(o.gid_size, bounded)
    if o.malformed == "huge-count":
        bad = HugeCount(gid=list(me[:16]), node_count=0x7FFFFFFF)
        gw = DataWriter(dp, Topic(dp, TOPIC, HugeCount), qos=wqos)
        gw.write(bad)
        graph_reader = None
    else:
        topic = Topic(dp, TOPIC, ParticipantEntitiesInfo)
        gw = DataWriter(dp, topic, qos=wqos)
        graph_reader = DataReader(dp, topic, qos=rqos) if o.malformed is None else None
        pgid = me
        node_name = name
        if o.malformed == "foreign":
            pgid = bytes([0x42] * 12) + bytes([0, 0, 1, 0xC1]) + bytes(o.gid_size - 16)
        if o.malformed == "long-name":
            node_name = "n" * 300
        info = ParticipantEntitiesInfo(
            gid=Gid(data=list(pgid)),
            node_entities_info_seq=[
                NodeEntitiesInfo(
                    node_namespace=ns,
                    node_name=node_name,
                    reader_gid_seq=[Gid(data=list(gid_bytes(sub_r, o.gid_size)))],
                    writer_gid_seq=[Gid(data=list(gid_bytes(pub_w, o.gid_size)))],
                )
            ],
        )
        gw.write(info)
    emit(f"ready {hexs(me[:16])} writer {hexs(gid_bytes(pub_w, 16))} reader {hexs(gid_bytes(sub_r, 16))}")

    pubs = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    subs = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
    parts = BuiltinDataReader(dp, BuiltinTopicDcpsParticipant)
    topics = {}
    participants = set()

    def learn():
        for s in pubs.take(N=100) + subs.take(N=100):
            if getattr(s, "topic_name", None):
                topics[s.key.bytes] = s.topic_name
        for s in parts.take(N=100):
            participants.add(s.key.bytes)

    def describe(gids):
        if not gids:
            return "-"
        return ",".join(f"{topics.get(bytes(g.data[:16]), '?')}={hexs(g.data[:16])}" for g in gids)

    while not stdin_closed.is_set():
        check()
        learn()
        samples = graph_reader.take(N=10) if graph_reader is not None else []
        for m in samples:
            if bytes(m.gid.data) == me:
                continue  # ours (rmw ignores local publications)
            gids = [g for n in m.node_entities_info_seq for g in n.reader_gid_seq + n.writer_gid_seq]
            # give discovery a moment to announce the endpoints named
            settle = time.monotonic() + 5
            while time.monotonic() < settle and any(bytes(g.data[:16]) not in topics for g in gids):
                check()
                time.sleep(0.02)
                learn()
            known = "known" if bytes(m.gid.data[:16]) in participants else "unknown"
            emit(f"graph {hexs(m.gid.data[:16])} {known} nodes {len(m.node_entities_info_seq)}")
            for n in m.node_entities_info_seq:
                emit(
                    f"node {n.node_namespace} {n.node_name} "
                    f"writers {describe(n.writer_gid_seq)} readers {describe(n.reader_gid_seq)}"
                )
        time.sleep(0.01)
    emit("done")
    del gw, pub_w, sub_r, dp, dom
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Exception as e:  # a DDS error: say it and fail
        print(f"{PROG}: {e}", file=sys.stderr)
        sys.exit(1)

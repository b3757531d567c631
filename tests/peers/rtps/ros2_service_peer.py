#!/usr/bin/env python3
"""A ROS 2 service as rmw_cyclonedds puts it on the wire, on Cyclone DDS 11
(the PyPI `cyclonedds` package): request topic `rq/<name>Request`, reply
topic `rr/<name>Reply`, and before the body of every request and reply the
16-byte header of rmw_cyclonedds's serdata (`cdds_request_header_t`:
uint64 client id, int64 request number). Requests carry no related sample
identity; a client takes only replies with its own id.

The service type is AddTwoInts: request { int64 a; int64 b; }, reply
{ int64 sum; } (DDS type names courier::test::AddTwoInts_Request_ and
..._Response_), so the samples are the header's two fields followed by the
body's.

  --server            answer --count requests with a + b
  --client            ask --count requests (a = 10 * n, b = n) and wait for each reply

Loopback only (interface lo, no multicast, unicast SPDP to 127.0.0.1);
CYCLONEDDS_URI is removed before the library loads.

Output: ready | matched <n> | request <seq> <a> <b> | reply <seq> <sum> |
foreign <client> <seq> (a reply for another client) | done | timeout.
Exit codes: 0 done, 1 DDS error, 2 timeout, 3 parent gone, 64 usage.
"""

import argparse
import random
import sys
import time
from dataclasses import dataclass

# before the cyclonedds package loads: importing it drops CYCLONEDDS_URI
from peer_common import Clock, emit, loopback_domain

try:
    from cyclonedds.core import Policy, Qos  # noqa: E402
    from cyclonedds.domain import DomainParticipant  # noqa: E402
    from cyclonedds.idl import IdlStruct  # noqa: E402
    from cyclonedds.idl.annotations import final  # noqa: E402
    from cyclonedds.idl.types import int64, uint64  # noqa: E402
    from cyclonedds.pub import DataWriter  # noqa: E402
    from cyclonedds.sub import DataReader  # noqa: E402
    from cyclonedds.topic import Topic  # noqa: E402
    from cyclonedds.util import duration  # noqa: E402
except ImportError as e:  # pragma: no cover
    print(f"ros2_service_peer: the cyclonedds Python package (11.x) is missing: {e}", file=sys.stderr)
    sys.exit(1)

PROG = "ros2_service_peer"

# The header's fields, then the body's: the bytes rmw_cyclonedds writes.
@dataclass
@final
class Request(IdlStruct, typename="courier::test::AddTwoInts_Request_"):
    client: uint64
    seq: int64
    a: int64
    b: int64


@dataclass
@final
class Reply(IdlStruct, typename="courier::test::AddTwoInts_Response_"):
    client: uint64
    seq: int64
    sum: int64


def main():
    ap = argparse.ArgumentParser(prog=PROG, description="rmw_cyclonedds-style service peer (loopback only)")
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--service", required=True)
    role = ap.add_mutually_exclusive_group(required=True)
    role.add_argument("--server", action="store_true")
    role.add_argument("--client", action="store_true")
    ap.add_argument("--count", type=int, default=3)
    ap.add_argument("--timeout-s", type=float, default=60)
    o = ap.parse_args()
    if not 0 <= o.domain <= 232:
        ap.error("--domain must be 0..232")


    check = Clock(PROG, o.timeout_s).check

    dom = loopback_domain(o.domain)  # kept for the whole run
    dp = DomainParticipant(o.domain)
    # rmw's default service QoS: reliable, volatile, keep last 10
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
    rq = Topic(dp, f"rq/{o.service}Request", Request)
    rr = Topic(dp, f"rr/{o.service}Reply", Reply)
    if o.server:
        reader, writer = DataReader(dp, rq, qos=qos), DataWriter(dp, rr, qos=qos)
    else:
        writer, reader = DataWriter(dp, rq, qos=qos), DataReader(dp, rr, qos=qos)
    emit("ready")

    matched = -1
    while True:
        check()
        n = min(
            writer.get_publication_matched_status().current_count,
            reader.get_subscription_matched_status().current_count,
        )
        if n != matched:
            matched = n
            emit(f"matched {n}")
        if n >= 1:
            break
        time.sleep(0.01)

    done = 0
    if o.server:
        while done < o.count:
            check()
            for r in reader.take(N=10):
                emit(f"request {r.seq} {r.a} {r.b}")
                writer.write(Reply(client=r.client, seq=r.seq, sum=r.a + r.b))
                done += 1
            time.sleep(0.005)
        writer.wait_for_acks(duration(seconds=5))
    else:
        # matching is seen from each side on its own: the service's reader
        # may not know this writer yet, and a volatile reader takes nothing
        # written before it matched. Settle, and ask again (same number)
        # when no answer comes: a late duplicate's reply is ignored.
        time.sleep(0.25)
        me = random.getrandbits(64)
        for seq in range(1, o.count + 1):
            answered = False
            while not answered:
                writer.write(Request(client=me, seq=seq, a=10 * seq, b=seq))
                deadline = time.monotonic() + 1.0
                while not answered and time.monotonic() < deadline:
                    check()
                    for r in reader.take(N=10):
                        if r.client != me:
                            emit(f"foreign {r.client} {r.seq}")
                        elif r.seq == seq and not answered:
                            emit(f"reply {r.seq} {r.sum}")
                            answered = True
                    time.sleep(0.005)
    emit("done")
    del dp, dom
    return 0


if __name__ == "__main__":
    sys.exit(main())

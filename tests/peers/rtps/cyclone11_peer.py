#!/usr/bin/env python3
"""Cyclone DDS 11 (the PyPI `cyclonedds` package) as an RTPS interop peer.

The same command line and output lines as cyclone_peer.c / fastdds_peer.cpp
(see README.md in this directory), for the types only Cyclone 11 speaks
(XCDR2: @appendable and @mutable) and for the keyed types:

  --type keyed       @final struct courier::test::Keyed { @key int32 id; uint32 seq; string text; }
  --type strkeyed    @final struct courier::test::StrKeyed { @key string name; uint32 seq; string text; }
  --type appendable  @appendable struct courier::test::Appendable { @key int32 id; uint32 seq; string text; }
  --type mutable     @mutable struct courier::test::Mutable { @key int32 id; uint32 seq; string text; }
  --type appendable_v1, mutable_v1
                     an older version of each: the same type name without `text`
                     (a reader of the newer version gets its default, "")
  --type colors      @final struct courier::test::Colors { @key int32 id; uint32 seq;
                     sequence<Color> colors; Color pair[2]; string text; }
                     with enum courier::test::Color { RED, GREEN, BLUE }: XCDR2
                     puts a DHEADER before the sequence and the array (an enum is
                     not a CDR primitive). Sample seq has colors
                     [Color((seq + i) % 3) for i in range(seq % 4)] and pair
                     [Color(seq % 3), Color((2 * seq + 1) % 3)].
  --type stamped     @final struct courier::test::Stamped { @key int32 id;
                     @key int64 stamp; uint32 seq; string text; }
                     instance `id` has stamp 0x0102030405060708 + id and is
                     named <id>:<stamp> (decimal), as cyclone_peer names it;
                     its key hash differs between XCDR1 (id, 4 bytes of
                     padding, stamp) and XCDR2 (id, stamp)

Loopback only: the domain is created from a configuration string (interface
lo, no multicast, unicast SPDP to 127.0.0.1); CYCLONEDDS_URI is removed from
the environment before the library loads.

Liveliness: --liveliness KIND:SECONDS (KIND automatic, participant or
topic) offers (writer) or requests (reader) that LIVELINESS; a reader then
prints `liveliness <alive_count> <not_alive_count>` each time its
liveliness_changed status changes, a writer `liveliness-lost <total>`.
--run-s makes a reader without --count stop (`done`) after that long.
Cyclone's participant lease stays its default (10 s): a stop shorter than
that loses a writer's liveliness, not its participant.

--no-autodispose gives a writer WRITER_DATA_LIFECYCLE autodispose false
(Cyclone's readers then take its instances as NOT_ALIVE_NO_WRITERS, not
disposed, when it goes); --close-writer deletes the writer once its
samples are acknowledged (`closed`) while the participant stays.

Output: ready | matched <n> | sent <key> <seq> | dispose <key> | acked | closed |
sample <key> <seq> <text> | disposed <key> | unregistered <key> |
liveliness <alive> <not_alive> | liveliness-lost <total> | done | timeout;
for --type colors the sample line goes on with the colors and the pair,
each as enumerator names joined by commas (`""` when empty):
sample <key> <seq> <text> <colors> <pair>.
A reader given --representation accepts that representation only, so a sample
it takes proves what the writer wrote. A dispose or unregister of an instance this
reader never saw alive is `disposed-unknown` / `unregistered-unknown`: the
change did not land on a known instance.

Exit codes: 0 done, 1 DDS error, 2 timeout, 3 parent gone, 64 usage.
"""

import argparse
import sys
import time
from dataclasses import dataclass

# before the cyclonedds package loads: importing it drops CYCLONEDDS_URI
import peer_common
from peer_common import Clock, emit, loopback_domain

try:
    from cyclonedds.core import InstanceState, Policy, Qos  # noqa: E402
    from cyclonedds.domain import DomainParticipant  # noqa: E402
    from cyclonedds.idl import IdlEnum, IdlStruct  # noqa: E402
    from cyclonedds.idl.annotations import appendable, final, key, mutable  # noqa: E402
    from cyclonedds.idl.types import array, int32, int64, sequence, uint32  # noqa: E402
    from cyclonedds.pub import DataWriter  # noqa: E402
    from cyclonedds.sub import DataReader  # noqa: E402
    from cyclonedds.topic import Topic  # noqa: E402
    from cyclonedds.util import duration  # noqa: E402
except ImportError as e:  # pragma: no cover
    print(f"cyclone11_peer: the cyclonedds Python package (11.x) is missing: {e}", file=sys.stderr)
    sys.exit(1)

PROG = "cyclone11_peer"


@dataclass
@final
class Keyed(IdlStruct, typename="courier::test::Keyed"):
    id: int32
    key("id")
    seq: uint32
    text: str


@dataclass
@final
class StrKeyed(IdlStruct, typename="courier::test::StrKeyed"):
    name: str
    key("name")
    seq: uint32
    text: str


@dataclass
@appendable
class Appendable(IdlStruct, typename="courier::test::Appendable"):
    id: int32
    key("id")
    seq: uint32
    text: str


@dataclass
@mutable
class Mutable(IdlStruct, typename="courier::test::Mutable"):
    id: int32
    key("id")
    seq: uint32
    text: str


@dataclass
@appendable
class AppendableV1(IdlStruct, typename="courier::test::Appendable"):
    id: int32
    key("id")
    seq: uint32


@dataclass
@mutable
class MutableV1(IdlStruct, typename="courier::test::Mutable"):
    id: int32
    key("id")
    seq: uint32


@dataclass
@final
class Unkeyed(IdlStruct, typename="courier::test::Unkeyed"):
    id: int32
    seq: uint32
    text: str


class Color(IdlEnum, typename="courier::test::Color"):
    RED = 0
    GREEN = 1
    BLUE = 2


@dataclass
@final
class Colors(IdlStruct, typename="courier::test::Colors"):
    id: int32
    key("id")
    seq: uint32
    colors: sequence[Color]
    pair: array[Color, 2]
    text: str


STAMP = 0x0102030405060708


@dataclass
@final
class Stamped(IdlStruct, typename="courier::test::Stamped"):
    id: int32
    key("id")
    stamp: int64
    key("stamp")
    seq: uint32
    text: str


def colors_of(seq):
    return [Color((seq + i) % 3) for i in range(seq % 4)]


def pair_of(seq):
    return [Color(seq % 3), Color((2 * seq + 1) % 3)]


def names(colors):
    return ",".join(c.name for c in colors) or '""'


TYPES = {
    "keyed": Keyed,
    "strkeyed": StrKeyed,
    "appendable": Appendable,
    "mutable": Mutable,
    "unkeyed": Unkeyed,
    "appendable_v1": AppendableV1,
    "mutable_v1": MutableV1,
    "colors": Colors,
    "stamped": Stamped,
}


def fail(msg, code=1):
    peer_common.fail(PROG, msg, code)


def escape(text):
    if text == "":
        return '""'
    out = []
    for b in text.encode():
        if 0x21 <= b <= 0x7E and b not in (ord("%"), ord('"')):
            out.append(chr(b))
        else:
            out.append(f"%{b:02X}")
    return "".join(out)


def key_of(kind, v):
    if kind == "stamped":
        return f"{v.id}:{v.stamp}"
    return v.name if kind == "strkeyed" else str(v.id)


def make(kind, k, seq, text):
    if kind == "strkeyed":
        return StrKeyed(name=k, seq=seq, text=text)
    if kind.endswith("_v1"):
        return TYPES[kind](id=int(k), seq=seq)
    if kind == "stamped":
        return Stamped(id=int(k), stamp=STAMP + int(k), seq=seq, text=text)
    if kind == "colors":
        return Colors(id=int(k), seq=seq, colors=colors_of(seq), pair=pair_of(seq), text=text)
    return TYPES[kind](id=int(k), seq=seq, text=text)


def sample_line(kind, k, v):
    line = f"sample {escape(k)} {v.seq} {escape(getattr(v, 'text', ''))}"
    if kind == "colors":
        line += f" {names(v.colors)} {names(v.pair)}"
    return line



def liveliness_policy(spec):
    kind, _, secs = spec.partition(":")
    lease = duration(seconds=float(secs or "1"))
    kinds = {
        "automatic": Policy.Liveliness.Automatic,
        "participant": Policy.Liveliness.ManualByParticipant,
        "topic": Policy.Liveliness.ManualByTopic,
    }
    if kind not in kinds:
        raise argparse.ArgumentTypeError(f"liveliness kind {kind!r}: automatic, participant or topic")
    return kinds[kind](lease)


class LivelinessWatch:
    """Prints a reader's liveliness_changed counts, or a writer's
    liveliness_lost total, when they change."""

    def __init__(self, entity, reader):
        self.entity = entity
        self.reader = reader
        self.last = None

    def poll(self):
        if self.reader:
            st = self.entity.get_liveliness_changed_status()
            now = (st.alive_count, st.not_alive_count)
            if now != self.last:
                self.last = now
                emit(f"liveliness {now[0]} {now[1]}")
        else:
            st = self.entity.get_liveliness_lost_status()
            if st.total_count != self.last:
                if self.last is not None or st.total_count:
                    emit(f"liveliness-lost {st.total_count}")
                self.last = st.total_count


def main():
    ap = argparse.ArgumentParser(prog=PROG, description="Cyclone DDS 11 interop peer (loopback only)")
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--topic", required=True)
    ap.add_argument("--type", choices=sorted(TYPES), required=True)
    role = ap.add_mutually_exclusive_group(required=True)
    role.add_argument("--pub", action="store_true")
    role.add_argument("--sub", action="store_true")
    rel = ap.add_mutually_exclusive_group(required=True)
    rel.add_argument("--reliable", action="store_true")
    rel.add_argument("--best-effort", action="store_true")
    ap.add_argument("--representation", choices=["xcdr1", "xcdr2", "default"], default="default",
                    help="writer: the one it writes; reader: xcdr1 or xcdr2 alone (default: the type's)")
    ap.add_argument("--count", type=int)
    ap.add_argument("--disposed", type=int)
    ap.add_argument("--keys", help="pub: comma-separated keys, sample n goes to keys[n %% len]")
    ap.add_argument("--dispose", action="store_true", help="pub: dispose every key after writing")
    ap.add_argument("--no-autodispose", action="store_true",
                    help="pub: WRITER_DATA_LIFECYCLE autodispose_unregistered_instances false")
    ap.add_argument("--close-writer", action="store_true",
                    help="pub: delete the writer once acked (`closed`), the participant stays for --linger-ms")
    ap.add_argument("--wait-match", type=int, default=0)
    ap.add_argument("--settle-ms", type=int, default=250)
    ap.add_argument("--linger-ms", type=int, default=0)
    ap.add_argument("--timeout-s", type=float, default=60)
    ap.add_argument("--text", default="cyclone11")
    ap.add_argument("--trace", help="Cyclone's finest trace into this file")
    ap.add_argument("--liveliness", type=liveliness_policy,
                    help="KIND:SECONDS, KIND automatic | participant | topic")
    ap.add_argument("--run-s", type=float, help="sub without --count: stop after this long")
    o = ap.parse_args()
    if not 0 <= o.domain <= 232:
        ap.error("--domain must be 0..232")
    if o.pub and o.disposed is not None:
        ap.error("--disposed is a subscriber option")
    if o.sub and (o.no_autodispose or o.close_writer):
        ap.error("--no-autodispose and --close-writer are publisher options")

    clock = Clock(PROG, o.timeout_s)
    ty = TYPES[o.type]
    dom = loopback_domain(o.domain, o.trace)  # kept for the whole run
    dp = DomainParticipant(o.domain)
    policies = [
        Policy.Reliability.Reliable(duration(seconds=1)) if o.reliable else Policy.Reliability.BestEffort,
        Policy.History.KeepLast(100),
    ]
    if o.liveliness is not None:
        policies.append(o.liveliness)
    if o.representation == "xcdr1":
        policies.append(Policy.DataRepresentation(use_cdrv0_representation=True))
    elif o.representation == "xcdr2":
        policies.append(Policy.DataRepresentation(use_xcdrv2_representation=True))
    qos = Qos(*policies)
    topic = Topic(dp, o.topic, ty)
    emit("ready")

    if o.pub:
        wqos = qos
        if o.no_autodispose:
            wqos = Qos(*policies, Policy.WriterDataLifecycle(autodispose=False))
        w = DataWriter(dp, topic, qos=wqos)
        matched = -1
        while True:
            clock.check()
            n = w.get_publication_matched_status().current_count
            if n != matched:
                matched = n
                emit(f"matched {n}")
            if n >= o.wait_match:
                break
            time.sleep(0.01)
        time.sleep(o.settle_ms / 1000)
        keys = (o.keys or "1").split(",")
        count = o.count if o.count is not None else 1
        for seq in range(1, count + 1):
            k = keys[(seq - 1) % len(keys)]
            w.write(make(o.type, k, seq, f"{o.text}-{seq}"))
            emit(f"sent {k} {seq}")
        if o.dispose:
            for k in keys:
                w.dispose(make(o.type, k, 0, ""))
                emit(f"dispose {k}")
        if o.reliable:
            if not w.wait_for_acks(duration(seconds=o.timeout_s)):
                emit("timeout")
                sys.exit(2)
            emit("acked")
        if o.close_writer:
            # Cyclone sends no unregister per instance when a writer goes:
            # only its SEDP dispose says so
            w.__del__()
            w = None
            emit("closed")
        if o.liveliness is None or w is None:
            time.sleep(o.linger_ms / 1000)
        else:
            watch = LivelinessWatch(w, reader=False)
            end = time.monotonic() + o.linger_ms / 1000
            while time.monotonic() < end:
                watch.poll()
                time.sleep(min(0.02, max(0.0, end - time.monotonic())))
        emit("done")
        del w, dom
        return 0

    r = DataReader(dp, topic, qos=qos)
    matched = -1
    received = 0
    disposed = 0
    ids = {}  # instance handle -> key, for instances seen alive
    states = {}

    watch = LivelinessWatch(r, reader=True) if o.liveliness is not None else None
    started = time.monotonic()

    def finished():
        if o.count is None and o.disposed is None:
            return o.run_s is not None and time.monotonic() - started >= o.run_s
        return (o.count is None or received >= o.count) and (o.disposed is None or disposed >= o.disposed)

    while not finished():
        clock.check()
        n = r.get_subscription_matched_status().current_count
        if n != matched:
            matched = n
            emit(f"matched {n}")
        if watch:
            watch.poll()
        got = r.take(N=100)
        for s in got:
            info = s.sample_info
            if info.valid_data:
                k = key_of(o.type, s)
                emit(sample_line(o.type, k, s))
                ids[info.instance_handle] = k
                received += 1
            # the instance state as seen when taken: on a valid sample too
            # (a dispose that came before the sample was taken shows there)
            st = info.instance_state
            k = ids.get(info.instance_handle)
            if st == InstanceState.NotAliveDisposed:
                word = "disposed"
            elif st == InstanceState.NotAliveNoWriters:
                word = "unregistered"
            else:
                if k is not None:
                    states[k] = "alive"
                continue
            if k is None:
                emit(f"{word}-unknown {info.instance_handle}")
                continue
            if states.get(k) != word:
                states[k] = word
                emit(f"{word} {escape(k)}")
                if word == "disposed":
                    disposed += 1
        if not got:
            time.sleep(0.02)
    if watch is None:
        time.sleep(o.linger_ms / 1000)
    else:
        # liveliness goes on changing while the reader lingers
        end = time.monotonic() + o.linger_ms / 1000
        while time.monotonic() < end:
            watch.poll()
            time.sleep(min(0.02, max(0.0, end - time.monotonic())))
    emit("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())

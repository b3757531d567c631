#!/usr/bin/env python3
"""Extract the UDP payloads (RTPS messages) of chosen frames from the pcaps in
shared/fixtures/rtps into small hex fixtures for wire/tests/rtps_*.rs.

Usage: extract.py SHARED_FIXTURES_RTPS_DIR OUT_DIR
Standard library only; classic pcap, Ethernet or Linux cooked (SLL) link types, IPv4/UDP.
"""
import struct
import sys
from pathlib import Path

# (output name, pcap, frame number, what tshark says it is)
FRAMES = [
    ("cyclone11_data_hb", "cyclone11_pubsub.pcap", 104, "INFO_TS, DATA (user, 4-byte ... sample), HEARTBEAT"),
    ("cyclone11_heartbeat", "cyclone11_pubsub.pcap", 100, "INFO_DST, HEARTBEAT first=1 last=0"),
    ("cyclone11_acknack", "cyclone11_pubsub.pcap", 101, "INFO_DST, ACKNACK final, base 1, 0 bits"),
    ("cyclone11_spdp", "cyclone11_pubsub.pcap", 2, "INFO_DST (zero prefix), INFO_TS, DATA(p) SPDP"),
    ("cyclone11_datafrag", "cyclone11_pubsub.pcap", 115, "INFO_TS, DATA_FRAG (10 x 1344), HEARTBEAT_FRAG"),
    ("fastdds_spdp", "fastdds_pubsub.pcap", 1, "vendor 0x80 submessage, INFO_TS, DATA(p) SPDP"),
    ("fastdds_heartbeat", "fastdds_pubsub.pcap", 280, "HEARTBEAT"),
    ("fastdds_acknack", "fastdds_pubsub.pcap", 282, "ACKNACK"),
    ("fastdds_data", "fastdds_pubsub.pcap", 285, "INFO_DST, INFO_TS, DATA"),
    ("fastdds_datafrag_last", "fastdds_pubsub.pcap", 304, "DATA_FRAG (last) + HEARTBEAT"),
    ("cyclone010_gap", "ddsperf010_gap.pcap", 81, "GAP"),
    ("fastdds_gap", "fastdds_gap.pcap", 222, "GAP"),
    ("cyclone11_sedp_pub", "cyclone11_pubsub.pcap", 99, "SEDP publication"),
    ("cyclone11_sedp_sub", "cyclone11_pubsub.pcap", 91, "SEDP subscription (DATA_REPRESENTATION)"),
    ("fastdds_sedp_pub", "fastdds_pubsub.pcap", 269, "SEDP publication, every QoS"),
    ("fastdds_sedp_sub", "fastdds_pubsub.pcap", 279, "SEDP subscription, every QoS"),
    ("cyclone11_spdp_dispose", "cyclone11_pubsub.pcap", 125, "SPDP dispose: K+Q DATA, STATUS_INFO 3"),
    ("fastdds_spdp_dispose", "fastdds_pubsub.pcap", 306, "SPDP dispose: Q-only DATA, KEY_HASH + STATUS_INFO"),
    ("cyclone11_sedp_dispose", "cyclone11_pubsub.pcap", 124, "SEDP dispose: K+Q DATA"),
    ("fastdds_sedp_dispose", "fastdds_pubsub.pcap", 305, "SEDP dispose: Q-only DATA"),
    ("cyclone010_spdp", "ddsperf010_pingpong.pcap", 1, "SPDP of Cyclone 0.10.2 (RTPS 2.1)"),
]


def frames(path):
    data = Path(path).read_bytes()
    magic = data[:4]
    if magic == b"\xd4\xc3\xb2\xa1":
        end = "<"
    elif magic == b"\xa1\xb2\xc3\xd4":
        end = ">"
    else:
        raise SystemExit(f"{path}: not a classic pcap")
    linktype = struct.unpack(end + "I", data[20:24])[0]
    off, n = 24, 0
    while off + 16 <= len(data):
        _, _, incl, _ = struct.unpack(end + "IIII", data[off:off + 16])
        off += 16
        n += 1
        yield n, linktype, data[off:off + incl]
        off += incl


def udp_payload(linktype, pkt):
    if linktype == 1:  # Ethernet
        eth_type = struct.unpack(">H", pkt[12:14])[0]
        ip = pkt[14:]
    elif linktype == 113:  # Linux cooked
        eth_type = struct.unpack(">H", pkt[14:16])[0]
        ip = pkt[16:]
    elif linktype == 276:  # Linux cooked v2
        eth_type = struct.unpack(">H", pkt[0:2])[0]
        ip = pkt[20:]
    else:
        raise SystemExit(f"unsupported link type {linktype}")
    if eth_type != 0x0800 or ip[9] != 17:
        return None
    ihl = (ip[0] & 0x0F) * 4
    udp = ip[ihl:]
    length = struct.unpack(">H", udp[4:6])[0]
    return udp[8:length]


def main():
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    for name, pcap, frame, what in FRAMES:
        for n, lt, pkt in frames(src / pcap):
            if n == frame:
                payload = udp_payload(lt, pkt)
                break
        else:
            raise SystemExit(f"{pcap}: no frame {frame}")
        hexs = payload.hex()
        lines = [hexs[i:i + 64] for i in range(0, len(hexs), 64)]
        (out / f"{name}.hex").write_text(
            f"# {pcap} frame {frame} (UDP payload, {len(payload)} bytes): {what}\n"
            f"# extracted by tools/rtps-fixtures/extract.py from shared/fixtures/rtps\n"
            + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

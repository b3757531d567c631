"""What the Python peers (cyclone11_peer, ros2_service_peer, ros2_graph_peer)
share: the loopback-only Cyclone DDS configuration, and the output and exit
conventions of README.md.

Importing it removes CYCLONEDDS_URI from the environment, so import it
before the `cyclonedds` package loads: the domain is then configured by
`loopback_domain` alone (interface lo, no multicast, unicast SPDP to
127.0.0.1), never by a configuration the environment names.
"""

import os
import sys
import time

os.environ.pop("CYCLONEDDS_URI", None)

_LOOPBACK_CONFIG = (
    '<CycloneDDS><Domain id="any">'
    '<General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>"
    '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
    "{tracing}"
    "</Domain></CycloneDDS>"
)


def loopback_domain(domain_id, trace_file=None):
    """The Cyclone domain `domain_id`, pinned to lo. Keep it for the whole
    run: dropped, the domain would fall back to Cyclone's default
    configuration (multicast on the default interface)."""
    from cyclonedds.domain import Domain

    tracing = ""
    if trace_file:
        tracing = (
            f"<Tracing><Verbosity>finest</Verbosity><OutputFile>{trace_file}</OutputFile>"
            "</Tracing>"
        )
    return Domain(domain_id, _LOOPBACK_CONFIG.format(tracing=tracing))


def emit(line):
    """One output line, flushed at once (the test reads it as it comes)."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def fail(prog, msg, code=1):
    print(f"{prog}: {msg}", file=sys.stderr)
    sys.exit(code)


class Clock:
    """The run's bounds: `timeout` and exit 2 after `timeout_s`, exit 3 once
    the parent (the test) is gone (checked at most twice a second)."""

    def __init__(self, prog, timeout_s):
        self.prog = prog
        self.start = time.monotonic()
        self.timeout_s = timeout_s
        self.parent = os.getppid()
        self.last_parent_check = 0.0

    def check(self):
        now = time.monotonic()
        if now - self.start > self.timeout_s:
            emit("timeout")
            sys.exit(2)
        if now - self.last_parent_check > 0.5:
            self.last_parent_check = now
            if os.getppid() != self.parent:
                fail(self.prog, "the parent process went away", 3)

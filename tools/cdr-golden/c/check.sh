#!/bin/sh
# Cross-checks the fixtures made by gen.py (cyclonedds 11.0.1, Python
# serializer) against Cyclone DDS's C serializer (dds_cdrstream), as packaged
# by Debian: apt-get install cyclonedds-dev libddsc0debian (0.10.2).
# Pure serialization: no DDS entities, no network.
#
# Expected differences (0.10.2 vs 11.x), everything else must be identical:
# - XCDR1 of mutable / appendable / @optional types: 0.10.2 has no XCDR1
#   (PL_CDR) support for them and emits XCDR2 framing; such types are XCDR2-only
#   in 0.10. 11.x writes PL_CDR (checked against its source, see the CDR tests).
# - mutkeyed_*: 0.10.2 sets must-understand on key members (EMHEADER 0xa0000000,
#   XTypes 1.3); 11.x no longer does (for RTI interop), which Courier follows.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
fix="$here/../../../wire/tests/fixtures/cdr"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cp "$here/types.idl" "$here/dump.c" "$tmp/"
cd "$tmp"
idlc types.idl
cc -o dump dump.c types.c -lddsc
./dump | while read -r name hex; do
  golden=$(grep -v '^#' "$fix/$name.hex" | tr -d '\n')
  if [ "$golden" = "$hex" ]; then echo "same $name"; else echo "DIFF $name"; echo "  fixture $golden"; echo "  C       $hex"; fi
done

#!/usr/bin/env python3
"""Generate golden CDR payloads with Cyclone DDS's Python binding.

`IdlStruct.serialize()` is pure (no DDS entities, no network); it runs the
cyclonedds Python serializer, which implements the same rules as the C core's
dds_cdrstream (checked against the C source for DHEADER / LC / XCDR1
parameter-list rules, see the test file).

Usage:  pip install cyclonedds==11.0.1 && python3 tools/cdr-golden/gen.py
Writes  wire/tests/fixtures/cdr/<case>.hex: a '#' comment line, then the
payload (encapsulation header included) as hex, 32 bytes per line.
"""
from dataclasses import dataclass
import importlib.metadata
import os
import sys
from typing import Optional

from cyclonedds.idl import IdlStruct, IdlEnum
from cyclonedds.idl._support import Endianness
from cyclonedds.idl.annotations import final, appendable, mutable, key
import cyclonedds.idl.types as t

VERSION = importlib.metadata.version("cyclonedds")
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "wire", "tests", "fixtures", "cdr")


class Color(IdlEnum, typename="Color"):
    RED = 0
    GREEN = 1
    BLUE = 2


@final
@dataclass
class Prims(IdlStruct, typename="Prims"):
    a: t.int8
    b: t.uint8
    c: t.int16
    d: t.uint16
    e: t.int32
    f: t.uint32
    g: t.int64
    h: t.uint64
    i: t.float32
    j: t.float64
    k: bool
    l: t.char
    m: Color


@final
@dataclass
class Point(IdlStruct, typename="Point"):
    x: t.int32
    y: t.float64


@final
@dataclass
class Strings(IdlStruct, typename="Strings"):
    empty: str
    hello: str
    b: t.uint8
    list: t.sequence[str]


@final
@dataclass
class Seqs(IdlStruct, typename="Seqs"):
    i32: t.sequence[t.int32]
    i16: t.sequence[t.int16]
    u8: t.sequence[t.uint8]
    f64: t.sequence[t.float64]
    flags: t.sequence[bool]
    colors: t.sequence[Color]
    empty: t.sequence[t.int64]


@final
@dataclass
class Nested(IdlStruct, typename="Nested"):
    tag: t.uint8
    p: Point
    pts: t.sequence[Point]
    arr: t.array[Point, 2]
    grid: t.array[t.array[t.int16, 3], 2]
    names: t.array[str, 2]
    seqseq: t.sequence[t.sequence[t.int32]]


@appendable
@dataclass
class AppInner(IdlStruct, typename="AppInner"):
    v: t.int16
    s: str


@appendable
@dataclass
class App(IdlStruct, typename="App"):
    id: t.int32
    inner: AppInner
    d: t.float64
    items: t.sequence[AppInner]


@mutable
@dataclass
class Mut(IdlStruct, typename="Mut"):
    a: t.int8
    b: t.int16
    c: t.int32
    d: t.int64
    s: str
    color: Color
    flag: bool
    p: Point
    si32: t.sequence[t.int32]
    si16: t.sequence[t.int16]
    su8: t.sequence[t.uint8]
    sf64: t.sequence[t.float64]
    spts: t.sequence[Point]
    arr: t.array[t.int32, 2]
    sarr: t.array[str, 2]
    opt: Optional[t.int32]
    optp: Optional[Point]


@final
@dataclass
class Opt(IdlStruct, typename="Opt"):
    a: t.uint8
    x: Optional[t.int32]
    d: Optional[t.float64]
    s: Optional[str]
    z: t.int16


@final
@dataclass
class Keyed(IdlStruct, typename="Keyed"):
    id: t.int32
    key("id")
    name: str
    key("name")
    value: t.float64


@mutable
@dataclass
class MutKeyed(IdlStruct, typename="MutKeyed"):
    id: t.int32
    key("id")
    value: str


@final
@dataclass
class HelloWorld(IdlStruct, typename="HelloWorld"):
    id: t.int32
    msg: str


LE, BE = Endianness.Little, Endianness.Big
ENCODINGS = {"x1le": (False, LE), "x1be": (False, BE), "x2le": (True, LE), "x2be": (True, BE)}

CASES = [
    ("prims", "Prims", Prims(-5, 250, -1234, 54321, -123456789, 3000000000, -1234567890123, 18000000000000000000, 1.5, -2.25, True, 'Z', Color.BLUE)),
    ("point", "Point", Point(7, 0.5)),
    ("strings", "Strings", Strings("", "hello", 9, ["a", "", "xyz"])),
    ("seqs", "Seqs", Seqs([1, -2, 3], [4, -5], [6, 7, 8], [0.5, -1.0], [True, False, True], [Color.GREEN, Color.RED], [])),
    ("nested", "Nested", Nested(1, Point(2, 3.5), [Point(4, 4.5), Point(5, 5.5)], [Point(6, 6.5), Point(7, 7.5)], [[1, 2, 3], [4, 5, 6]], ["ab", ""], [[1], [], [2, 3]])),
    ("appendable", "App", App(42, AppInner(3, "in"), 1.25, [AppInner(1, "a"), AppInner(2, "bc")])),
    ("mutable", "Mut", Mut(-1, 2, 3, 4, "mut", Color.GREEN, True, Point(9, 9.5), [1, 2], [3, 4, 5], [6, 7, 8, 9, 10], [1.5], [Point(1, 1.5)], [11, 12], ["x", "yz"], 77, Point(8, 8.5))),
    ("mutable_absent", "Mut", Mut(0, 0, 0, 0, "", Color.RED, False, Point(0, 0.0), [], [], [], [], [], [0, 0], ["", ""], None, None)),
    ("optional_present", "Opt", Opt(1, 5, 2.5, "opt", -1)),
    ("optional_absent", "Opt", Opt(1, None, None, None, -1)),
    ("keyed", "Keyed", Keyed(17, "key", 3.5)),
    ("mutkeyed", "MutKeyed", MutKeyed(17, "val")),
    ("hello", "HelloWorld", HelloWorld(0, "final #0")),
]

IDL = {
    "Prims": "@final struct Prims { int8 a; uint8 b; int16 c; uint16 d; int32 e; uint32 f; int64 g; uint64 h; float i; double j; boolean k; char l; Color m; }; enum Color { RED, GREEN, BLUE };",
    "Point": "@final struct Point { int32 x; double y; };",
    "Strings": "@final struct Strings { string empty; string hello; uint8 b; sequence<string> list; };",
    "Seqs": "@final struct Seqs { sequence<int32> i32; sequence<int16> i16; sequence<uint8> u8; sequence<double> f64; sequence<boolean> flags; sequence<Color> colors; sequence<int64> empty; };",
    "Nested": "@final struct Nested { uint8 tag; Point p; sequence<Point> pts; Point arr[2]; int16 grid[2][3]; string names[2]; sequence<sequence<int32>> seqseq; };",
    "App": "@appendable struct AppInner { int16 v; string s; }; @appendable struct App { int32 id; AppInner inner; double d; sequence<AppInner> items; };",
    "Mut": "@mutable struct Mut { int8 a; int16 b; int32 c; int64 d; string s; Color color; boolean flag; Point p; sequence<int32> si32; sequence<int16> si16; sequence<uint8> su8; sequence<double> sf64; sequence<Point> spts; int32 arr[2]; string sarr[2]; @optional int32 opt; @optional Point optp; };",
    "Opt": "@final struct Opt { uint8 a; @optional int32 x; @optional double d; @optional string s; int16 z; };",
    "Keyed": "@final struct Keyed { @key int32 id; @key string name; double value; };",
    "MutKeyed": "@mutable struct MutKeyed { @key int32 id; string value; };",
    "HelloWorld": "@final struct HelloWorld { int32 id; string msg; };",
}

KEY_CASES = [("keyed", Keyed(17, "key", 3.5)), ("mutkeyed", MutKeyed(17, "val"))]


def write(name, comment, data):
    lines = [data[i:i + 32].hex() for i in range(0, len(data), 32)]
    with open(os.path.join(OUT, name + ".hex"), "w") as f:
        f.write("# " + comment + "\n")
        f.write("\n".join(lines) + "\n")


def main():
    os.makedirs(OUT, exist_ok=True)
    for case, tname, value in CASES:
        for enc, (v2, endian) in ENCODINGS.items():
            data = value.serialize(use_version_2=v2, endianness=endian)
            # the pure-Python serializer must read back what it wrote
            assert type(value).deserialize(data) == value, (case, enc)
            write(f"{case}_{enc}", f"IDL {IDL[tname]} value {value!r}; "
                  f"{type(value).__name__}.serialize(use_version_2={v2}, endianness={endian.name}); cyclonedds {VERSION} (PyPI)", data)
    for case, value in KEY_CASES:
        for enc, (v2, endian) in ENCODINGS.items():
            data = value.serialize_key(use_version_2=v2, endianness=endian)
            write(f"key_{case}_{enc}", f"IDL {IDL[type(value).__name__]} value {value!r}; "
                  f"{type(value).__name__}.serialize_key(use_version_2={v2}, endianness={endian.name}) (key members only, with encapsulation header); cyclonedds {VERSION} (PyPI)", data)
    print(f"wrote fixtures to {os.path.normpath(OUT)} with cyclonedds {VERSION}", file=sys.stderr)


if __name__ == "__main__":
    main()

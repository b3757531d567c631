//! `courier gen` on malformed input: one test per error class, each
//! pinning the message with its file:line:column.

use courier_broker::gen::{self, FsLoader, GenError, Input, Lang};

fn err(lang: Lang, file: &str, text: &str) -> String {
    match gen::generate(lang, &[Input::new(file, text)], &FsLoader::default()) {
        Ok(code) => panic!("{file} generated code:\n{code}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn unknown_type() {
    assert_eq!(
        err(
            Lang::Idl,
            "bad.idl",
            "module m {\n  struct S { Foo f; };\n};\n"
        ),
        "bad.idl:2:14: unknown type `Foo`"
    );
    assert_eq!(
        err(Lang::Ipc, "bad.ipc", "T = {int, Foo}\n"),
        "bad.ipc:1:11: unknown type `Foo`"
    );
    assert_eq!(
        err(Lang::Xdr, "bad.xdr", "struct S {\n  Missing m;\n};\n"),
        "bad.xdr:2:3: unknown type `Missing`"
    );
}

#[test]
fn unterminated_struct() {
    assert_eq!(
        err(Lang::Idl, "bad.idl", "struct S {\n  long a;\n"),
        "bad.idl:3:1: unterminated struct `S` (opened at 1:10): expected `}`, found end of file"
    );
    assert_eq!(
        err(Lang::Xdr, "bad.xdr", "struct S {\n  int a;\n"),
        "bad.xdr:3:1: unterminated struct `S` (opened at 1:10): expected `}`, found end of file"
    );
    assert_eq!(
        err(
            Lang::Idl,
            "bad.idl",
            "/* never closed\nstruct S { long a; };\n"
        ),
        "bad.idl:3:1: unterminated comment (opened at 1:1): expected `*/`, found end of file"
    );
    // IPC: the format parser of courier_wire, at the byte it stopped
    assert_eq!(
        err(Lang::Ipc, "bad.ipc", "T1 = {int,\n      [double:2,3}\n"),
        "bad.ipc:2:18: bad IPC format: expected ',' or ']' after an array dimension, found '}'"
    );
}

#[test]
fn bad_array_bound() {
    assert_eq!(
        err(Lang::Idl, "bad.idl", "struct S { long a[0]; };\n"),
        "bad.idl:1:19: bad array bound 0: an array dimension must be an integer from 1 to 2147483647"
    );
    assert_eq!(
        err(Lang::Idl, "bad.idl", "const long N = 2 - 3;\nstruct S { sequence<long, N> a; };\n"),
        "bad.idl:2:27: bad array bound -1: a sequence bound must be an integer from 1 to 2147483647"
    );
    assert_eq!(
        err(Lang::Xdr, "bad.xdr", "struct S {\n  int a[-2];\n};\n"),
        "bad.xdr:2:9: bad array bound -2: a fixed-length array needs a length from 1 to 2147483647"
    );
}

#[test]
fn recursive_type() {
    assert_eq!(
        err(
            Lang::Idl,
            "bad.idl",
            "struct A;\nstruct B { A a; };\nstruct A { B b; };\n"
        ),
        "bad.idl:3:8: recursive type `A` contains itself by value (A -> B -> A); break the cycle \
         with a sequence, an @optional member or a pointer"
    );
    assert_eq!(
        err(Lang::Ipc, "bad.ipc", "Node = {int, Node}\n"),
        "bad.ipc:1:1: recursive type `Node` contains itself by value (Node -> Node); break the \
         cycle with a sequence, an @optional member or a pointer"
    );
    // through a sequence or a pointer, it is a list
    gen::generate(
        Lang::Idl,
        &[Input::new(
            "ok.idl",
            "struct A;\nstruct A { sequence<A> children; };\n",
        )],
        &FsLoader::default(),
    )
    .unwrap();
}

#[test]
fn duplicate_name() {
    assert_eq!(
        err(
            Lang::Idl,
            "bad.idl",
            "module m {\n  struct S { long a; };\n  enum S { X };\n};\n"
        ),
        "bad.idl:3:8: duplicate name `m::S` (first defined at bad.idl:2:10)"
    );
    assert_eq!(
        err(Lang::Idl, "bad.idl", "struct S { long a; double a; };\n"),
        "bad.idl:1:27: duplicate name `S.a` (first defined at bad.idl:1:17)"
    );
    assert_eq!(
        err(Lang::Ipc, "bad.ipc", "T = int\n\nT = double\n"),
        "bad.ipc:3:1: duplicate name `T` (first defined at bad.ipc:1:1)"
    );
}

#[test]
fn unsupported_constructs() {
    assert_eq!(
        err(
            Lang::Idl,
            "bad.idl",
            "union U switch (long) { case 1: long a; };\n"
        ),
        "bad.idl:1:1: IDL `union` is not supported: #[derive(IpcMessage)] has no unions; use a \
         struct with an enum discriminator and @optional members"
    );
    assert_eq!(
        err(Lang::Idl, "bad.idl", "struct S { wstring w; };\n"),
        "bad.idl:1:12: IDL `wstring` is not supported: wide characters have no IPC or Courier \
         type; use `char` / `string` (UTF-8)"
    );
    assert_eq!(
        err(Lang::Idl, "bad.idl", "#define N 3\n"),
        "bad.idl:1:1: the directive `#define` is not supported: courier gen reads `#include` \
         and skips `#pragma`; run other preprocessor directives through cpp first"
    );
    // a size field of another type, and too few size fields
    for (fields, line) in [("int rows;\n  double cols;", 4), ("int cols;", 3)] {
        assert_eq!(
            err(
                Lang::Xdr,
                "bad.xdr",
                &format!("struct Image {{\n  {fields}\n  unsigned char data<><>;\n}};\n")
            ),
            format!(
                "bad.xdr:{line}:17: 2-dimensional variable-length array `data` is not preceded \
                 by the 2 int or unsigned int fields that hold its dimensions"
            )
        );
    }
    assert_eq!(
        err(
            Lang::Xdr,
            "bad.xdr",
            "union U switch (int k) { case 0: int a; };\n"
        ),
        "bad.xdr:1:1: XDR `union` is not supported: xdrgen does not implement unions (IPC has \
         no union type); use a struct with an enum tag"
    );
    assert_eq!(
        err(Lang::Ipc, "bad.ipc", "T = {int, short, <int:1,2>}\n"),
        "bad.ipc:1:1: the variable array `<int:1,2>` sized by field 2 of format `short` is not \
         supported: the size fields of a multi-dimensional array must be `int`, `uint`, `long` \
         or `ulong` (C's IPC reads them as `int`)"
    );
}

#[test]
fn xdr_variable_array_needs_its_count() {
    assert_eq!(
        err(
            Lang::Xdr,
            "bad.xdr",
            "struct S {\n  string name<>;\n  float v<>;\n};\n"
        ),
        "bad.xdr:3:9: variable-length array `v` is not preceded by the int or unsigned int field \
         that holds its length"
    );
}

#[test]
fn missing_include() {
    let e = gen::generate(
        Lang::Idl,
        &[Input::new("dir/a.idl", "\n#include \"nowhere/b.idl\"\n")],
        &FsLoader::default(),
    )
    .unwrap_err();
    assert!(matches!(e, GenError::Include { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "dir/a.idl:2:1: cannot find included file \"nowhere/b.idl\" (looked in dir, .)"
    );
}

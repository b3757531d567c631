//! `courier gen` on the command line: exit codes and messages.

use std::path::Path;
use std::process::{Command, Output};

fn courier(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(args)
        .output()
        .expect("run courier")
}

fn inputs() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/gen/inputs")
}

#[test]
fn bad_flags_are_usage_errors() {
    for (args, says) in [
        (
            &["gen", "ipc", "x.ipc", "--bogus"][..],
            "unexpected argument '--bogus'",
        ),
        (
            &["gen", "cobol", "x.cob"],
            "[possible values: ipc, xdr, idl]",
        ),
        (
            &["gen", "idl"],
            "the following required arguments were not provided",
        ),
    ] {
        let out = courier(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    }
}

#[test]
fn a_missing_file_names_its_path() {
    let out = courier(&["gen", "xdr", "no/such/file.xdr"]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.starts_with("courier gen: cannot read no/such/file.xdr: "),
        "{stderr}"
    );
}

#[test]
fn a_malformed_file_names_the_place() {
    let dir = std::env::temp_dir().join(format!("courier-gen-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.idl");
    std::fs::write(&bad, "struct S {\n  Foo f;\n};\n").unwrap();
    let out = courier(&["gen", "idl", bad.to_str().unwrap()]);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&out.stderr).trim_end(),
        format!("courier gen: {}:2:3: unknown type `Foo`", bad.display())
    );
    assert!(out.stdout.is_empty());
}

#[test]
fn writes_the_golden_output() {
    let dir = std::env::temp_dir().join(format!("courier-gen-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out_file = dir.join("types.rs");
    let input = inputs().join("manual.xdr");
    let out = courier(&[
        "gen",
        "xdr",
        input.to_str().unwrap(),
        "-o",
        out_file.to_str().unwrap(),
    ]);
    let written = std::fs::read_to_string(&out_file);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let want = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/gen/expected/manual_xdr.rs"),
    )
    .unwrap();
    assert_eq!(written.unwrap(), want);
    // and to stdout by default
    let out = courier(&["gen", "xdr", input.to_str().unwrap()]);
    assert_eq!(String::from_utf8_lossy(&out.stdout), want);
}

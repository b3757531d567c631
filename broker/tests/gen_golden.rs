//! `courier gen` golden tests: each input under `tests/gen/inputs/` is
//! translated and compared byte for byte with `tests/gen/expected/`.
//! `COURIER_BLESS=1 cargo test -p courier-broker --test gen_golden`
//! rewrites the expected files instead (review the diff before committing).

use std::path::{Path, PathBuf};

use courier_broker::gen::{self, FsLoader, Input, Lang, Options};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/gen")
}

/// Generates `expected` from `inputs` (paths under `inputs/`) and compares.
fn golden(lang: Lang, inputs: &[&str], expected: &str, options: &Options) {
    let inputs: Vec<Input> = inputs
        .iter()
        .map(|p| Input::read(&dir().join("inputs").join(p)).unwrap())
        .collect();
    let got = gen::generate_with(lang, &inputs, &FsLoader::default(), options)
        .unwrap_or_else(|e| panic!("{expected}: {e}"));
    let path = dir().join("expected").join(expected);
    if std::env::var_os("COURIER_BLESS").is_some_and(|v| v == "1") {
        std::fs::write(&path, &got).unwrap();
        return;
    }
    let want = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (COURIER_BLESS=1 writes it)", path.display()));
    if got != want {
        let line = got
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| got.lines().count().min(want.lines().count()))
            + 1;
        panic!(
            "{} differs from the generated code at line {line}:\n  generated: {:?}\n  expected:  {:?}\n(COURIER_BLESS=1 rewrites it)",
            path.display(),
            got.lines().nth(line - 1),
            want.lines().nth(line - 1),
        );
    }
}

#[test]
fn ipc_manual_formats() {
    golden(
        Lang::Ipc,
        &["manual.ipc"],
        "manual_ipc.rs",
        &Options::default(),
    );
}

#[test]
fn xdr_manual_examples() {
    golden(
        Lang::Xdr,
        &["manual.xdr"],
        "manual_xdr.rs",
        &Options::default(),
    );
}

/// A ROS 2 message set as rosidl writes IDL, with ROS 2's DDS type names;
/// the files `#include` each other by package path.
#[test]
fn idl_ros2_messages() {
    golden(
        Lang::Idl,
        &[
            "ros2/sensor_msgs/msg/Imu.idl",
            "ros2/sensor_msgs/msg/NavSatStatus.idl",
            "ros2/geometry_msgs/msg/PoseStamped.idl",
            "ros2/geometry_msgs/msg/Twist.idl",
            "ros2/example_interfaces/srv/AddTwoInts.idl",
        ],
        "ros2_idl.rs",
        &{
            let mut o = Options::default();
            o.ros2_names = true;
            o
        },
    );
}

#[test]
fn idl_cyclone_types() {
    golden(
        Lang::Idl,
        &["cyclone.idl"],
        "cyclone_idl.rs",
        &Options::default(),
    );
}

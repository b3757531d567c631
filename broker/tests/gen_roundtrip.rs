//! The code `courier gen` generated (the golden files under
//! `tests/gen/expected/`) compiles, its IPC formats are those of the input,
//! and its values survive IPC marshalling and CDR (XCDR1, XCDR2).

use std::path::Path;

use courier::cdr::{self, Encoding};
use courier::format::{self, Format, FormatRegistry};
use courier::{ipc, IpcMessage, NamedFormats};
use courier_broker::gen::{self, Input};

#[allow(dead_code)]
mod manual_ipc {
    include!("gen/expected/manual_ipc.rs");
}

#[allow(dead_code)]
mod manual_xdr {
    /// `ipc_type ExternalStruct1;` names a type the including code
    /// provides (in C, with its `ExternalStruct1_IPC_FORMAT` macro).
    #[derive(courier::IpcMessage, Debug, Clone, PartialEq)]
    pub struct ExternalStruct1 {
        pub foo: i32,
        pub goo: i32,
    }

    include!("gen/expected/manual_xdr.rs");
}

/// The same generated files included again elsewhere, as a second program
/// would: their types must keep their DDS type names.
#[allow(dead_code)]
mod again {
    pub mod ipc {
        include!("gen/expected/manual_ipc.rs");
    }
    pub mod xdr {
        pub use crate::manual_xdr::ExternalStruct1;
        include!("gen/expected/manual_xdr.rs");
    }
}

#[allow(dead_code)]
mod ros2_idl {
    include!("gen/expected/ros2_idl.rs");
}

#[allow(dead_code)]
mod cyclone_idl {
    include!("gen/expected/cyclone_idl.rs");
}

/// `value` encodes and decodes to itself in IPC and in every CDR encoding.
fn round_trip<T: IpcMessage + PartialEq + std::fmt::Debug>(value: &T) {
    let bytes = ipc::to_vec(value);
    assert_eq!(&ipc::from_slice::<T>(&bytes).unwrap(), value, "IPC");
    cdr_round_trip(value);
}

/// `value` survives every CDR encoding.
fn cdr_round_trip<T: IpcMessage + PartialEq + std::fmt::Debug>(value: &T) {
    for enc in [
        Encoding::Xcdr1Le,
        Encoding::Xcdr1Be,
        Encoding::Xcdr2Le,
        Encoding::Xcdr2Be,
    ] {
        let bytes = cdr::to_vec(value, enc);
        assert_eq!(&cdr::from_slice::<T>(&bytes).unwrap(), value, "{enc:?}");
    }
}

/// The formats an IPC input defines, by name.
fn input_formats(file: &str) -> FormatRegistry {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/gen/inputs")
        .join(file);
    let input = Input::read(&path).unwrap();
    let mut reg = FormatRegistry::new();
    for (name, f) in gen::ipc::formats(&input).unwrap() {
        if f != Format::Empty {
            reg.insert(&name, f).unwrap();
        }
    }
    reg
}

/// `T`'s format, with the named formats it uses expanded.
fn expanded<T: IpcMessage>() -> String {
    let mut reg = FormatRegistry::new();
    for (name, f) in NamedFormats::of::<T>().iter() {
        reg.define(name, f).unwrap();
    }
    let f = format::parse(T::FORMAT).unwrap();
    reg.resolve(&f).unwrap().to_string()
}

/// The input's format `name`, expanded.
fn input_expanded(reg: &FormatRegistry, name: &str) -> String {
    reg.resolve(&Format::Named(name.into()))
        .unwrap()
        .to_string()
}

#[test]
fn ipc_formats_are_the_inputs() {
    use manual_ipc::*;
    let reg = input_formats("manual.ipc");
    // the generated format string is the input's, character for character
    // (a struct's format names the named formats it uses, as the input does)
    for (name, got) in [
        ("DATA1", Data1::FORMAT),
        ("Primitives", Primitives::FORMAT),
        ("Row", Row::FORMAT),
        ("Samples", Samples::FORMAT),
        ("Grid", Grid::FORMAT),
        ("Voxels", Voxels::FORMAT),
        ("POINTER_EXAMPLE", PointerExample::FORMAT),
        ("ENUM_TYPE", EnumType::FORMAT),
        ("Mixed", Mixed::FORMAT),
        ("point", Point::FORMAT),
        ("T1", T1::FORMAT),
        ("T2", T2::FORMAT),
        ("LIST", List::FORMAT),
        ("Matrix", Matrix::FORMAT),
        ("radians", Radians::FORMAT),
        ("message1", Message1::FORMAT),
        ("message2", Message2::FORMAT),
    ] {
        assert_eq!(got, reg.get(name).unwrap().to_string(), "{name}");
    }
    assert_eq!(
        T2::FORMAT,
        "{string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}"
    );
    assert_eq!(T2::FORMAT_NAME, Some("T2"));
    assert_eq!(Point::FORMAT_NAME, Some("point"));
    // aliases of named formats are written out where they are used: the
    // same format once names are expanded
    assert_eq!(TwoPointArrays::FORMAT, "{[point:5], [point:5]}");
    assert_eq!(
        expanded::<TwoPointArrays>(),
        input_expanded(&reg, "two-point-arrays")
    );
    assert_eq!(
        expanded::<PointArray>(),
        input_expanded(&reg, "point-array")
    );
    assert_eq!(expanded::<T2>(), input_expanded(&reg, "T2"));
}

#[test]
fn ipc_values_round_trip() {
    use manual_ipc::*;
    round_trip(&Data1(1, "two".into(), 3));
    round_trip(&Primitives(
        'x',
        -1,
        255,
        -300,
        60000,
        -70000,
        4_000_000_000,
        -(1 << 40),
        1 << 63,
        1.5,
        -2.25,
        true,
        "all".into(),
    ));
    round_trip(&Row(
        [1.0, 2.0, 3.0],
        ['a', 'b', 'c', 'd', 'e', 'f', 'g', 'h'],
    ));
    round_trip(&Samples(3, vec![0.5, 1.5, 2.5]));
    // the size fields are written from the shape
    round_trip(&Grid(
        2,
        3,
        courier::Matrix::new([2, 3], vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]).unwrap(),
    ));
    round_trip(&Voxels(
        1,
        courier::NdVec::from_fn([2, 1, 3], |[i, j, k]| (i * 3 + j + k) as f32).unwrap(),
        2,
        3,
    ));
    round_trip(&PointerExample(7, Some(Box::new(8))));
    round_trip(&PointerExample(7, None));
    round_trip(&List(
        1,
        Some(Box::new(List(2, Some(Box::new(List(3, None)))))),
    ));
    round_trip(&Mixed(
        4,
        MixedField2::C,
        [0.0, -1.0, 1e300],
        MixedField4::V10,
    ));
    let p = |x: f64| Point(x, x + 1.0, x + 2.0);
    round_trip(&TwoPointArrays(
        [p(0.0), p(1.0), p(2.0), p(3.0), p(4.0)],
        [p(5.0), p(6.0), p(7.0), p(8.0), p(9.0)],
    ));
    let t1 = |i: i32| {
        T1(
            i,
            T1Field2::V3,
            [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
            f64::from(i),
        )
    };
    round_trip(&T2(
        "hello".into(),
        2,
        vec![t1(1), t1(2)],
        T2Field4::ReceiveVal,
    ));
    round_trip(&T2(String::new(), 0, vec![], T2Field4::WaitVal));
    let m: Matrix = [[9; 42]; 17];
    round_trip(&m);
}

/// T1 as the C library marshals `{int, {enum : 3}, [double:2,3], double}`
/// on a little-endian host: each field in order, no padding.
#[test]
fn ipc_t1_golden_bytes() {
    use manual_ipc::*;
    let t1 = T1(5, T1Field2::V2, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], 0.5);
    let mut want = Vec::new();
    want.extend_from_slice(&5i32.to_le_bytes()); // int
    want.extend_from_slice(&2i32.to_le_bytes()); // {enum : 3}: V2 as a C int
    for d in [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0] {
        want.extend_from_slice(&d.to_le_bytes()); // [double:2,3], row-major
    }
    want.extend_from_slice(&0.5f64.to_le_bytes()); // double
    assert_eq!(ipc::to_vec(&t1), want);
    assert_eq!(want.len(), 64);
}

/// The IPC formats xdrgen gives the manual's examples (appendix B), with
/// named formats expanded.
#[test]
fn xdr_formats_are_xdrgens() {
    use manual_xdr::*;
    let canon = |s: &str| format::parse(s).unwrap().to_string();
    assert_eq!(Zoo::FORMAT, "{int, int}");
    assert_eq!(expanded::<Transform>(), canon("{[double:4,4]}"));
    assert_eq!(expanded::<Gamma>(), canon("{int, <float:1>}"));
    // xdrgen's `{int,int,<uchar:1,2>}`
    assert_eq!(expanded::<Image>(), canon("{int, int, <ubyte:1,2>}"));
    assert_eq!(
        expanded::<Volume>(),
        canon("{string, uint, int, int, <float:2,3,4>, float}")
    );
    assert_eq!(expanded::<Color>(), canon("{enum RED,ORANGE,YELLOW}"));
    assert_eq!(expanded::<Mixed>(), canon("int"));
    // xdrgen writes `uchar`, which no IPC library knows: `ubyte` is the
    // one-byte unsigned primitive
    assert_eq!(expanded::<ImagePixel>(), canon("[ubyte:3]"));
    assert_eq!(
        expanded::<ExecCall>(),
        canon("{{int,<string:1>},[string:20]}")
    );
    assert_eq!(expanded::<Roo>(), canon("{int, char}"));
    assert_eq!(
        expanded::<PrimitiveTypes>(),
        canon("{string, ubyte, char, uint, int, char, float, double}")
    );
    assert_eq!(
        expanded::<IncExternalStruct>(),
        canon("{int, {int, int}, {char, double}}")
    );
    assert_eq!(
        expanded::<MyNestedStruct>(),
        canon("{{int, {int}}, {char, {int, {int}}}}")
    );
    assert_eq!(
        expanded::<IncludesEnums>(),
        canon("{{enum RED,ORANGE,YELLOW}, {enum FOO,GOO,ZOO}, int}")
    );
    assert_eq!((TWO, FOUR, SIX), (2, 3, 6));
}

#[test]
fn xdr_values_round_trip() {
    use manual_xdr::*;
    round_trip(&Zoo { foo: 1, goo: 2 });
    round_trip(&Image {
        rows: 2,
        cols: 2,
        data: courier::Matrix::from_rows(vec![[1, 2], [3, 4]]).unwrap(),
    });
    round_trip(&Volume {
        label: "v".into(),
        depth: 1,
        height: 2,
        width: 1,
        voxels: courier::NdVec::filled([1, 2, 1], 0.5).unwrap(),
        scale: 2.0,
    });
    let inc = MyIncludableStruct {
        foo: 3,
        goo: MyIncludableStructGoo { a: 4 },
    };
    round_trip(&MyNestedStruct {
        b: inc.clone(),
        roo: MyNestedStructRoo { a: 'r', b2: inc },
    });
    round_trip(&PrimitiveTypes {
        a: "xdr".into(),
        b: 200,
        c: 'c',
        d: 3_000_000_000,
        e: -5,
        f: 1,
        g: 0.25,
        h: -8.5,
    });
    let px: ImagePixel = [1, 2, 3];
    round_trip(&px);
    let mut mat = [[0.0; 4]; 4];
    mat[1][2] = 12.0;
    round_trip(&Transform { mat });
    round_trip(&Alpha {
        size: 2,
        beta: vec![
            AlphaBeta {
                data: ['a', 'b', 'c', 'd', 'e'],
            },
            AlphaBeta {
                data: ['v', 'w', 'x', 'y', 'z'],
            },
        ],
    });
    round_trip(&Gamma {
        delta: 3,
        epsilon: vec![1.0, 2.0, 3.0],
    });
    round_trip(&IncludesEnums {
        color: Color::YELLOW,
        my_enum: IncludesEnumsMyEnum::GOO,
        mixed: SIX,
    });
    round_trip(&ExecCall {
        args: ExecCallArgs {
            argc: 2,
            argv: vec!["ls".into(), "-l".into()],
        },
        env_vars: std::array::from_fn(|i| format!("V{i}=1")),
    });
    round_trip(&Roo { a: 1, b: 'b' });
    round_trip(&IncExternalStruct {
        a: 1,
        s1: ExternalStruct1 { foo: 2, goo: 3 },
        s2: ExternalStruct2('s', 4.0),
    });
}

/// std_msgs/Header as a ROS 2 node sends it (XCDR1, little endian),
/// derived byte by byte from the CDR rules (DDS-XTypes 1.3 §7.4.1).
#[test]
fn idl_ros2_header_golden_bytes() {
    use ros2_idl::builtin_interfaces::msg::Time;
    use ros2_idl::std_msgs::msg::Header;
    let h = Header {
        stamp: Time { sec: 1, nanosec: 2 },
        frame_id: "map".into(),
    };
    let want = [
        0x00, 0x01, 0x00, 0x00, // encapsulation CDR_LE, options 0
        0x01, 0x00, 0x00, 0x00, // stamp.sec: int32 1 at offset 0
        0x02, 0x00, 0x00, 0x00, // stamp.nanosec: uint32 2 at offset 4
        0x04, 0x00, 0x00, 0x00, // frame_id length: 3 chars + NUL, at offset 8
        b'm', b'a', b'p', 0x00, // frame_id bytes and its NUL
    ];
    assert_eq!(cdr::to_vec(&h, Encoding::Xcdr1Le), want);
    assert_eq!(cdr::from_slice::<Header>(&want).unwrap(), h);
    assert_eq!(Header::TYPE_NAME, "std_msgs::msg::dds_::Header_");
    round_trip(&h);
}

/// example_interfaces/AddTwoInts: the request is two int64s, 8-aligned
/// from the end of the encapsulation header.
#[test]
fn idl_ros2_service_pair() {
    use ros2_idl::example_interfaces::srv::{AddTwoIntsRequest, AddTwoIntsResponse};
    let rq = AddTwoIntsRequest { a: 1, b: -2 };
    let mut want = vec![0x00, 0x01, 0x00, 0x00]; // CDR_LE
    want.extend_from_slice(&1i64.to_le_bytes()); // a at offset 0
    want.extend_from_slice(&(-2i64).to_le_bytes()); // b at offset 8
    assert_eq!(cdr::to_vec(&rq, Encoding::Xcdr1Le), want);
    assert_eq!(
        AddTwoIntsRequest::TYPE_NAME,
        "example_interfaces::srv::dds_::AddTwoInts_Request_"
    );
    assert_eq!(
        AddTwoIntsResponse::TYPE_NAME,
        "example_interfaces::srv::dds_::AddTwoInts_Response_"
    );
    round_trip(&rq);
    round_trip(&AddTwoIntsResponse { sum: -1 });
}

#[test]
fn idl_ros2_values_round_trip() {
    use ros2_idl::builtin_interfaces::msg::Time;
    use ros2_idl::geometry_msgs::msg::*;
    use ros2_idl::sensor_msgs::msg::{self as sensor, Imu, NavSatStatus};
    use ros2_idl::std_msgs::msg::Header;
    let header = Header {
        stamp: Time {
            sec: 10,
            nanosec: 500,
        },
        frame_id: "base_link".into(),
    };
    let q = Quaternion {
        x: 0.0,
        y: 0.0,
        z: 0.0,
        w: 1.0,
    };
    let v = |x: f64| Vector3 {
        x,
        y: -x,
        z: 2.0 * x,
    };
    round_trip(&PoseStamped {
        header: header.clone(),
        pose: Pose {
            position: Point {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            },
            orientation: q.clone(),
        },
    });
    round_trip(&Twist {
        linear: v(1.0),
        angular: v(0.5),
    });
    let cov: sensor::Double9 = [0.1, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1];
    round_trip(&Imu {
        header,
        orientation: q,
        orientation_covariance: cov,
        angular_velocity: v(0.25),
        angular_velocity_covariance: cov,
        linear_acceleration: v(9.81),
        linear_acceleration_covariance: [-1.0; 9],
    });
    use sensor::nav_sat_status_constants::*;
    round_trip(&NavSatStatus {
        status: STATUS_NO_FIX,
        service: SERVICE_GLONASS,
    });
    assert_eq!((STATUS_FIX, SERVICE_GPS), (0, 1));
}

#[test]
fn idl_cyclone_types_round_trip() {
    use courier::cdr::Extensibility;
    use cyclone_idl::hello_world_data::*;
    assert_eq!(Msg::TYPE_NAME, "HelloWorldData::Msg");
    assert_eq!(Msg::KEYS, ["user_id"]);
    assert_eq!(Reading::EXTENSIBILITY, Extensibility::Appendable);
    assert_eq!(Config::EXTENSIBILITY, Extensibility::Mutable);
    assert_eq!((MAX_NAME, GRID, SCALE, GREETING), (32, 2, 1500.0, "hello"));
    round_trip(&Msg {
        user_id: 7,
        message: "hi".into(),
    });
    // sequences are CDR-only: IPC counts arrays with a field
    let reading = Reading {
        sensor: "imu0".into(),
        level: Level::HIGH,
        values: vec![1.0, 2.0],
        raw: vec![0xde, 0xad],
        grid: [[1, 2, 3], [4, 5, 6]],
        tag: 'x',
        valid: true,
    };
    cdr_round_trip(&reading);
    // the IDL's bounds hold: `string<MAX_NAME>` (through its typedef),
    // `sequence<double, 16>`
    assert_eq!(reading.check_lengths(), Ok(()));
    let long = Reading {
        sensor: "s".repeat(33),
        ..reading.clone()
    };
    assert_eq!(
        long.check_lengths().unwrap_err().to_string(),
        "field `sensor` has 33 bytes, more than its bound of 32"
    );
    let long = Reading {
        values: vec![0.0; 17],
        ..reading
    };
    assert_eq!(long.check_lengths().unwrap_err().field(), "values");
    let history = vec![Msg {
        user_id: 1,
        message: "a".into(),
    }];
    cdr_round_trip(&Config {
        port: 7400,
        note: Some(Box::new("n".into())),
        big: -1,
        history,
    });
    cdr_round_trip(&Config {
        port: 0,
        note: None,
        big: 0,
        history: vec![],
    });
}

/// Two modules that include the same `gen ipc` / `gen xdr` output give its
/// types the same DDS type name (the input's names, not the module path),
/// so that two programs including one file match on DDS.
#[test]
fn the_same_generated_types_have_one_dds_name_in_every_module() {
    fn same<A: IpcMessage, B: IpcMessage>(want: &str) {
        assert_eq!((A::TYPE_NAME, B::TYPE_NAME), (want, want));
    }
    same::<manual_ipc::Data1, again::ipc::Data1>("DATA1");
    same::<manual_ipc::T2, again::ipc::T2>("T2");
    same::<manual_ipc::T2Field4, again::ipc::T2Field4>("T2Field4");
    same::<manual_ipc::EnumType, again::ipc::EnumType>("ENUM_TYPE");
    same::<manual_xdr::Zoo, again::xdr::Zoo>("Zoo");
    same::<manual_xdr::MyNestedStructRoo, again::xdr::MyNestedStructRoo>("MyNestedStructRoo");
    same::<manual_xdr::Color, again::xdr::Color>("Color");
}

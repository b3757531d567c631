//! `#[derive(IpcMessage)]` in a crate that depends on `courier` under
//! another name (`courier2 = { package = "courier", .. }`), without
//! `#[ipc(crate = "...")]`: the derive finds the name in this crate's
//! `Cargo.toml`. It failed with "could not find `courier`".

use courier2::IpcMessage;

#[derive(IpcMessage, Debug, PartialEq)]
struct Pose {
    x: f64,
    y: f64,
    #[ipc(key)]
    id: i32,
}

#[test]
fn the_derive_finds_a_renamed_courier() {
    assert_eq!(Pose::FORMAT, "{double, double, int}");
    let p = Pose {
        x: 1.5,
        y: -2.0,
        id: 7,
    };
    let bytes = courier2::ipc::to_vec(&p);
    assert_eq!(courier2::ipc::from_slice::<Pose>(&bytes).unwrap(), p);
    let cdr = courier2::cdr::to_vec(&p, courier2::cdr::Encoding::Xcdr2Le);
    assert_eq!(courier2::cdr::from_slice::<Pose>(&cdr).unwrap(), p);
}

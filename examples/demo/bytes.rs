//! `--bytes`: what each protocol carries for one value.

use courier::cdr::{self, Encoding};
use courier::{ipc, IpcMessage};

/// Bytes in groups of four, in hex.
fn hex(b: &[u8]) -> String {
    b.chunks(4)
        .map(|c| c.iter().map(|x| format!("{x:02x}")).collect::<String>())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Prints `v`'s IPC format, its IPC bytes (as the C library marshals them)
/// and its CDR bytes (as DDS and XRCE carry them).
pub fn show<T: IpcMessage + std::fmt::Debug>(v: &T) {
    println!("{v:?}");
    println!("  IPC format      {}", T::FORMAT);
    println!("  DDS type name   {}", T::TYPE_NAME);
    let bytes = ipc::to_vec(v);
    println!("  IPC bytes  ({:>3}) {}", bytes.len(), hex(&bytes));
    for enc in [Encoding::Xcdr1Le, Encoding::Xcdr2Le] {
        let c = cdr::to_vec(v, enc);
        println!("  {enc:?} ({:>3}) {}", c.len(), hex(&c));
    }
    println!();
}

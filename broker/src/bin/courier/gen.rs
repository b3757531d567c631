//! `courier gen`: Rust types from IPC formats, XDR or IDL files
//! (the library's `courier_broker::gen`), written to a file or stdout.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, ValueEnum};

use courier_broker::gen::{self, FsLoader, Input, Lang};

use crate::text::{err, write_stdout};

/// What `courier gen --help` says after the options.
pub const GEN_HELP: &str = "\
Input languages:
  ipc   IPC format strings, one `NAME = FORMAT` a line (a format may span lines
        while a bracket is open; # starts a comment), as given to IPC_defineFormat
        or IPC_defineMsg; names may be used in later formats. A struct becomes a
        tuple struct whose IPC format name is NAME.
  xdr   XDR as CMU IPC's xdrgen reads it (manual appendix B): typedef, struct,
        enum, ipc_type, fixed arrays [n], variable arrays <> counted by the int
        field before them, strings; %{ code %} sections are skipped.
  idl   OMG IDL as ROS 2 (rosidl) and Cyclone DDS write it: modules, structs,
        enums, typedefs, constants, sequences, arrays, bounded strings,
        #include (searched next to the including file, in its parent
        directories, then in -I directories), @key, @id, @optional,
        @final/@appendable/@mutable, @verbatim comments.
Every type derives courier::IpcMessage (IPC marshalling and CDR); the output
needs the `courier` crate. DDS type names (#[ipc(type_name)]): ipc and xdr give
each type the name the input gives it (NAME, the XDR struct or enum name; an
inline part its Rust name), idl its scoped name (pkg::msg::Name); so the types
match on DDS whichever module includes the output. Errors name FILE:LINE:COLUMN; exit 1 on any error.";

/// `courier gen` arguments.
#[derive(Args, Debug)]
pub struct GenArgs {
    /// The input language
    #[arg(value_enum)]
    pub lang: LangArg,
    /// Input files (types of all of them go into one output)
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Where to write the Rust code (- for stdout, the default)
    #[arg(short, long, value_name = "OUT.rs", default_value = "-")]
    pub output: String,
    /// IDL: a directory to search for #include files (repeat for more)
    #[arg(short = 'I', long = "include", value_name = "DIR")]
    pub include: Vec<PathBuf>,
    /// IDL: DDS type names as ROS 2 gives them (pkg::msg::dds_::Name_)
    #[arg(long)]
    pub ros2_names: bool,
}

/// The input languages, as the command line names them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LangArg {
    /// IPC format strings
    Ipc,
    /// XDR as IPC's xdrgen reads it
    Xdr,
    /// OMG IDL (ROS 2, Cyclone DDS)
    Idl,
}

impl From<LangArg> for Lang {
    fn from(l: LangArg) -> Lang {
        match l {
            LangArg::Ipc => Lang::Ipc,
            LangArg::Xdr => Lang::Xdr,
            LangArg::Idl => Lang::Idl,
        }
    }
}

/// Runs `courier gen`: 0 when the code is written, 1 on any error.
pub fn run(args: GenArgs) -> ExitCode {
    match generate(&args) {
        Ok(None) => ExitCode::SUCCESS,
        Ok(Some(code)) => write_stdout("gen", code.as_bytes()),
        Err(e) => {
            err(format_args!("courier gen: {e}"));
            ExitCode::from(1)
        }
    }
}

/// Writes the code to the file named, or gives it back for stdout.
fn generate(args: &GenArgs) -> Result<Option<String>, String> {
    let mut inputs = Vec::new();
    for p in &args.inputs {
        inputs.push(Input::read(p).map_err(|e| e.to_string())?);
    }
    let loader = FsLoader {
        include_dirs: args.include.clone(),
    };
    let mut options = gen::Options::default();
    options.ros2_names = args.ros2_names;
    let code = gen::generate_with(args.lang.into(), &inputs, &loader, &options)
        .map_err(|e| e.to_string())?;
    if args.output == "-" {
        Ok(Some(code))
    } else {
        std::fs::write(&args.output, code)
            .map(|()| None)
            .map_err(|e| format!("cannot write {}: {e}", args.output))
    }
}

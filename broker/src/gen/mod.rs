//! `courier gen`: Rust types with `#[derive(IpcMessage)]` from IPC format
//! strings, from XDR files as CMU IPC's `xdrgen` reads them, and from OMG
//! IDL (the subset ROS 2 and Cyclone DDS use).
//!
//! Parsing and writing are pure functions: the only I/O is the reading of
//! included IDL files, done through a [`Loader`] ([`FsLoader`] reads the
//! file system). Errors are [`GenError`]s naming file, line and column.
//!
//! ```
//! use courier_broker::gen::{self, Input, Lang};
//!
//! let input = Input::new("manual.ipc", "T1 = {int, {enum : 3}, [double:2,3], double}\n");
//! let rust = gen::generate(Lang::Ipc, &[input], &gen::FsLoader::default())?;
//! assert!(rust.contains("pub struct T1(pub i32, pub T1Field2, pub [[f64; 3]; 2], pub f64);"));
//! # Ok::<(), gen::GenError>(())
//! ```
//!
//! What each language becomes is described in [`ipc`], [`xdr`] and [`idl`].
//! Every generated struct and enum derives `Debug`, `Clone`, `PartialEq`
//! and `courier::IpcMessage`, so the output compiles in any crate that
//! depends on `courier`.

mod error;
pub mod idl;
pub mod ipc;
mod lex;
mod model;
mod names;
mod rust;
pub mod xdr;

use std::path::{Path, PathBuf};

pub use error::{GenError, Pos};

/// One input file: its text and how to name it.
#[derive(Debug, Clone)]
pub struct Input {
    /// The path as the user gave it (errors name it).
    pub path: String,
    /// The name generated doc comments give it (the file name).
    pub name: String,
    /// The contents.
    pub text: String,
}

impl Input {
    /// An input read from `path` (its doc name is the file name).
    pub fn new(path: impl Into<String>, text: impl Into<String>) -> Self {
        let path = path.into();
        let name = Path::new(&path)
            .file_name()
            .map_or_else(|| path.clone(), |n| n.to_string_lossy().into_owned());
        Input {
            path,
            name,
            text: text.into(),
        }
    }

    /// Reads `path`.
    pub fn read(path: &Path) -> Result<Self, GenError> {
        let text = std::fs::read_to_string(path).map_err(|source| GenError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Input::new(path.display().to_string(), text))
    }
}

/// The input language.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lang {
    /// IPC format strings: `NAME = FORMAT` lines (see [`ipc`]).
    Ipc,
    /// XDR as `xdrgen` reads it (see [`xdr`]).
    Xdr,
    /// OMG IDL (see [`idl`]).
    Idl,
}

impl Lang {
    /// The name `courier gen` takes.
    pub fn name(self) -> &'static str {
        match self {
            Lang::Ipc => "ipc",
            Lang::Xdr => "xdr",
            Lang::Idl => "idl",
        }
    }
}

/// Where `#include`d files come from.
pub trait Loader {
    /// The text of `path`.
    fn load(&self, path: &Path) -> std::io::Result<String>;
    /// True if `path` exists.
    fn exists(&self, path: &Path) -> bool;
    /// Directories searched after the including file's own and its
    /// parents (`-I`).
    fn include_dirs(&self) -> Vec<PathBuf> {
        Vec::new()
    }
}

/// Reads included files from the file system, searching the including
/// file's directory, its ancestors, then `include_dirs`.
#[derive(Debug, Clone, Default)]
pub struct FsLoader {
    /// Extra directories to search (`-I`).
    pub include_dirs: Vec<PathBuf>,
}

impl Loader for FsLoader {
    fn load(&self, path: &Path) -> std::io::Result<String> {
        std::fs::read_to_string(path)
    }
    fn exists(&self, path: &Path) -> bool {
        path.is_file()
    }
    fn include_dirs(&self) -> Vec<PathBuf> {
        self.include_dirs.clone()
    }
}

/// Choices of the generated code.
#[derive(Debug, Clone, Default)]
#[non_exhaustive]
pub struct Options {
    /// IDL: DDS type names as ROS 2 gives them: `pkg::msg::dds_::Name_`
    /// for a struct `Name` in modules `pkg::msg` (and `srv`, `action`),
    /// rather than `pkg::msg::Name`.
    pub ros2_names: bool,
}

/// Translates `inputs` (all in language `lang`, sharing one namespace)
/// to one Rust source file, with the default [`Options`].
pub fn generate(lang: Lang, inputs: &[Input], loader: &dyn Loader) -> Result<String, GenError> {
    generate_with(lang, inputs, loader, &Options::default())
}

/// [`generate`] with [`Options`].
pub fn generate_with(
    lang: Lang,
    inputs: &[Input],
    loader: &dyn Loader,
    options: &Options,
) -> Result<String, GenError> {
    let module = match lang {
        Lang::Ipc => ipc::translate(inputs)?,
        Lang::Xdr => xdr::translate(inputs)?,
        Lang::Idl => idl::translate(inputs, loader, options)?,
    };
    let sources: Vec<String> = inputs.iter().map(|i| i.name.clone()).collect();
    Ok(rust::emit(&module, lang.name(), &sources))
}

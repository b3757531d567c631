//! A DDS type the CLI reads or writes: one Courier knows by name, or any
//! type laid out as an IPC format (`--format`) under a type name (see
//! `cdr_value`). Used where the session must name the type itself: `call`
//! on DDS, and `echo`/`spy` on XRCE, whose agent creates the DDS reader.

use courier::format::Format;
use courier::TypeInfo;

use crate::values::{known_names, known_type, parse_value, Decoded, Known};
use crate::Result;

/// The DDS type `pub` and `call` use without `--type` (the samples of
/// `courier ping`), as their `--help` says.
pub const DEFAULT_TYPE: &str = "courier::Ping";

/// What an error about a VALUE adds when no `--type` was given: that the
/// type was the default, so that `hello` refused as not a value of `{uint,
/// ulong, string}` says why.
pub fn default_type_note(type_name: Option<&str>) -> &'static str {
    match type_name {
        Some(_) => "",
        None => {
            "; without --type the type is courier::Ping ([seq, stamp_ns, \"text\"]): \
             name another with --type (with --format for one Courier does not know)"
        }
    }
}

fn known(name: &str) -> Result<&'static Known> {
    Ok(known_type(name)
        .ok_or_else(|| format!("type {name:?} is not one Courier knows ({})", known_names()))?)
}

fn type_info(k: &Known) -> TypeInfo {
    TypeInfo::dynamic(Some(k.format), k.type_name)
}

/// One side of a DDS call: a type Courier knows, or any type laid out as
/// an IPC format (`--format` / `--reply-format`) under a type name.
pub enum DdsType {
    Known(&'static Known),
    Cdr(Format, &'static str),
}

impl DdsType {
    /// `type_name` (default `courier::Ping`) laid out as `format`, or the
    /// known type of that name.
    pub fn new(format: Option<&Format>, type_name: Option<&str>) -> Result<DdsType> {
        let name = type_name.unwrap_or(DEFAULT_TYPE);
        Ok(match format {
            Some(f) => DdsType::Cdr(f.clone(), Box::leak(name.to_string().into_boxed_str())),
            None => DdsType::Known(known(name)?),
        })
    }

    /// What the session announces.
    pub fn type_info(&self) -> TypeInfo {
        match self {
            DdsType::Known(k) => type_info(k),
            DdsType::Cdr(f, name) => {
                TypeInfo::dynamic(Some(Box::leak(f.to_string().into_boxed_str())), name)
            }
        }
    }

    /// A value given as text or JSON, in CDR.
    pub fn encode(&self, text: &str) -> Result<Vec<u8>> {
        Ok(match self {
            DdsType::Known(k) => k.encode(&parse_value(&k.parsed(), text)?)?,
            DdsType::Cdr(f, _) => crate::cdr_value::encode(f, &parse_value(f, text)?)?,
        })
    }

    /// Its layout as an IPC format.
    pub fn format(&self) -> Format {
        match self {
            DdsType::Known(k) => k.parsed(),
            DdsType::Cdr(f, _) => f.clone(),
        }
    }

    /// A sample's CDR, decoded.
    pub fn decode(&self, data: &[u8]) -> Result<Decoded> {
        Ok(match self {
            DdsType::Known(k) => Decoded::dds(Some(k.type_name), data)?,
            DdsType::Cdr(f, _) => Decoded::cdr(f, data)?,
        })
    }
}

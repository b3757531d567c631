//! IPC: does the format central holds for a message fit the subscriber's
//! type? The C library decodes by the sender's format and never looks at
//! the reader's type, so `{int}` read as `f32` gives a wrong value, not an
//! error. The IPC backend tags each sample with central's format; a typed
//! subscription checks it against its type once per format
//! ([`courier_wire::format::fits`]) and turns a misfit into
//! [`RecvError::FormatMismatch`] instead of decoding.

use std::sync::Arc;

use courier_wire::format::{self, Format, FormatRegistry};
use courier_wire::{IpcMessage, NamedFormats};

use crate::subscriber::RecvError;

/// The verdict on the last format seen (one subscription's).
#[derive(Debug, Default)]
pub(crate) struct FormatCheck {
    last: Option<(Arc<str>, Result<(), String>)>,
}

impl FormatCheck {
    /// `Err` if data of `theirs` (central's format of `msg`) does not read
    /// as `T`.
    pub(crate) fn check<T: IpcMessage>(
        &mut self,
        msg: &str,
        theirs: &Arc<str>,
    ) -> Result<(), RecvError> {
        let fresh = match &self.last {
            Some((seen, _)) => !Arc::ptr_eq(seen, theirs) && **seen != **theirs,
            None => true,
        };
        if fresh {
            self.last = Some((theirs.clone(), verdict::<T>(theirs)));
        }
        match &self.last {
            Some((_, Err(detail))) => Err(RecvError::FormatMismatch {
                msg: msg.to_string(),
                ty: std::any::type_name::<T>(),
                central: theirs.to_string(),
                detail: detail.clone(),
            }),
            _ => Ok(()),
        }
    }
}

/// `T`'s format with its named formats expanded, as central expands the
/// formats it holds.
fn expanded<T: IpcMessage>() -> Option<Format> {
    let mut names = FormatRegistry::new();
    for (name, f) in NamedFormats::of::<T>().iter() {
        names.define(name, f).ok()?;
    }
    names.resolve(&format::parse(T::FORMAT).ok()?).ok()
}

/// Whether data of `theirs` (a format central holds, expanded) reads as `T`.
pub(crate) fn verdict<T: IpcMessage>(theirs: &str) -> Result<(), String> {
    // what cannot be compared is not held against the data: decoding
    // still checks every byte
    let (Ok(theirs), Some(ours)) = (format::parse(theirs), expanded::<T>()) else {
        return Ok(());
    };
    format::fits(&theirs, &ours).map_err(|m| m.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(courier_derive::IpcMessage)]
    #[ipc(crate = "::courier_wire")]
    struct Inner {
        a: i32,
        b: f64,
    }

    #[derive(courier_derive::IpcMessage)]
    #[ipc(crate = "::courier_wire")]
    struct Outer {
        name: String,
        inner: Inner,
    }

    #[test]
    fn named_formats_are_expanded_and_misfits_named_once_per_format() {
        let mut c = FormatCheck::default();
        let good: Arc<str> = Arc::from("{string, {uint, double}}");
        assert_eq!(c.check::<Outer>("m", &good), Ok(()));
        let bad: Arc<str> = Arc::from("{string, {int, float}}");
        let e = c.check::<Outer>("m", &bad).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "m is sent as {{string, {{int, float}}}} (central's format), which does not \
                 fit {}: at field 2, field 2, the data has float where the reader has double",
                std::any::type_name::<Outer>()
            )
        );
        // the same format again: the same verdict
        assert!(c
            .check::<Outer>("m", &Arc::from("{string, {int, float}}"))
            .is_err());
        assert!(FormatCheck::default()
            .check::<i32>("n", &Arc::from("float"))
            .is_err());
        assert_eq!(
            FormatCheck::default().check::<u32>("n", &Arc::from("int")),
            Ok(())
        );
    }
}

//! IPC: does the format central holds for a message fit the subscriber's
//! type? The C library decodes by the sender's format and never looks at
//! the reader's type, so `{int}` read as `f32` gives a wrong value, not an
//! error. The IPC backend tags each sample with central's format; a typed
//! subscription checks it against its type once per format
//! ([`courier_wire::format::fits`]) and turns a misfit into
//! [`RecvError::FormatMismatch`] instead of decoding; a typed subscription
//! of a message whose format central holds already is refused at once
//! ([`subscribable`]). Queries, servers and first definitions check
//! central's format once per message and type ([`CentralFormats`]).

use std::sync::Arc;

use courier_wire::format::{self, Format, FormatRegistry};
use courier_wire::{IpcMessage, NamedFormats};

use crate::error::OpenError;
use crate::session::Session;
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

/// Whether data of `theirs` (a format central holds, expanded) reads as `T`:
/// what a reader (a subscriber, a server, a query's reply) needs. The
/// detail names `T` and its format, and where the data differs from it.
pub(crate) fn verdict<T: IpcMessage>(theirs: &str) -> Result<(), String> {
    // what cannot be compared is not held against the data: decoding
    // still checks every byte
    let (Ok(theirs), Some(ours)) = (format::parse(theirs), expanded::<T>()) else {
        return Ok(());
    };
    format::fits(&theirs, &ours).map_err(|m| {
        let ty = std::any::type_name::<T>();
        misfit(ty, &ours, &m, |data, t| {
            format!("the data has {data} where {ty} has {t}")
        })
    })
}

/// Whether data of `T` reads as `theirs` (a format central holds, which
/// the message's readers read by): what a definition (a publish, a query's
/// request, a server's definitions) must not break. The detail names `T`
/// and its format, and where it differs from central's.
pub(crate) fn written_verdict<T: IpcMessage>(theirs: &str) -> Result<(), String> {
    let (Ok(theirs), Some(ours)) = (format::parse(theirs), expanded::<T>()) else {
        return Ok(());
    };
    // (the data is `T`'s here: `m.theirs` is `T`'s part, `m.ours` central's)
    format::fits(&ours, &theirs).map_err(|m| {
        let ty = std::any::type_name::<T>();
        misfit(ty, &ours, &m, |t, held| {
            format!("{ty} has {t} where central's format has {held}")
        })
    })
}

/// `ty`'s format, and where it differs (`here` says the misfit's two
/// parts) unless that is at the top: the two whole formats, which the
/// message names already.
fn misfit(
    ty: &str,
    ours: &Format,
    m: &format::Misfit,
    here: impl FnOnce(&str, &str) -> String,
) -> String {
    if m.at.is_empty() {
        return format!("{ty}'s format is {ours}");
    }
    let shown = |s: &str| if s.is_empty() { "no data" } else { s }.to_string();
    let here = here(&shown(&m.theirs), &shown(&m.ours));
    format!("{ty}'s format is {ours}; at {}, {here}", m.at)
}

/// IPC: refuses a subscription of `msg` as `T` at once when central already
/// holds a format for it that `T` does not read (as a definition or a
/// publish is refused), instead of an `Ok` whose every message is then a
/// [`RecvError::FormatMismatch`]. A message central does not know yet (its
/// definer comes later), or whose format cannot be compared here, is
/// checked message by message ([`FormatCheck`]) as before.
pub(crate) async fn subscribable<T: IpcMessage>(
    session: &Session,
    msg: &str,
) -> Result<(), OpenError> {
    // (no name: the backend refuses it, before asking central anything)
    let (Some(ipc), false) = (session.backend.ipc(), msg.is_empty()) else {
        return Ok(());
    };
    // (a lookup that fails leaves it to the subscription, which fails the
    // same way when the connection is gone)
    let theirs = match ipc.look_up(msg).await {
        Ok(Some(info)) => info.res_format.map(|f| f.to_string()),
        _ => None,
    };
    let Some(theirs) = theirs.filter(|f| !names_formats(f)) else {
        return Ok(());
    };
    verdict::<T>(&theirs).map_err(|detail| OpenError::FormatMismatch {
        msg: msg.to_string(),
        ty: std::any::type_name::<T>(),
        central: theirs,
        detail,
    })
}

/// IPC: does the format central holds for a message fit a type this
/// session reads or writes it as? Looked up once per message and type (a
/// round trip to central the first time), for replies a query reads and
/// for messages the session defines (where C would replace another
/// module's definition); subscriptions and servers check each sample's
/// format ([`crate::format_check`]). The C library decodes by the
/// sender's format, so `{int}` read as `f32` is a wrong value, not an
/// error. Also the named formats the session defined.
/// Fits, or central's format and where it differs.
type Verdict = Result<(), (String, String)>;

#[derive(Debug, Default)]
pub(crate) struct CentralFormats {
    /// By message, then by type: a hit allocates nothing.
    verdicts: std::sync::Mutex<
        std::collections::HashMap<String, std::collections::HashMap<&'static str, Verdict>>,
    >,
    named: std::sync::Mutex<std::collections::HashMap<&'static str, &'static str>>,
}

impl CentralFormats {
    /// `Err((central's format, where they differ))` when data of `msg`
    /// as central holds it does not read as the type `ty` (`fits`).
    pub(crate) async fn check(
        &self,
        session: &Session,
        msg: &str,
        ty: &'static str,
        fits: fn(&str) -> Result<(), String>,
    ) -> Verdict {
        let lock = || self.verdicts.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(v) = lock().get(msg).and_then(|m| m.get(ty)) {
            return v.clone();
        }
        let Some(ipc) = session.backend.ipc() else {
            return Ok(());
        };
        // central's format (looked up as a C module does; the C central
        // dies of `x_ipc_getMessageInfo` for a name it does not know);
        // unknown (central does not know the message, holds no format, or
        // names other formats in it) is not held against the data, which
        // decoding still checks
        let theirs = match ipc.look_up(msg).await {
            Ok(Some(info)) => info.res_format.map(|f| f.to_string()),
            _ => None,
        };
        // (remembered too: a message unknown now is not asked about again
        // on every query)
        let verdict = match theirs.filter(|f| !names_formats(f)) {
            Some(theirs) => fits(&theirs).map_err(|detail| (theirs, detail)),
            None => Ok(()),
        };
        lock()
            .entry(msg.to_string())
            .or_default()
            .insert(ty, verdict.clone());
        verdict
    }

    /// Whether `msg` was looked up for `ty` already.
    pub(crate) fn known(&self, msg: &str, ty: &'static str) -> bool {
        let lock = self.verdicts.lock().unwrap_or_else(|e| e.into_inner());
        lock.get(msg).is_some_and(|m| m.contains_key(ty))
    }

    /// Forgets the verdict on `msg` as `ty`: the next
    /// [`CentralFormats::check`] looks central's format up again (after a
    /// definition: what central holds now).
    pub(crate) fn forget(&self, msg: &str, ty: &'static str) {
        if let Some(m) = self
            .verdicts
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get_mut(msg)
        {
            m.remove(ty);
        }
    }

    /// Records the named formats a definition brings; a name this session
    /// gave another format is refused.
    pub(crate) fn named_formats(
        &self,
        formats: &[(&'static str, &'static str)],
    ) -> Result<(), OpenError> {
        // two types of one name inside the definition itself
        for (i, (name, fmt)) in formats.iter().enumerate() {
            if let Some((_, first)) = formats[..i].iter().find(|(n, f)| n == name && f != fmt) {
                return Err(OpenError::NamedFormatConflict {
                    name: name.to_string(),
                    existing: first.to_string(),
                    given: fmt.to_string(),
                });
            }
        }
        let mut named = self.named.lock().unwrap_or_else(|e| e.into_inner());
        for (name, fmt) in formats {
            match named.get(name) {
                Some(existing) if existing != fmt => {
                    return Err(OpenError::NamedFormatConflict {
                        name: name.to_string(),
                        existing: existing.to_string(),
                        given: fmt.to_string(),
                    })
                }
                _ => {}
            }
        }
        for (name, fmt) in formats {
            named.insert(name, fmt);
        }
        Ok(())
    }
}

/// Whether a format refers to named formats (central answers them
/// unexpanded); one that does not parse counts as one.
fn names_formats(f: &str) -> bool {
    courier_wire::format::parse(f).map_or(true, |f| f.names_formats())
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
                 fit {ty}: {ty}'s format is {{string, {{int, double}}}}; at field 2, field 2, \
                 the data has float where {ty} has double",
                ty = std::any::type_name::<Outer>()
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

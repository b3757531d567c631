//! The one type each topic (IPC message) carries within a session.
//!
//! Two Rust types with the same IPC format string and the same DDS type
//! name put the same bytes on the wire, so they may share a topic; any
//! other pair may not: a subscriber would get bytes it cannot decode (IPC)
//! or never match the writer (DDS). The typed API binds a topic to its type
//! on first use and refuses another type afterwards, naming both.

use std::collections::HashMap;
use std::sync::Mutex;

use courier_wire::IpcMessage;

use crate::error::OpenError;
use crate::qos::TypeInfo;

/// A topic's type as bound by its first typed use.
#[derive(Debug, Clone, Copy)]
struct Bound {
    /// The Rust type of the first use, for error messages.
    rust: &'static str,
    format: &'static str,
    type_name: &'static str,
    /// The session has defined the topic for publishing (IPC_defineMsg;
    /// DDS: a writer exists).
    defined: bool,
}

/// A session's topic → type bindings, shared by the session's clones.
#[derive(Debug, Default)]
pub(crate) struct Topics(Mutex<HashMap<String, Bound>>);

impl Topics {
    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Bound>> {
        // a panic elsewhere cannot leave the map half-updated: every update
        // is one insert or one field store
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Binds `msg` to `T`, or checks that it is bound to a type with the
    /// same wire form. `Ok(true)` when the session has not yet defined the
    /// topic for publishing.
    pub(crate) fn bind<T: IpcMessage>(&self, msg: &str) -> Result<bool, OpenError> {
        let mut map = self.lock();
        match map.get(msg) {
            Some(b) if b.format == T::FORMAT && b.type_name == T::TYPE_NAME => Ok(!b.defined),
            Some(b) => Err(OpenError::TypeMismatch {
                msg: msg.to_string(),
                bound: b.rust,
                given: std::any::type_name::<T>(),
            }),
            None => {
                map.insert(
                    msg.to_string(),
                    Bound {
                        rust: std::any::type_name::<T>(),
                        format: T::FORMAT,
                        type_name: T::TYPE_NAME,
                        defined: false,
                    },
                );
                Ok(true)
            }
        }
    }

    /// Records that `msg` is defined for publishing.
    pub(crate) fn defined(&self, msg: &str) {
        if let Some(b) = self.lock().get_mut(msg) {
            b.defined = true;
        }
    }
}

/// What publishing a topic the session has not defined yet needs first:
/// its named formats (IPC) and its type.
#[derive(Debug)]
pub(crate) struct Definition {
    pub(crate) ty: TypeInfo,
    pub(crate) formats: Vec<(&'static str, &'static str)>,
}

impl Definition {
    pub(crate) fn of<T: IpcMessage>() -> Definition {
        Definition {
            ty: TypeInfo::of::<T>(),
            formats: courier_wire::NamedFormats::of::<T>().iter().collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(courier_derive::IpcMessage)]
    #[ipc(type_name = "Point", crate = "::courier_wire")]
    struct Point {
        x: i32,
        y: i32,
    }

    #[derive(courier_derive::IpcMessage)]
    #[ipc(type_name = "Point", crate = "::courier_wire")]
    struct SamePoint {
        a: i32,
        b: i32,
    }

    #[test]
    fn a_topic_keeps_its_first_type() {
        let t = Topics::default();
        assert!(t.bind::<Point>("p").unwrap(), "not defined yet");
        assert!(t.bind::<SamePoint>("p").unwrap(), "same wire form");
        t.defined("p");
        assert!(!t.bind::<Point>("p").unwrap());
        let e = t.bind::<f64>("p").unwrap_err();
        let text = e.to_string();
        assert!(text.contains("Point") && text.contains("f64"), "{text}");
        assert!(t.bind::<f64>("q").unwrap(), "other topics are free");
    }
}

//! Session URL schemes: which backend a URL's scheme names.
//!
//! `ipc://`, `rtps://`, `xrce+udp://`, `xrce+tcp://` and `xrce+serial://`
//! are built in; a program can plug in its own
//! backend under a scheme of its own with [`register_scheme`], after which
//! [`Session::builder`](crate::Session::builder) connects such URLs through
//! it. A URL whose scheme nobody registered is refused with an error that
//! lists the schemes this process knows.

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, RwLock};

use crate::session::{Backend, ConnectError};

/// The schemes built into Courier.
pub const BUILT_IN: &[&str] = &["ipc", "rtps", "xrce+udp", "xrce+tcp", "xrce+serial"];

/// What a plugged-in backend is asked to connect.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct ConnectRequest {
    /// The whole session URL, scheme included.
    pub url: String,
    /// The session's name ([`SessionBuilder::name`](crate::SessionBuilder::name)).
    pub name: String,
}

/// The future a [`Connector`] returns.
pub type ConnectFuture =
    Pin<Box<dyn Future<Output = Result<Arc<dyn Backend>, ConnectError>> + Send>>;

/// Connects a URL of a plugged-in scheme to its backend.
pub type Connector = Arc<dyn Fn(ConnectRequest) -> ConnectFuture + Send + Sync>;

static REGISTRY: RwLock<BTreeMap<String, Connector>> = RwLock::new(BTreeMap::new());

/// Why a scheme could not be registered.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RegisterError {
    /// The scheme is built in or already registered.
    #[error("URL scheme {0:?} is already taken")]
    Taken(String),
    /// Not a URL scheme (RFC 3986: a letter, then letters, digits, `+`, `-`, `.`).
    #[error("{0:?} is not a URL scheme (a letter, then letters, digits, '+', '-' or '.')")]
    Invalid(String),
}

/// Plugs a backend in under `scheme` (without `://`): sessions whose URL
/// starts with `scheme://` connect through `connector`. Schemes are case
/// insensitive, as in URLs.
pub fn register_scheme<F, Fut>(scheme: &str, connector: F) -> Result<(), RegisterError>
where
    F: Fn(ConnectRequest) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = Result<Arc<dyn Backend>, ConnectError>> + Send + 'static,
{
    let valid = scheme
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic())
        && scheme
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'));
    if !valid {
        return Err(RegisterError::Invalid(scheme.to_string()));
    }
    let scheme = scheme.to_ascii_lowercase();
    let mut map = REGISTRY.write().unwrap_or_else(|e| e.into_inner());
    if BUILT_IN.contains(&scheme.as_str()) || map.contains_key(&scheme) {
        return Err(RegisterError::Taken(scheme));
    }
    let connector: Connector = Arc::new(move |r| Box::pin(connector(r)) as ConnectFuture);
    map.insert(scheme, connector);
    Ok(())
}

/// Every scheme this process knows: the built-in ones, then the registered
/// ones in order.
pub fn known_schemes() -> Vec<String> {
    let map = REGISTRY.read().unwrap_or_else(|e| e.into_inner());
    BUILT_IN
        .iter()
        .map(|s| s.to_string())
        .chain(map.keys().cloned())
        .collect()
}

/// What a URL's scheme resolves to.
pub(crate) enum Resolved {
    Ipc,
    Rtps,
    Xrce,
    Plugged(Connector),
}

/// Resolves `url`'s scheme, or says which schemes exist.
pub(crate) fn resolve(url: &str) -> Result<Resolved, ConnectError> {
    let unknown = |scheme: Option<&str>| ConnectError::UnknownScheme {
        url: url.to_string(),
        scheme: scheme.map(str::to_string),
        known: known_schemes(),
    };
    let Some((scheme, _)) = url.split_once("://") else {
        return Err(unknown(None));
    };
    match scheme.to_ascii_lowercase().as_str() {
        "ipc" => Ok(Resolved::Ipc),
        "rtps" => Ok(Resolved::Rtps),
        "xrce+udp" | "xrce+tcp" | "xrce+serial" => Ok(Resolved::Xrce),
        other => {
            let map = REGISTRY.read().unwrap_or_else(|e| e.into_inner());
            map.get(other)
                .cloned()
                .map(Resolved::Plugged)
                .ok_or_else(|| unknown(Some(scheme)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn refuse(r: ConnectRequest) -> Result<Arc<dyn Backend>, ConnectError> {
        Err(ConnectError::BadUrl {
            url: r.url,
            why: "test".into(),
        })
    }

    #[test]
    fn unknown_schemes_list_the_known_ones() {
        let e = resolve("zenoh://127.0.0.1:7447").err().unwrap();
        let text = e.to_string();
        assert!(text.contains("\"zenoh\""), "{text}");
        assert!(
            text.contains("ipc, rtps, xrce+udp, xrce+tcp, xrce+serial"),
            "{text}"
        );
        assert!(matches!(resolve("XRCE+UDP://h:1"), Ok(Resolved::Xrce)));
        let e = resolve("localhost:1381").err().unwrap();
        assert!(e.to_string().contains("no scheme"), "{e}");
        let e = resolve("ipc:/127.0.0.1:1381").err().unwrap();
        assert_eq!(
            e.to_string(),
            "session URL \"ipc:/127.0.0.1:1381\" lacks \"//\" after \"ipc:\": \
             write ipc://127.0.0.1:1381"
        );
        let e = resolve("rtps:7").err().unwrap();
        assert!(e.to_string().ends_with("write rtps://7"), "{e}");
        assert!(matches!(resolve("IPC://h:1"), Ok(Resolved::Ipc)));
    }

    #[test]
    fn schemes_are_registered_once_and_must_be_schemes() {
        assert_eq!(
            register_scheme("rtps", refuse),
            Err(RegisterError::Taken("rtps".into()))
        );
        assert!(matches!(
            register_scheme("9p", refuse),
            Err(RegisterError::Invalid(_))
        ));
        register_scheme("test+mem", refuse).unwrap();
        assert!(matches!(
            register_scheme("Test+Mem", refuse),
            Err(RegisterError::Taken(_))
        ));
        assert!(matches!(resolve("test+mem://x"), Ok(Resolved::Plugged(_))));
        assert!(known_schemes().contains(&"test+mem".to_string()));
    }
}

//! IPC: a format the CLI is about to define a message with (`pub
//! --format`, a recording's channel), checked against the one central
//! already holds, as `Session::define` checks a type's. Defining replaces
//! central's format (C's `IPC_defineMsg`), and the message's subscribers,
//! which read by that format, would then fail to decode every sample (or
//! read wrong values): a misfit is refused unless `--redefine` asks for it.

use courier::format::{self, Format};
use courier::Session;

/// `Ok(Err(what to say))` when central defines `msg` with a format that
/// data of `ours` does not fit; `ours_is` says where `ours` comes from
/// (`--format int`, `the recording's format int`). A message central does
/// not know, or whose format cannot be compared (none, or one naming other
/// formats), is no misfit. `Err`: central could not be asked.
pub async fn check(
    s: &Session,
    msg: &str,
    ours: &Format,
    ours_is: &str,
) -> crate::Result<Result<(), String>> {
    let theirs = s
        .ipc()?
        .look_up(msg)
        .await?
        .and_then(|info| info.res_format);
    let Some(theirs) = theirs.filter(|f| !f.names_formats()) else {
        return Ok(Ok(()));
    };
    // the data is ours, its readers read by central's format
    Ok(match format::fits(ours, &theirs) {
        Ok(()) => Ok(()),
        Err(misfit) => Err(format!(
            "central defines {msg} as {theirs}, which does not fit {ours_is}: {misfit}; \
             defining it anew would make its subscribers fail to decode (--redefine replaces \
             central's format anyway)"
        )),
    })
}

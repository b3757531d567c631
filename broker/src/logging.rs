//! The binaries' diagnostics on stderr, alike for `central` and
//! `xrce-agent`: `RUST_LOG` when set, else the level their own options say.

use tracing::level_filters::LevelFilter;

/// Installs the stderr subscriber: `RUST_LOG` (`warn`, `debug`,
/// `courier_broker=trace,info`, …) when set, else `default`. A `RUST_LOG`
/// that does not parse is reported and `default` used. `targets`: whether
/// lines name the module that logged them.
#[doc(hidden)]
pub fn init(default: LevelFilter, targets: bool) {
    use tracing_subscriber::filter::Targets;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let fallback = Targets::new().with_default(default);
    let (filter, bad) = match std::env::var("RUST_LOG") {
        Ok(spec) if !spec.trim().is_empty() => match spec.parse::<Targets>() {
            Ok(t) => (t, None),
            Err(e) => (fallback, Some(format!("RUST_LOG={spec:?} ignored: {e}"))),
        },
        _ => (fallback, None),
    };
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(targets);
    let _ = tracing_subscriber::registry()
        .with(fmt)
        .with(filter)
        .try_init();
    if let Some(bad) = bad {
        tracing::warn!("{bad}");
    }
}

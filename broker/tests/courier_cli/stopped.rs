//! A process stopped (`SIGSTOP`, a debugger, a swapping machine) for
//! longer than the lease it announced: its peer drops it, while it never
//! loses its peer (which announced a longer lease). Once it is resumed,
//! reliable data flows again, both when the stopped one subscribes and when
//! it publishes. Before the readers' pre-emptive ACKNACKs, neither side saw
//! the other's endpoints again: the side that lost the peer waited for
//! heartbeats that the other, believing itself acknowledged, never sent.

use std::time::{Duration, Instant};

use super::{url, Proc};

/// Takes the lines `p` prints from now until `d` passed.
fn lines_for(p: &mut Proc, d: Duration) {
    let end = Instant::now() + d;
    while let Ok(l) = p
        .lines
        .recv_timeout(end.saturating_duration_since(Instant::now()))
    {
        p.seen.push(l);
    }
}

/// Lets discovery finish: once every SEDP sample is acknowledged, no
/// writer heartbeats any more (a stop during discovery recovers through
/// the heartbeats still going, and proves nothing).
fn settle() {
    std::thread::sleep(Duration::from_secs(2));
}

/// `pub` at 20 Hz, forever, with the lease given.
fn publisher(u: &str, lease_ms: u32) -> Proc {
    Proc::start(&[
        "pub",
        &format!("{u}&lease_ms={lease_ms}"),
        "beat",
        "x",
        "--type",
        "string",
        "--rate",
        "20",
        "--count",
        "0",
    ])
}

fn subscriber(u: &str, lease_ms: u32) -> Proc {
    Proc::start(&["echo", &format!("{u}&lease_ms={lease_ms}"), "beat"])
}

#[test]
fn a_subscriber_stopped_past_its_lease_is_matched_and_served_again() {
    let u = url(290);
    let mut echo = subscriber(&u, 1000);
    let mut publ = publisher(&u, 30_000);
    publ.expect("matched 1");
    echo.expect("\"x\"");
    settle();
    echo.signal(libc::SIGSTOP);
    // the publisher drops it after its 1 s lease
    publ.expect("matched 0");
    std::thread::sleep(Duration::from_secs(1));
    echo.signal(libc::SIGCONT);
    // and finds its reader again (it never did before)
    publ.expect("matched 1");
    // what waited in its socket was printed at once; new samples come
    lines_for(&mut echo, Duration::from_millis(500));
    echo.expect("\"x\"");
}

#[test]
fn a_publisher_stopped_past_its_lease_reaches_its_subscriber_again() {
    let u = url(291);
    let mut echo = subscriber(&u, 30_000);
    let mut publ = publisher(&u, 1000);
    publ.expect("matched 1");
    echo.expect("\"x\"");
    settle();
    publ.signal(libc::SIGSTOP);
    // the subscriber drops the publisher after its 1 s lease: nothing
    // comes, and what was on its way has arrived
    std::thread::sleep(Duration::from_secs(3));
    lines_for(&mut echo, Duration::ZERO);
    publ.signal(libc::SIGCONT);
    echo.expect("\"x\"");
}

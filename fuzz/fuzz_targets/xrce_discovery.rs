//! Fuzzes agent discovery: any datagram, from any address, is either an
//! error or names agents; every agent found is found once.
#![no_main]

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use courier_wire::xrce::discovery::{Discovery, DiscoveryConfig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let from = SocketAddr::from(([127, 0, 0, 1], 7400));
    let cfg = DiscoveryConfig { attempts: 1, period: Duration::from_millis(1) };
    let mut d = Discovery::new(vec![from], cfg, Instant::now());
    let first = d.handle_input(from, data);
    let again = d.handle_input(from, data);
    if let Ok(new) = first {
        assert_eq!(d.found(), &new[..]);
        assert_eq!(again.map(|n| n.len()), Ok(0), "found twice");
    }
});

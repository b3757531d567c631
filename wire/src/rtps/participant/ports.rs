//! The standard port mapping (DDSI-RTPS 2.5 §9.6.1.1) as pure functions.
//!
//! | port | formula | domain 0, index i |
//! |---|---|---|
//! | SPDP (metatraffic) multicast | PB + DG·domain + d0 | 7400 |
//! | metatraffic unicast | PB + DG·domain + d1 + PG·index | 7410 + 2i |
//! | user multicast | PB + DG·domain + d2 | 7401 |
//! | user unicast | PB + DG·domain + d3 + PG·index | 7411 + 2i |
//!
//! Cyclone DDS and Fast DDS both use exactly these values, and both pick
//! the participant index by probing 7410 + 2i upwards
//! (`shared/protocols/rtps.md` §2). With the standard parameters the
//! highest usable domain id is 232.
//!
//! ```
//! use courier_wire::rtps::participant::PortMapping;
//! let m = PortMapping::STANDARD;
//! assert_eq!(m.metatraffic_unicast(0, 1), Some(7412));
//! assert_eq!(m.user_unicast(0, 1), Some(7413));
//! assert_eq!(m.spdp_multicast(1), Some(7650));
//! assert_eq!(m.spdp_multicast(233), None);
//! ```

use crate::rtps::Locator;

/// The default SPDP multicast group, 239.255.0.1 (§9.6.1.4.1).
pub const SPDP_MULTICAST_ADDRESS: [u8; 4] = [239, 255, 0, 1];

/// The parameters of the port mapping.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PortMapping {
    /// PB, the port base (7400).
    pub port_base: u16,
    /// DG, the domain id gain (250).
    pub domain_gain: u16,
    /// PG, the participant id gain (2).
    pub participant_gain: u16,
    /// d0, offset of the SPDP multicast port (0).
    pub d0: u16,
    /// d1, offset of the metatraffic unicast port (10).
    pub d1: u16,
    /// d2, offset of the user multicast port (1).
    pub d2: u16,
    /// d3, offset of the user unicast port (11).
    pub d3: u16,
}

impl Default for PortMapping {
    fn default() -> Self {
        Self::STANDARD
    }
}

impl PortMapping {
    /// PB 7400, DG 250, PG 2, d0 0, d1 10, d2 1, d3 11.
    pub const STANDARD: Self = PortMapping {
        port_base: 7400,
        domain_gain: 250,
        participant_gain: 2,
        d0: 0,
        d1: 10,
        d2: 1,
        d3: 11,
    };

    fn port(&self, domain: u32, offset: u16, index: u32) -> Option<u16> {
        let p = u64::from(self.port_base)
            + u64::from(self.domain_gain) * u64::from(domain)
            + u64::from(offset)
            + u64::from(self.participant_gain) * u64::from(index);
        u16::try_from(p).ok()
    }

    /// The SPDP multicast port of a domain: PB + DG·domain + d0.
    pub fn spdp_multicast(&self, domain: u32) -> Option<u16> {
        self.port(domain, self.d0, 0)
    }

    /// The metatraffic (SPDP/SEDP) unicast port: PB + DG·domain + d1 + PG·index.
    pub fn metatraffic_unicast(&self, domain: u32, index: u32) -> Option<u16> {
        self.port(domain, self.d1, index)
    }

    /// The user-data multicast port: PB + DG·domain + d2.
    pub fn user_multicast(&self, domain: u32) -> Option<u16> {
        self.port(domain, self.d2, 0)
    }

    /// The user-data unicast port: PB + DG·domain + d3 + PG·index.
    pub fn user_unicast(&self, domain: u32, index: u32) -> Option<u16> {
        self.port(domain, self.d3, index)
    }

    /// The SPDP destinations of a unicast peer address: its metatraffic
    /// port for every participant index `0..=max_index`, as Cyclone expands
    /// a `<Peer address="…"/>` without port (Fast DDS's
    /// `maxInitialPeersRange` default of 4 covers indices 0..=3).
    pub fn unicast_peers(&self, ip: [u8; 4], domain: u32, max_index: u32) -> Vec<Locator> {
        (0..=max_index)
            .map_while(|i| self.metatraffic_unicast(domain, i))
            .map(|p| Locator::udpv4(ip, p))
            .collect()
    }

    /// The standard SPDP multicast locator of a domain (239.255.0.1).
    pub fn spdp_multicast_locator(&self, domain: u32) -> Option<Locator> {
        self.spdp_multicast(domain)
            .map(|p| Locator::udpv4(SPDP_MULTICAST_ADDRESS, p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_ports_as_the_peers_use_them() {
        let m = PortMapping::default();
        assert_eq!(m.spdp_multicast(0), Some(7400));
        assert_eq!(m.user_multicast(0), Some(7401));
        assert_eq!(m.metatraffic_unicast(0, 0), Some(7410));
        assert_eq!(m.user_unicast(0, 0), Some(7411));
        assert_eq!(m.metatraffic_unicast(0, 20), Some(7450));
        assert_eq!(m.user_unicast(232, 0), Some(65411));
        assert_eq!(m.user_unicast(232, 100), None);
        assert_eq!(m.metatraffic_unicast(u32::MAX, u32::MAX), None);
        let peers = m.unicast_peers([127, 0, 0, 1], 0, 3);
        assert_eq!(
            peers.iter().map(|l| l.port).collect::<Vec<_>>(),
            [7410, 7412, 7414, 7416]
        );
        assert_eq!(
            m.spdp_multicast_locator(0),
            Some(Locator::udpv4([239, 255, 0, 1], 7400))
        );
    }
}

//! Classic pcap captures (not pcapng): UDP datagrams over IPv4, on Ethernet (with or without
//! 802.1Q VLAN tags), Linux cooked capture (SLL) or raw IP links. Enough to replay Velodyne
//! captures; other frames are counted and skipped.

use std::io::{BufReader, Read};
use std::path::Path;

/// Why a pcap file could not be read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PcapError {
    /// Reading failed.
    #[error("reading pcap: {0}")]
    Io(#[from] std::io::Error),
    /// Not a classic pcap file (pcapng is not supported).
    #[error("not a pcap file (magic {0:#010x})")]
    Magic(u32),
    /// A link type this reader does not parse.
    #[error("unsupported pcap link type {0}")]
    LinkType(u32),
    /// A record header claims more than the snapshot length allows.
    #[error("pcap record of {0} bytes is corrupt")]
    Record(u32),
}

/// One UDP datagram from a capture.
#[derive(Clone, Debug, PartialEq)]
pub struct UdpDatagram {
    /// Capture time, seconds since the Unix epoch.
    pub stamp_s: f64,
    /// UDP source port.
    pub src_port: u16,
    /// UDP destination port.
    pub dst_port: u16,
    /// The UDP payload.
    pub payload: Vec<u8>,
}

/// Frames of a capture that were not returned, by reason.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PcapStats {
    /// Records read.
    pub records: u64,
    /// Not IPv4/UDP (ARP, IPv6, TCP...).
    pub not_udp: u64,
    /// IPv4 fragments (Velodyne packets are never fragmented).
    pub fragments: u64,
    /// Truncated or inconsistent headers.
    pub truncated: u64,
    /// UDP to another port than the one asked for.
    pub other_port: u64,
}

const LINK_ETHERNET: u32 = 1;
const LINK_RAW: u32 = 101;
const LINK_LINUX_SLL: u32 = 113;
const LINK_IPV4: u32 = 228;
/// Largest record accepted regardless of the header's snapshot length (jumbo frames fit).
const MAX_RECORD: u32 = 262_144;

/// Streams the UDP datagrams of a classic pcap file.
#[derive(Debug)]
pub struct PcapReader<R: Read> {
    r: R,
    little: bool,
    nanos: bool,
    link: u32,
    /// Counts of skipped frames.
    pub stats: PcapStats,
}

impl PcapReader<BufReader<std::fs::File>> {
    /// Opens a capture file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, PcapError> {
        Self::new(BufReader::new(std::fs::File::open(path)?))
    }
}

impl<R: Read> PcapReader<R> {
    /// Reads the global header.
    pub fn new(mut r: R) -> Result<Self, PcapError> {
        let mut h = [0u8; 24];
        r.read_exact(&mut h)?;
        let magic = u32::from_le_bytes([h[0], h[1], h[2], h[3]]);
        let (little, nanos) = match magic {
            0xa1b2_c3d4 => (true, false),
            0xa1b2_3c4d => (true, true),
            0xd4c3_b2a1 => (false, false),
            0x4d3c_b2a1 => (false, true),
            m => return Err(PcapError::Magic(m)),
        };
        let u32_at = |o: usize| {
            let a = [h[o], h[o + 1], h[o + 2], h[o + 3]];
            if little {
                u32::from_le_bytes(a)
            } else {
                u32::from_be_bytes(a)
            }
        };
        // The upper bits of the link-type field carry FCS flags in newer writers.
        let link = u32_at(20) & 0x0FFF_FFFF;
        if ![LINK_ETHERNET, LINK_RAW, LINK_LINUX_SLL, LINK_IPV4].contains(&link) {
            return Err(PcapError::LinkType(link));
        }
        Ok(Self {
            r,
            little,
            nanos,
            link,
            stats: PcapStats::default(),
        })
    }

    fn u32(&self, b: &[u8]) -> u32 {
        let a = [b[0], b[1], b[2], b[3]];
        if self.little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    }

    /// The next UDP datagram (to `port` when given), or `None` at the end of the file. A record cut
    /// short by the end of the file (a capture that was killed) ends the stream quietly.
    pub fn next_udp(&mut self, port: Option<u16>) -> Result<Option<UdpDatagram>, PcapError> {
        loop {
            let mut h = [0u8; 16];
            match self.r.read_exact(&mut h) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
                Err(e) => return Err(e.into()),
            }
            let (sec, frac, incl) = (self.u32(&h[0..4]), self.u32(&h[4..8]), self.u32(&h[8..12]));
            if incl > MAX_RECORD {
                return Err(PcapError::Record(incl));
            }
            let mut rec = vec![0u8; incl as usize];
            match self.r.read_exact(&mut rec) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
                Err(e) => return Err(e.into()),
            }
            self.stats.records += 1;
            let stamp_s = sec as f64 + frac as f64 * if self.nanos { 1e-9 } else { 1e-6 };
            let Some(ip) = self.ipv4_payload(&rec) else {
                continue;
            };
            let Some(d) = self.udp(&rec[ip..], stamp_s) else {
                continue;
            };
            if port.is_some_and(|p| p != d.dst_port) {
                self.stats.other_port += 1;
                continue;
            }
            return Ok(Some(d));
        }
    }

    /// Offset of the IPv4 header in a link-layer frame.
    fn ipv4_payload(&mut self, rec: &[u8]) -> Option<usize> {
        let be16 = |o: usize| rec.get(o..o + 2).map(|b| u16::from_be_bytes([b[0], b[1]]));
        let (mut ethertype_at, ip_at) = match self.link {
            LINK_ETHERNET => (12, 14),
            LINK_LINUX_SLL => (14, 16),
            _ => return Some(0),
        };
        let mut ip_at = ip_at;
        let Some(mut ethertype) = be16(ethertype_at) else {
            self.stats.truncated += 1;
            return None;
        };
        while ethertype == 0x8100 || ethertype == 0x88A8 {
            ethertype_at += 4;
            ip_at += 4;
            let Some(t) = be16(ethertype_at) else {
                self.stats.truncated += 1;
                return None;
            };
            ethertype = t;
        }
        if ethertype != 0x0800 {
            self.stats.not_udp += 1;
            return None;
        }
        Some(ip_at)
    }

    fn udp(&mut self, ip: &[u8], stamp_s: f64) -> Option<UdpDatagram> {
        if ip.len() < 20 || ip[0] >> 4 != 4 {
            if ip.first().is_some_and(|b| b >> 4 == 6) {
                self.stats.not_udp += 1;
            } else {
                self.stats.truncated += 1;
            }
            return None;
        }
        let ihl = (ip[0] & 0x0F) as usize * 4;
        let total = u16::from_be_bytes([ip[2], ip[3]]) as usize;
        if ip[9] != 17 {
            self.stats.not_udp += 1;
            return None;
        }
        let frag = u16::from_be_bytes([ip[6], ip[7]]);
        if frag & 0x3FFF != 0 {
            self.stats.fragments += 1;
            return None;
        }
        // Ethernet pads short frames: trust the IP total length, never more than was captured.
        let end = total.min(ip.len());
        if ihl < 20 || ihl + 8 > end {
            self.stats.truncated += 1;
            return None;
        }
        let u = &ip[ihl..end];
        let udp_len = u16::from_be_bytes([u[4], u[5]]) as usize;
        if udp_len < 8 || udp_len > u.len() {
            self.stats.truncated += 1;
            return None;
        }
        Some(UdpDatagram {
            stamp_s,
            src_port: u16::from_be_bytes([u[0], u[1]]),
            dst_port: u16::from_be_bytes([u[2], u[3]]),
            payload: u[8..udp_len].to_vec(),
        })
    }
}

/// Builds a classic little-endian Ethernet pcap from `(stamp_s, dst_port, payload)` (tests, tools).
pub fn write_pcap(datagrams: &[(f64, u16, Vec<u8>)]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
    b.extend_from_slice(&2u16.to_le_bytes());
    b.extend_from_slice(&4u16.to_le_bytes());
    b.extend_from_slice(&[0; 8]);
    b.extend_from_slice(&65535u32.to_le_bytes());
    b.extend_from_slice(&LINK_ETHERNET.to_le_bytes());
    for (t, port, payload) in datagrams {
        let mut f = vec![0xFFu8; 12];
        f.extend_from_slice(&[0x08, 0x00]);
        let total = (20 + 8 + payload.len()) as u16;
        let mut ip = vec![
            0x45, 0, 0, 0, 0, 0, 0x40, 0, 64, 17, 0, 0, 192, 168, 1, 201, 255, 255, 255, 255,
        ];
        ip[2..4].copy_from_slice(&total.to_be_bytes());
        f.extend_from_slice(&ip);
        f.extend_from_slice(&port.to_be_bytes());
        f.extend_from_slice(&port.to_be_bytes());
        f.extend_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
        f.extend_from_slice(&[0, 0]);
        f.extend_from_slice(payload);
        let sec = t.floor();
        b.extend_from_slice(&(sec as u32).to_le_bytes());
        b.extend_from_slice(&(((t - sec) * 1e6).round() as u32).to_le_bytes());
        b.extend_from_slice(&(f.len() as u32).to_le_bytes());
        b.extend_from_slice(&(f.len() as u32).to_le_bytes());
        b.extend_from_slice(&f);
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_and_filters_by_port() {
        let pcap = write_pcap(&[
            (1.5, 2368, vec![1; 1206]),
            (1.6, 8308, vec![2; 512]),
            (1.7, 2368, vec![3; 10]),
        ]);
        let mut r = PcapReader::new(&pcap[..]).unwrap();
        let a = r.next_udp(Some(2368)).unwrap().unwrap();
        assert_eq!((a.dst_port, a.payload.len(), a.stamp_s), (2368, 1206, 1.5));
        let b = r.next_udp(Some(2368)).unwrap().unwrap();
        assert_eq!(b.payload, vec![3; 10]);
        assert!(r.next_udp(Some(2368)).unwrap().is_none());
        assert_eq!(r.stats.other_port, 1);
        assert_eq!(r.stats.records, 3);
    }

    #[test]
    fn truncated_file_ends_quietly_and_bad_magic_is_an_error() {
        let pcap = write_pcap(&[(1.0, 2368, vec![1; 1206]), (2.0, 2368, vec![1; 1206])]);
        let mut r = PcapReader::new(&pcap[..pcap.len() - 100]).unwrap();
        assert!(r.next_udp(None).unwrap().is_some());
        assert!(r.next_udp(None).unwrap().is_none());
        assert!(matches!(
            PcapReader::new(&[0u8; 24][..]),
            Err(PcapError::Magic(0))
        ));
    }

    proptest::proptest! {
        #[test]
        fn random_records_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..3000)) {
            let mut f = write_pcap(&[]);
            f.extend_from_slice(&bytes);
            if let Ok(mut r) = PcapReader::new(&f[..]) {
                for _ in 0..10 {
                    if !matches!(r.next_udp(None), Ok(Some(_))) {
                        break;
                    }
                }
            }
        }
    }
}

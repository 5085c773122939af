//! One VLP-16 data packet (the 1206-byte UDP payload) into returns in the sensor frame.
//!
//! Layout (Velodyne VLP-16 user manual, "Packet Structure & Timing Definition"): 12 data blocks of
//! 100 bytes (flag `0xFF 0xEE`, azimuth u16 in 0.01 deg, 32 channel returns of distance u16 in
//! 2 mm units + reflectivity u8: two firing sequences of the 16 lasers), then the timestamp u32 in
//! microseconds past the hour (time of the first firing of the first block), then two factory
//! bytes: return mode (0x37 strongest, 0x38 last, 0x39 dual) and product id (0x22 VLP-16).
//! Every multi-byte field is little-endian.

use super::{AzimuthInterpolation, VelodyneConfig, LASER_ELEVATION_DEG};
use crate::cloud::Point;

/// Size of a VLP-16 data packet (UDP payload), bytes.
pub const PACKET_SIZE: usize = 1206;
/// Data blocks per packet.
pub const BLOCKS_PER_PACKET: usize = 12;
/// Lasers fired per firing sequence.
pub const LASERS: usize = 16;
/// Time between two consecutive laser firings within a sequence, microseconds.
pub const FIRING_INTERVAL_US: f64 = 2.304;
/// Duration of one firing sequence (16 firings + recharge), microseconds.
pub const SEQUENCE_INTERVAL_US: f64 = 55.296;
/// Distance unit of the packet, metres.
pub const DISTANCE_UNIT_M: f64 = 0.002;
/// Product id byte of a VLP-16 (and Puck LITE).
pub const PRODUCT_VLP16: u8 = 0x22;

const BLOCK_SIZE: usize = 100;
const BLOCK_FLAG: [u8; 2] = [0xFF, 0xEE];
const TIMESTAMP_OFFSET: usize = 1200;
const RETURN_MODE_OFFSET: usize = 1204;
const PRODUCT_OFFSET: usize = 1205;
/// Two firing sequences span one block (single return) or one block pair (dual return).
const BLOCK_DURATION_US: f64 = 2.0 * SEQUENCE_INTERVAL_US;
/// Azimuth steps between blocks above this (5 deg) are not rotation: the sensor turns at most
/// ~0.8 deg per block pair at 20 Hz. Interpolating across such a gap would smear points.
const MAX_BLOCK_STEP_CENTIDEG: u32 = 500;

/// The sensor's return mode (factory byte 1204).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ReturnMode {
    /// 0x37: the strongest return of each firing.
    Strongest,
    /// 0x38: the last return of each firing.
    Last,
    /// 0x39: both; blocks come in pairs with the same azimuth (even block last, odd block strongest,
    /// or second strongest when the last return is also the strongest).
    Dual,
}

impl ReturnMode {
    fn from_byte(b: u8) -> Option<Self> {
        match b {
            0x37 => Some(Self::Strongest),
            0x38 => Some(Self::Last),
            0x39 => Some(Self::Dual),
            _ => None,
        }
    }
}

/// Which echo a return is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum ReturnType {
    /// Strongest-return mode.
    #[default]
    Strongest,
    /// Last-return mode.
    Last,
    /// Dual mode, the two echoes are the same (or the second is empty): emitted once.
    Identical,
    /// Dual mode, the nearer of two distinct echoes and the stronger one.
    FirstStrongest,
    /// Dual mode, the nearer of two distinct echoes and the weaker one.
    FirstWeak,
    /// Dual mode, the farther of two distinct echoes and the stronger one.
    LastStrongest,
    /// Dual mode, the farther of two distinct echoes and the weaker one.
    LastWeak,
}

impl ReturnType {
    /// The code Autoware's nebula driver writes in its `return_type` PCD field, so clouds can be
    /// compared with its output. Nebula calls the *farther* echo "first" (it compares raw distances
    /// the other way round), so `FirstStrongest` here is its `LAST_STRONGEST` and so on.
    pub fn nebula_code(self) -> u8 {
        match self {
            Self::Last => 1,
            Self::Strongest => 3,
            Self::LastWeak => 4,
            Self::FirstWeak => 5,
            Self::Identical => 6,
            Self::LastStrongest => 9,
            Self::FirstStrongest => 10,
        }
    }
}

/// Why a packet was rejected (each reason is counted by the scan assembler).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, thiserror::Error)]
#[non_exhaustive]
pub enum PacketError {
    /// The payload is not 1206 bytes.
    #[error("packet of {0} bytes, want 1206")]
    WrongSize(usize),
    /// A block does not start with `0xFF 0xEE`.
    #[error("block {0} lacks the 0xFFEE flag")]
    BadBlockFlag(usize),
    /// A block azimuth is 360.00 deg or more.
    #[error("block {0} azimuth out of range")]
    BadAzimuth(usize),
    /// The product byte is not a VLP-16.
    #[error("product id {0:#04x} is not a VLP-16 (0x22)")]
    UnknownProduct(u8),
    /// The return-mode byte is none of 0x37, 0x38, 0x39.
    #[error("unknown return mode {0:#04x}")]
    UnknownReturnMode(u8),
}

impl PacketError {
    /// A short stable name for counting (`wrong_size`, `bad_block_flag`, ...).
    pub fn reason(&self) -> &'static str {
        match self {
            Self::WrongSize(_) => "wrong_size",
            Self::BadBlockFlag(_) => "bad_block_flag",
            Self::BadAzimuth(_) => "bad_azimuth",
            Self::UnknownProduct(_) => "unknown_product",
            Self::UnknownReturnMode(_) => "unknown_return_mode",
        }
    }
}

/// One decoded return.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct VelodyneReturn {
    /// Position in the sensor frame (x forward, y left, z up), intensity = reflectivity (0-255),
    /// `ring` = laser id (0-15, firing order, *not* sorted by elevation: see
    /// [`LASER_ELEVATION_DEG`](super::LASER_ELEVATION_DEG)). `t_s` is relative to the packet
    /// timestamp out of [`decode_packet`] and to the scan's first return inside a
    /// [`LidarScan`](super::LidarScan).
    pub point: Point,
    /// Which echo.
    pub return_type: ReturnType,
    /// Azimuth of the firing, radians in [0, 2 pi), clockwise seen from above, 0 = +x.
    pub azimuth_rad: f32,
    /// Elevation of the laser, radians, positive up.
    pub elevation_rad: f32,
    /// Measured distance, metres.
    pub distance_m: f32,
}

/// What a packet header says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacketInfo {
    /// Return mode.
    pub mode: ReturnMode,
    /// Sensor timestamp, microseconds past the hour (first firing of the first block).
    pub timestamp_us: u32,
    /// Azimuth of the first block, 0.01 deg.
    pub first_azimuth_cdeg: u16,
}

/// Checks a packet's size, block flags, azimuths, return mode and (when `require_vlp16`) product.
pub fn inspect_packet(data: &[u8], require_vlp16: bool) -> Result<PacketInfo, PacketError> {
    if data.len() != PACKET_SIZE {
        return Err(PacketError::WrongSize(data.len()));
    }
    for b in 0..BLOCKS_PER_PACKET {
        let o = b * BLOCK_SIZE;
        if data[o..o + 2] != BLOCK_FLAG {
            return Err(PacketError::BadBlockFlag(b));
        }
        if u16::from_le_bytes([data[o + 2], data[o + 3]]) >= 36000 {
            return Err(PacketError::BadAzimuth(b));
        }
    }
    let product = data[PRODUCT_OFFSET];
    if require_vlp16 && product != PRODUCT_VLP16 {
        return Err(PacketError::UnknownProduct(product));
    }
    let mode_byte = data[RETURN_MODE_OFFSET];
    let mode = ReturnMode::from_byte(mode_byte).ok_or(PacketError::UnknownReturnMode(mode_byte))?;
    let t = &data[TIMESTAMP_OFFSET..TIMESTAMP_OFFSET + 4];
    Ok(PacketInfo {
        mode,
        timestamp_us: u32::from_le_bytes([t[0], t[1], t[2], t[3]]),
        first_azimuth_cdeg: u16::from_le_bytes([data[2], data[3]]),
    })
}

fn block_azimuth(data: &[u8], b: usize) -> u32 {
    u32::from_le_bytes([data[b * BLOCK_SIZE + 2], data[b * BLOCK_SIZE + 3], 0, 0])
}

/// Distance (raw, 2 mm units) and reflectivity of channel `c` (0..32) of block `b`.
fn channel(data: &[u8], b: usize, c: usize) -> (u16, u8) {
    let o = b * BLOCK_SIZE + 4 + 3 * c;
    (u16::from_le_bytes([data[o], data[o + 1]]), data[o + 2])
}

/// Forward azimuth step (0.01 deg) from `a` to `b`, across the 360 deg wrap.
fn step_cdeg(a: u32, b: u32) -> u32 {
    (36000 + b - a) % 36000
}

/// Base azimuth and rotation per block duration (both 0.01 deg) for each block.
///
/// `Exact`: a block (pair) is interpolated towards the next distinct block azimuth; the last one
/// reuses the previous step. `NebulaCompat` reproduces Autoware nebula's VLP-16 decoder (the
/// reference `decoded_*.pcd`): in dual mode an odd block takes the azimuth of the *next* pair without
/// interpolation, and the last block (pair) of a packet is not interpolated.
fn block_azimuths(
    data: &[u8],
    dual: bool,
    how: AzimuthInterpolation,
) -> [(u32, u32); BLOCKS_PER_PACKET] {
    let mut out = [(0u32, 0u32); BLOCKS_PER_PACKET];
    let stride = if dual { 2 } else { 1 };
    match how {
        AzimuthInterpolation::Exact => {
            let mut last_step = 0;
            for first in (0..BLOCKS_PER_PACKET).step_by(stride) {
                let az = block_azimuth(data, first);
                let step = if first + stride < BLOCKS_PER_PACKET {
                    let s = step_cdeg(az, block_azimuth(data, first + stride));
                    if s <= MAX_BLOCK_STEP_CENTIDEG {
                        last_step = s;
                    }
                    last_step
                } else {
                    last_step
                };
                for o in out.iter_mut().skip(first).take(stride) {
                    *o = (az, step.min(MAX_BLOCK_STEP_CENTIDEG));
                }
            }
        }
        AzimuthInterpolation::NebulaCompat => {
            let mut last_step = 0;
            let mut az_next = 0;
            for (b, o) in out.iter_mut().enumerate() {
                let az = if b == 0 {
                    block_azimuth(data, 0)
                } else {
                    az_next
                };
                let step = if b + stride < BLOCKS_PER_PACKET {
                    az_next = block_azimuth(data, b + stride);
                    last_step = step_cdeg(az, az_next);
                    last_step
                } else if b == BLOCKS_PER_PACKET - stride {
                    0
                } else {
                    last_step
                };
                *o = (az, step);
            }
        }
    }
    out
}

/// Precomputed per-laser trigonometry.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LaserTable {
    cos_el: [f32; LASERS],
    sin_el: [f32; LASERS],
    el_rad: [f32; LASERS],
}

impl LaserTable {
    pub(crate) fn new() -> Self {
        let mut t = Self {
            cos_el: [0.0; LASERS],
            sin_el: [0.0; LASERS],
            el_rad: [0.0; LASERS],
        };
        for (i, deg) in LASER_ELEVATION_DEG.iter().enumerate() {
            let r = (*deg as f64).to_radians();
            t.el_rad[i] = r as f32;
            t.cos_el[i] = r.cos() as f32;
            t.sin_el[i] = r.sin() as f32;
        }
        t
    }
}

/// Decodes one packet, appending its returns to `out` (`point.t_s` relative to the packet
/// timestamp). Zero distance is "no return" and is skipped, as are returns outside the configured
/// range and azimuth window. On error nothing is appended.
pub fn decode_packet(
    data: &[u8],
    config: &VelodyneConfig,
    out: &mut Vec<VelodyneReturn>,
) -> Result<PacketInfo, PacketError> {
    decode_with_table(data, config, &LaserTable::new(), out)
}

pub(crate) fn decode_with_table(
    data: &[u8],
    config: &VelodyneConfig,
    lasers: &LaserTable,
    out: &mut Vec<VelodyneReturn>,
) -> Result<PacketInfo, PacketError> {
    decode_firings(data, config, lasers, out, |_, _| {})
}

/// Decodes a packet, calling `on_firing(azimuth_deg, out.len())` for every firing in packet order
/// (also those without a return or filtered out), so a caller can split scans between returns.
pub(crate) fn decode_firings(
    data: &[u8],
    config: &VelodyneConfig,
    lasers: &LaserTable,
    out: &mut Vec<VelodyneReturn>,
    mut on_firing: impl FnMut(f64, usize),
) -> Result<PacketInfo, PacketError> {
    let info = inspect_packet(data, config.require_vlp16_product)?;
    let dual = info.mode == ReturnMode::Dual;
    let azimuths = block_azimuths(data, dual, config.interpolation);
    let compat = config.interpolation == AzimuthInterpolation::NebulaCompat;
    let min_az_cdeg = config.min_azimuth_deg as f64 * 100.0;
    let max_az_cdeg = config.max_azimuth_deg as f64 * 100.0;
    let (min_r, max_r) = (config.min_range_m as f64, config.max_range_m as f64);
    for (b, &(az0, step)) in azimuths.iter().enumerate() {
        // First firing sequence of this block: two per block, or two per block pair in dual mode.
        let seq0 = if dual { b - b % 2 } else { 2 * b };
        for c in 0..2 * LASERS {
            let (laser, seq) = (c % LASERS, seq0 + c / LASERS);
            let az_cdeg = if compat {
                // Nebula computes this in f32 and rounds to 0.01 deg; the same arithmetic gives the
                // same rounding at the .5 boundaries.
                let off = laser as f32 * FIRING_INTERVAL_US as f32
                    + (c / LASERS) as f32 * SEQUENCE_INTERVAL_US as f32;
                (az0 as f32 + step as f32 * off / BLOCK_DURATION_US as f32).round() as f64
            } else {
                let within_block_us =
                    (c / LASERS) as f64 * SEQUENCE_INTERVAL_US + laser as f64 * FIRING_INTERVAL_US;
                az0 as f64 + step as f64 * within_block_us / BLOCK_DURATION_US
            } % 36000.0;
            on_firing(az_cdeg / 100.0, out.len());
            let (raw, reflectivity) = channel(data, b, c);
            if raw == 0 {
                continue;
            }
            let return_type = if dual {
                let (other, other_refl) = channel(data, b ^ 1, c);
                if b % 2 == 1 && other == raw {
                    continue; // the strongest echo is the last one: already emitted from the even block
                }
                if other == 0 || other == raw {
                    ReturnType::Identical
                } else {
                    let nearer = raw < other;
                    // Equal reflectivity: the odd block is the one the sensor reports as strongest.
                    let stronger =
                        reflectivity > other_refl || (reflectivity == other_refl && b % 2 == 1);
                    match (nearer, stronger) {
                        (true, true) => ReturnType::FirstStrongest,
                        (true, false) => ReturnType::FirstWeak,
                        (false, true) => ReturnType::LastStrongest,
                        (false, false) => ReturnType::LastWeak,
                    }
                }
            } else if info.mode == ReturnMode::Last {
                ReturnType::Last
            } else {
                ReturnType::Strongest
            };
            let distance_m = raw as f64 * DISTANCE_UNIT_M;
            if distance_m <= min_r
                || distance_m >= max_r
                || az_cdeg < min_az_cdeg
                || az_cdeg > max_az_cdeg
            {
                continue;
            }
            let az_rad = (az_cdeg / 100.0).to_radians();
            let (sin_az, cos_az) = az_rad.sin_cos();
            let d = distance_m as f32;
            let xy = d * lasers.cos_el[laser];
            let t_us = seq as f64 * SEQUENCE_INTERVAL_US + laser as f64 * FIRING_INTERVAL_US;
            out.push(VelodyneReturn {
                point: Point {
                    x: xy * cos_az as f32,
                    // Velodyne azimuth turns clockwise seen from above; y left needs the minus sign.
                    y: -xy * sin_az as f32,
                    z: d * lasers.sin_el[laser],
                    intensity: reflectivity as f32,
                    ring: laser as u16,
                    t_s: (t_us * 1e-6) as f32,
                },
                return_type,
                azimuth_rad: az_rad as f32,
                elevation_rad: lasers.el_rad[laser],
                distance_m: d,
            });
        }
    }
    Ok(info)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A synthetic packet: every block at `az0 + step * block` (pairs share azimuths in dual mode),
    /// every channel at `raw` distance with reflectivity 10.
    pub(crate) fn synthetic(mode: u8, az0: u16, step: u16, raw: u16) -> Vec<u8> {
        let mut p = vec![0u8; PACKET_SIZE];
        for b in 0..BLOCKS_PER_PACKET {
            let o = b * BLOCK_SIZE;
            p[o] = 0xFF;
            p[o + 1] = 0xEE;
            let k = if mode == 0x39 { b / 2 } else { b } as u32;
            let az = ((az0 as u32 + step as u32 * k) % 36000) as u16;
            p[o + 2..o + 4].copy_from_slice(&az.to_le_bytes());
            for c in 0..32 {
                let q = o + 4 + 3 * c;
                p[q..q + 2].copy_from_slice(&raw.to_le_bytes());
                p[q + 2] = 10;
            }
        }
        p[1200..1204].copy_from_slice(&1_000_000u32.to_le_bytes());
        p[1204] = mode;
        p[1205] = 0x22;
        p
    }

    #[test]
    fn geometry_and_timing_of_a_single_return_packet() {
        let cfg = VelodyneConfig::default();
        let p = synthetic(0x37, 9000, 20, 5000); // azimuth 90 deg, 10 m
        let mut out = Vec::new();
        let info = decode_packet(&p, &cfg, &mut out).unwrap();
        assert_eq!(info.mode, ReturnMode::Strongest);
        assert_eq!(info.timestamp_us, 1_000_000);
        assert_eq!(out.len(), 12 * 32);
        // Laser 0 (-15 deg) of block 0 looks at azimuth 90 deg clockwise = -y (right).
        let r = out[0];
        assert_eq!(r.point.ring, 0);
        assert!((r.distance_m - 10.0).abs() < 1e-6);
        assert!(
            r.point.x.abs() < 1e-4 && (r.point.y + 10.0 * 15f32.to_radians().cos()).abs() < 1e-4
        );
        assert!((r.point.z + 10.0 * 15f32.to_radians().sin()).abs() < 1e-4);
        // Laser 1 is +1 deg and fires 2.304 us later.
        assert!((out[1].elevation_rad - 1f32.to_radians()).abs() < 1e-6);
        assert!((out[1].point.t_s - 2.304e-6).abs() < 1e-10);
        // Second sequence of block 0: 55.296 us, half-way to block 1's azimuth.
        assert!((out[16].point.t_s - 55.296e-6).abs() < 1e-10);
        assert!((out[16].azimuth_rad.to_degrees() - 90.10).abs() < 1e-4);
        // Block 11 second sequence: 23 sequences in; its step comes from block 10.
        let last = out[12 * 32 - 16];
        assert!((last.point.t_s as f64 - 23.0 * 55.296e-6).abs() < 1e-9);
        assert!((last.azimuth_rad.to_degrees() - 92.30).abs() < 1e-3);
        for r in &out {
            assert!((r.point.range_m() - r.distance_m).abs() < 1e-4);
            assert_eq!(r.return_type, ReturnType::Strongest);
        }
    }

    #[test]
    fn dual_return_pairs() {
        let cfg = VelodyneConfig::default();
        let mut p = synthetic(0x39, 100, 40, 1000);
        // Block 1 channel 0: a distinct, stronger, nearer echo; channel 1: empty strongest echo.
        p[BLOCK_SIZE + 4..BLOCK_SIZE + 7].copy_from_slice(&[0xF4, 0x01, 50]); // 500 -> 1 m
        p[BLOCK_SIZE + 7..BLOCK_SIZE + 10].copy_from_slice(&[0, 0, 0]);
        let mut out = Vec::new();
        decode_packet(&p, &cfg, &mut out).unwrap();
        // 6 pairs x 32 channels once, plus one distinct echo.
        assert_eq!(out.len(), 6 * 32 + 1);
        assert_eq!(out[0].return_type, ReturnType::LastWeak);
        assert_eq!(out[1].return_type, ReturnType::Identical);
        let extra = out
            .iter()
            .find(|r| r.return_type == ReturnType::FirstStrongest)
            .unwrap();
        assert!((extra.distance_m - 1.0).abs() < 1e-6);
        // Both echoes of a firing share time and azimuth; pair 1 starts two sequences later.
        assert_eq!(extra.point.t_s, out[0].point.t_s);
        assert_eq!(extra.azimuth_rad, out[0].azimuth_rad);
        let pair1 = out
            .iter()
            .find(|r| (r.azimuth_rad.to_degrees() - 1.40).abs() < 1e-4)
            .unwrap();
        assert!((pair1.point.t_s as f64 - 2.0 * 55.296e-6).abs() < 1e-9);
    }

    #[test]
    fn malformed_packets_are_typed_errors() {
        let good = synthetic(0x37, 0, 20, 100);
        let mut out = Vec::new();
        let cfg = VelodyneConfig::default();
        assert_eq!(
            decode_packet(&good[..1205], &cfg, &mut out),
            Err(PacketError::WrongSize(1205))
        );
        let mut bad = good.clone();
        bad[300] = 0;
        assert_eq!(
            decode_packet(&bad, &cfg, &mut out),
            Err(PacketError::BadBlockFlag(3))
        );
        let mut bad = good.clone();
        bad[1205] = 0x28;
        assert_eq!(
            decode_packet(&bad, &cfg, &mut out),
            Err(PacketError::UnknownProduct(0x28))
        );
        let mut bad = good.clone();
        bad[1204] = 0x10;
        assert_eq!(
            decode_packet(&bad, &cfg, &mut out),
            Err(PacketError::UnknownReturnMode(0x10))
        );
        let mut bad = good;
        bad[102..104].copy_from_slice(&36000u16.to_le_bytes());
        assert_eq!(
            decode_packet(&bad, &cfg, &mut out),
            Err(PacketError::BadAzimuth(1))
        );
        assert!(out.is_empty());
    }

    #[test]
    fn range_and_zero_filters() {
        let mut cfg = VelodyneConfig::default();
        let p = synthetic(0x38, 0, 20, 0);
        let mut out = Vec::new();
        decode_packet(&p, &cfg, &mut out).unwrap();
        assert!(out.is_empty(), "zero distance is no return");
        cfg.max_range_m = 5.0;
        decode_packet(&synthetic(0x38, 0, 20, 2600), &cfg, &mut out).unwrap();
        assert!(out.is_empty(), "5.2 m is beyond max range");
        decode_packet(&synthetic(0x38, 0, 20, 2400), &cfg, &mut out).unwrap();
        assert_eq!(out.len(), 384);
        assert!(out.iter().all(|r| r.return_type == ReturnType::Last));
    }

    proptest::proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..1300)) {
            let mut out = Vec::new();
            let _ = decode_packet(&bytes, &VelodyneConfig::default(), &mut out);
        }

        /// Valid framing with random contents (azimuths, distances, modes): decodes, never panics,
        /// and every return is finite and within range.
        #[test]
        fn random_contents_decode_sanely(
            body in proptest::collection::vec(proptest::prelude::any::<u8>(), PACKET_SIZE),
            mode in 0x37u8..=0x39,
            compat in proptest::prelude::any::<bool>(),
        ) {
            let mut p = body;
            for b in 0..BLOCKS_PER_PACKET {
                p[b * BLOCK_SIZE] = 0xFF;
                p[b * BLOCK_SIZE + 1] = 0xEE;
                let az = u16::from_le_bytes([p[b * BLOCK_SIZE + 2], p[b * BLOCK_SIZE + 3]]) % 36000;
                p[b * BLOCK_SIZE + 2..b * BLOCK_SIZE + 4].copy_from_slice(&az.to_le_bytes());
            }
            p[RETURN_MODE_OFFSET] = mode;
            p[PRODUCT_OFFSET] = PRODUCT_VLP16;
            let cfg = VelodyneConfig {
                interpolation: if compat { AzimuthInterpolation::NebulaCompat } else { AzimuthInterpolation::Exact },
                ..VelodyneConfig::default()
            };
            let mut out = Vec::new();
            proptest::prop_assert!(decode_packet(&p, &cfg, &mut out).is_ok());
            for r in &out {
                proptest::prop_assert!(r.point.is_finite());
                proptest::prop_assert!(r.distance_m > 0.3 && r.distance_m < 130.0);
                proptest::prop_assert!((0.0..std::f32::consts::TAU + 1e-6).contains(&r.azimuth_rad));
            }
            let mut asm = crate::velodyne::ScanAssembler::new(cfg);
            asm.push_packet(&p, 0.0);
            asm.push_packet(&p, 0.0);
            let _ = asm.finish();
        }
    }
}

//! Velodyne VLP-16: data packets into returns, returns into scans, and the three packet sources
//! (live UDP socket, pcap capture, ROS 2 bag of `velodyne_msgs/msg/VelodyneScan`).
//!
//! # Conventions
//!
//! - Frame: the sensor frame with **x forward, y left, z up** (right-handed, as the rest of the
//!   system and the ROS Velodyne drivers use). Velodyne's azimuth is measured *clockwise* seen from
//!   above with 0 at the sensor's front (our +x), so a return at distance `d`, azimuth
//!   `a`, elevation `e` is `x = d cos(e) cos(a)`, `y = -d cos(e) sin(a)`, `z = d sin(e)`. This is
//!   exactly the convention of the reference decoding `lidar/vlp16/decoded_*.pcd` (Autoware nebula):
//!   its points equal ours, no axis swap or sign flip (tests check it point by point).
//! - `Point::ring` is the **laser id** 0..15 in firing order; elevations are interleaved
//!   ([`LASER_ELEVATION_DEG`]: id 0 -> -15 deg, 1 -> +1, 2 -> -13, ...). Nebula's `channel` field
//!   is instead the rank by elevation ([`ring_by_elevation`] converts).
//! - Time: `Point::t_s` is relative to the scan's first return, from the packet's sensor
//!   timestamp (microseconds past the hour, first firing of the packet) plus the firing offset:
//!   2.304 us per laser firing, 55.296 us per 16-laser sequence, two sequences per block (single
//!   return) or per block pair (dual return). `Scan::stamp_s` is the host time of the packet
//!   holding the first return (bag packet stamp, pcap record time, or UDP receive time) plus that
//!   return's offset in the packet.
//! - Azimuth: blocks carry the azimuth of their first firing; later firings are interpolated with
//!   the rotation measured to the next block (pair). [`AzimuthInterpolation::NebulaCompat`]
//!   reproduces the reference driver's rounding and its dual-mode simplifications instead.
//! - Dual return: both echoes are kept (`ReturnType` says which); when the two are identical the
//!   point is emitted once. Distance 0 means no return and is skipped.
//! - Scans are cut where the firing azimuth crosses [`VelodyneConfig::cut_angle_deg`] (or, when it
//!   is `None`, the azimuth at which the stream started).

mod packet;
pub mod pcap;
pub mod rosbag;
pub mod source;
pub mod udp;

pub use packet::{
    decode_packet, inspect_packet, PacketError, PacketInfo, ReturnMode, ReturnType, VelodyneReturn,
    BLOCKS_PER_PACKET, DISTANCE_UNIT_M, FIRING_INTERVAL_US, LASERS, PACKET_SIZE, PRODUCT_VLP16,
    SEQUENCE_INTERVAL_US,
};

use crate::cloud::{Point, Scan};
use packet::LaserTable;

/// Default UDP port of VLP-16 data packets.
pub const DATA_PORT: u16 = 2368;

/// Elevation of each laser id, degrees (VLP-16 manual, table "Laser ID and vertical angle").
pub const LASER_ELEVATION_DEG: [f32; LASERS] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];

/// Rank of a laser id when the lasers are sorted bottom (-15 deg) to top (+15 deg): the "ring" of
/// drivers that sort by elevation (nebula's `channel`). Ids >= 16 map to themselves.
pub fn ring_by_elevation(laser_id: u16) -> u16 {
    match laser_id {
        // Even ids are -15, -13, ... -1 deg; odd ids +1 ... +15 deg.
        0..=15 if laser_id.is_multiple_of(2) => laser_id / 2,
        0..=15 => 8 + laser_id / 2,
        _ => laser_id,
    }
}

/// How firing azimuths are interpolated between block azimuths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AzimuthInterpolation {
    /// Each firing at the block (pair) azimuth plus the rotation measured to the next block (pair)
    /// times its time offset; full precision.
    #[default]
    Exact,
    /// Bit-for-bit the azimuths of Autoware nebula's VLP-16 decoder (rounded to 0.01 deg; in dual
    /// mode the odd block of a pair takes the next pair's azimuth and the last pair of a packet is
    /// not interpolated). Only for comparing with its output: up to ~0.4 deg off in those blocks.
    NebulaCompat,
}

/// Decoder and scan-assembly settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VelodyneConfig {
    /// Returns at or below this distance are dropped (the robot's own body), metres.
    pub min_range_m: f32,
    /// Returns at or beyond this distance are dropped, metres (the VLP-16 is rated to 100 m but
    /// reports up to ~130 m; the default keeps everything it reports).
    pub max_range_m: f32,
    /// Returns with azimuth below this are dropped, degrees (clockwise from the front).
    pub min_azimuth_deg: f32,
    /// Returns with azimuth above this are dropped, degrees.
    pub max_azimuth_deg: f32,
    /// Azimuth where one scan ends and the next begins, degrees; `None`: where the stream began.
    pub cut_angle_deg: Option<f32>,
    /// Azimuth interpolation.
    pub interpolation: AzimuthInterpolation,
    /// Reject packets whose product byte is not 0x22 (VLP-16). Early (2014) VLP-16 firmware
    /// writes 0x21, the HDL-32E's id, as `lidar/vlp16/velodyne_vlp16.pcap` shows (its channels
    /// `c` and `c + 16` are the same laser and it turns 0.4 deg per block: VLP-16 layout and
    /// timing). Set false to decode such captures; an HDL-32E stream would then decode wrongly.
    pub require_vlp16_product: bool,
}

impl Default for VelodyneConfig {
    fn default() -> Self {
        Self {
            min_range_m: 0.3,
            max_range_m: 130.0,
            min_azimuth_deg: 0.0,
            max_azimuth_deg: 360.0,
            cut_angle_deg: Some(0.0),
            interpolation: AzimuthInterpolation::Exact,
            require_vlp16_product: true,
        }
    }
}

impl VelodyneConfig {
    /// The settings the reference decoding `lidar/vlp16/decoded_*.pcd` was made with (nebula's
    /// test configuration: min range 0.3 m, max 300 m, azimuths 0..359 deg, scans cut at 0 deg,
    /// nebula's azimuth arithmetic). With them, scan 3 of `packets_*.db3` (the rotation from the
    /// last packet of the 3rd message to the wrap in the last packet of the 4th, whose bag time
    /// names the file) equals the reference: 14 831 points, within 3 um. The reference's
    /// `time_stamp` field is not reproduced: that nebula build timed dual-return blocks as if
    /// single-return.
    pub fn nebula_reference() -> Self {
        Self {
            min_range_m: 0.3,
            max_range_m: 300.0,
            min_azimuth_deg: 0.0,
            max_azimuth_deg: 359.0,
            cut_angle_deg: Some(0.0),
            interpolation: AzimuthInterpolation::NebulaCompat,
            require_vlp16_product: true,
        }
    }
}

/// Packets seen by an assembler, and the malformed ones by reason (all skipped).
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DecodeStats {
    /// Packets decoded.
    pub packets_ok: u64,
    /// Payloads that were not 1206 bytes.
    pub wrong_size: u64,
    /// Packets with a block lacking the 0xFFEE flag.
    pub bad_block_flag: u64,
    /// Packets with a block azimuth of 360 deg or more.
    pub bad_azimuth: u64,
    /// Packets whose product byte is not a VLP-16.
    pub unknown_product: u64,
    /// Packets with an unknown return-mode byte.
    pub unknown_return_mode: u64,
    /// Gaps in the sensor clock between packets (more than 0.1 s forward, or backward): the scan
    /// under construction was closed as incomplete. Not malformed packets.
    pub time_gaps: u64,
}

impl DecodeStats {
    /// Counts one rejected packet.
    pub fn count(&mut self, e: &PacketError) {
        match e {
            PacketError::WrongSize(_) => self.wrong_size += 1,
            PacketError::BadBlockFlag(_) => self.bad_block_flag += 1,
            PacketError::BadAzimuth(_) => self.bad_azimuth += 1,
            PacketError::UnknownProduct(_) => self.unknown_product += 1,
            PacketError::UnknownReturnMode(_) => self.unknown_return_mode += 1,
        }
    }

    /// All rejected packets.
    pub fn malformed(&self) -> u64 {
        self.wrong_size
            + self.bad_block_flag
            + self.bad_azimuth
            + self.unknown_product
            + self.unknown_return_mode
    }
}

/// One assembled rotation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LidarScan {
    /// 0-based index of the scan in its stream (every cut counts, partial scans too).
    pub index: usize,
    /// Host time of the first return, seconds.
    pub stamp_s: f64,
    /// The returns in firing order; `point.t_s` relative to the first.
    pub returns: Vec<VelodyneReturn>,
    /// Packets that contributed firings (a packet straddling a cut counts for both scans).
    pub packets: usize,
    /// Azimuth swept by the scan's firings, degrees (360 for a full rotation).
    pub coverage_deg: f64,
    /// Began within 1 deg after the cut angle and ended at the next cut: a full rotation.
    pub complete: bool,
}

impl LidarScan {
    /// The plain scan other crates consume.
    pub fn to_scan(&self) -> Scan {
        Scan {
            stamp_s: self.stamp_s,
            points: self.returns.iter().map(|r| r.point).collect::<Vec<Point>>(),
        }
    }
}

/// Continuous azimuth bookkeeping: cuts a scan each time the unwrapped azimuth passes the cut.
#[derive(Clone, Debug, Default)]
struct CutTracker {
    cut_deg: Option<f64>,
    prev_rel_deg: Option<f64>,
    /// Whole turns counted so far (kept as an integer so the unwrapped angle never drifts).
    turns: i64,
    /// Unwrapped azimuth relative to the cut, degrees.
    unwrapped_deg: f64,
    next_cut_deg: f64,
}

impl CutTracker {
    /// Feeds one firing's azimuth; true when it is the first firing of a new scan.
    fn feed(&mut self, az_deg: f64) -> bool {
        let cut = *self.cut_deg.get_or_insert(az_deg);
        let rel = (az_deg - cut).rem_euclid(360.0);
        match self.prev_rel_deg {
            None => self.next_cut_deg = 360.0,
            Some(prev) => {
                // The sensor only turns forward; small backward steps happen within a dual-return
                // block pair. Anything else backward is a wrap (or a gap in the data).
                let d = rel - prev;
                if d < -10.0 {
                    self.turns += 1;
                } else if d >= 350.0 {
                    self.turns -= 1;
                }
            }
        }
        self.prev_rel_deg = Some(rel);
        self.unwrapped_deg = self.turns as f64 * 360.0 + rel;
        if self.unwrapped_deg >= self.next_cut_deg {
            while self.next_cut_deg <= self.unwrapped_deg {
                self.next_cut_deg += 360.0;
            }
            return true;
        }
        false
    }

    /// Unwrapped azimuth of the start of the current rotation.
    fn rotation_start_deg(&self) -> f64 {
        self.next_cut_deg - 360.0
    }
}

/// Scan under construction.
#[derive(Debug, Default)]
struct Building {
    returns: Vec<VelodyneReturn>,
    packets: usize,
    first_unwrapped_deg: Option<f64>,
    last_unwrapped_deg: f64,
    started_near_cut: bool,
    /// Sensor time of the first return, microseconds past the hour, and its host time.
    first_sensor_us: Option<f64>,
    stamp_s: f64,
}

/// Turns a stream of packets into scans: feed packets in arrival order, take scans as they close.
#[derive(Debug)]
pub struct ScanAssembler {
    config: VelodyneConfig,
    lasers: LaserTable,
    tracker: CutTracker,
    current: Building,
    next_index: usize,
    stats: DecodeStats,
    packet_buf: Vec<VelodyneReturn>,
    /// Cuts in the current packet: (returns before it, firings before it, unwrapped cut azimuth).
    cuts: Vec<(usize, usize, f64)>,
    firing_unwrapped: Vec<f64>,
    last_sensor_us: Option<u32>,
}

const HOUR_US: f64 = 3_600_000_000.0;
/// Packets come every 0.66 ms (dual) or 1.33 ms (single): a 0.1 s hole is lost data.
const MAX_GAP_US: f64 = 100_000.0;
/// Reordered datagrams may step back a little; more is a restart.
const MAX_BACKSTEP_US: f64 = 10_000.0;

/// A difference of microseconds-past-the-hour stamps, into (-30 min, 30 min].
fn wrap_hour_us(mut dt_us: f64) -> f64 {
    if dt_us <= -HOUR_US / 2.0 {
        dt_us += HOUR_US;
    } else if dt_us > HOUR_US / 2.0 {
        dt_us -= HOUR_US;
    }
    dt_us
}

impl ScanAssembler {
    /// An assembler with the given settings.
    pub fn new(config: VelodyneConfig) -> Self {
        Self {
            config,
            lasers: LaserTable::new(),
            tracker: CutTracker {
                cut_deg: config.cut_angle_deg.map(|d| (d as f64).rem_euclid(360.0)),
                ..CutTracker::default()
            },
            current: Building::default(),
            next_index: 0,
            stats: DecodeStats::default(),
            packet_buf: Vec::with_capacity(2 * BLOCKS_PER_PACKET * 2 * LASERS),
            cuts: Vec::new(),
            firing_unwrapped: Vec::new(),
            last_sensor_us: None,
        }
    }

    /// Packet counts so far.
    pub fn stats(&self) -> &DecodeStats {
        &self.stats
    }

    /// Feeds one UDP payload received (or recorded) at host time `host_stamp_s`; returns the scans
    /// it completed (usually none, at most one for real data). Malformed packets are counted in
    /// [`stats`](Self::stats) and skipped.
    pub fn push_packet(&mut self, data: &[u8], host_stamp_s: f64) -> Vec<LidarScan> {
        let mut done = Vec::new();
        // Lost packets (a cable pulled, a bag with holes) or a restarted sensor: the azimuth alone
        // cannot tell how many rotations were missed, so close the scan and start afresh.
        if let Ok(info) = inspect_packet(data, self.config.require_vlp16_product) {
            if let Some(prev) = self.last_sensor_us {
                let dt_us = wrap_hour_us(info.timestamp_us as f64 - prev as f64);
                if !(-MAX_BACKSTEP_US..=MAX_GAP_US).contains(&dt_us) {
                    self.stats.time_gaps += 1;
                    if self.current.packets > 0 {
                        let end = self.current.last_unwrapped_deg;
                        done.push(self.close(end, false));
                    }
                    let cut_deg = self
                        .config
                        .cut_angle_deg
                        .map(|d| (d as f64).rem_euclid(360.0));
                    self.tracker = CutTracker {
                        cut_deg,
                        ..CutTracker::default()
                    };
                }
            }
            self.last_sensor_us = Some(info.timestamp_us);
        }
        let mut buf = std::mem::take(&mut self.packet_buf);
        buf.clear();
        self.cuts.clear();
        self.firing_unwrapped.clear();
        let tracker = &mut self.tracker;
        let cuts = &mut self.cuts;
        let firing_unwrapped = &mut self.firing_unwrapped;
        let result = packet::decode_firings(
            data,
            &self.config,
            &self.lasers,
            &mut buf,
            |az_deg, n_out| {
                if tracker.feed(az_deg) {
                    cuts.push((n_out, firing_unwrapped.len(), tracker.rotation_start_deg()));
                }
                firing_unwrapped.push(tracker.unwrapped_deg);
            },
        );
        let info = match result {
            Ok(info) => info,
            Err(e) => {
                self.stats.count(&e);
                self.packet_buf = buf;
                return done;
            }
        };
        self.stats.packets_ok += 1;
        let first_u = self.firing_unwrapped.first().copied().unwrap_or(0.0);
        let last_u = self.firing_unwrapped.last().copied().unwrap_or(0.0);
        let mut start = 0;
        let mut seg_first_u = first_u;
        let cuts = std::mem::take(&mut self.cuts);
        for &(at, firing, cut_u) in &cuts {
            if firing > 0 {
                self.append(
                    &buf[start..at],
                    info.timestamp_us,
                    host_stamp_s,
                    seg_first_u,
                    cut_u,
                );
            }
            // A cut on the stream's very first firing closes nothing.
            if self.current.packets > 0 {
                done.push(self.close(cut_u, true));
            }
            start = at;
            seg_first_u = cut_u;
        }
        self.cuts = cuts;
        self.append(
            &buf[start..],
            info.timestamp_us,
            host_stamp_s,
            seg_first_u,
            last_u,
        );
        self.packet_buf = buf;
        done
    }

    /// Closes and returns the scan under construction (end of stream), if it has returns.
    pub fn finish(&mut self) -> Option<LidarScan> {
        if self.current.returns.is_empty() {
            return None;
        }
        let end = self.current.last_unwrapped_deg;
        Some(self.close(end, false))
    }

    fn append(
        &mut self,
        rets: &[VelodyneReturn],
        ts_us: u32,
        host_s: f64,
        first_u: f64,
        last_u: f64,
    ) {
        let b = &mut self.current;
        b.packets += 1;
        if b.first_unwrapped_deg.is_none() {
            b.first_unwrapped_deg = Some(first_u);
            b.started_near_cut = first_u.rem_euclid(360.0) < 1.0;
        }
        b.last_unwrapped_deg = last_u;
        for r in rets {
            let t_in_packet_us = r.point.t_s as f64 * 1e6;
            let first_us = *b.first_sensor_us.get_or_insert_with(|| {
                b.stamp_s = host_s + r.point.t_s as f64;
                ts_us as f64 + t_in_packet_us
            });
            // Sensor time is microseconds past the hour: unwrap across the hour.
            let dt_us = wrap_hour_us(ts_us as f64 + t_in_packet_us - first_us);
            let mut r = *r;
            r.point.t_s = (dt_us * 1e-6) as f32;
            b.returns.push(r);
        }
    }

    fn close(&mut self, end_u: f64, at_cut: bool) -> LidarScan {
        let b = std::mem::take(&mut self.current);
        let first_u = b.first_unwrapped_deg.unwrap_or(end_u);
        let scan = LidarScan {
            index: self.next_index,
            stamp_s: b.stamp_s,
            returns: b.returns,
            packets: b.packets,
            coverage_deg: end_u - first_u,
            complete: at_cut && b.started_near_cut,
        };
        self.next_index += 1;
        scan
    }
}

/// Decodes a whole packet stream into scans (the trailing partial scan included).
pub fn assemble_all<'a>(
    packets: impl IntoIterator<Item = (&'a [u8], f64)>,
    config: VelodyneConfig,
) -> (Vec<LidarScan>, DecodeStats) {
    let mut asm = ScanAssembler::new(config);
    let mut scans = Vec::new();
    for (data, t) in packets {
        scans.extend(asm.push_packet(data, t));
    }
    scans.extend(asm.finish());
    (scans, asm.stats().clone())
}

#[cfg(test)]
mod tests;

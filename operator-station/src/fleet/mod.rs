//! Robots seen on the bus: online/offline by liveliness (with the time), sessions and datums,
//! last pose / status / path, message rates and ages. Plain data: callers pass the time.

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use common::msg::{Path, Pose, Session, Status};

/// Window over which message rates are computed.
pub const RATE_WINDOW: Duration = Duration::from_secs(5);

/// Topics with rates and ages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum RateTopic {
    /// Poses.
    Pose,
    /// Status.
    Status,
    /// Tiles.
    Tile,
}

impl RateTopic {
    /// Name in the API.
    pub fn name(&self) -> &'static str {
        match self {
            RateTopic::Pose => "pose",
            RateTopic::Status => "status",
            RateTopic::Tile => "tile",
        }
    }
}

/// Arrival times of one topic.
#[derive(Clone, Debug, Default)]
pub struct Rate {
    arrivals: VecDeque<Instant>,
}

impl Rate {
    /// Records one arrival.
    pub fn hit(&mut self, now: Instant) {
        self.arrivals.push_back(now);
        while let Some(f) = self.arrivals.front() {
            if now.duration_since(*f) > RATE_WINDOW {
                self.arrivals.pop_front();
            } else {
                break;
            }
        }
    }

    /// Messages per second over the window ending at `now`.
    pub fn hz(&self, now: Instant) -> f64 {
        let n = self
            .arrivals
            .iter()
            .filter(|t| now.duration_since(**t) <= RATE_WINDOW)
            .count();
        n as f64 / RATE_WINDOW.as_secs_f64()
    }

    /// Time since the last arrival.
    pub fn age(&self, now: Instant) -> Option<Duration> {
        self.arrivals
            .back()
            .map(|t| now.saturating_duration_since(*t))
    }
}

/// Pose latencies kept per robot: the newest ones (at 10 Hz, about 3.4 minutes).
pub const LATENCY_WINDOW: usize = 2048;

/// Pose latency as the station sees it: its receive time minus the pose's stamp. Robot and
/// station clocks must agree for it to mean transport delay (NTP or GNSS time on real robots; one
/// clock in the tests), so it is reported as measured, negative values included.
#[derive(Clone, Debug, Default)]
pub struct Latency {
    ms: VecDeque<i64>,
}

impl Latency {
    /// Records one latency, ms.
    pub fn record(&mut self, ms: i64) {
        if self.ms.len() == LATENCY_WINDOW {
            self.ms.pop_front();
        }
        self.ms.push_back(ms);
    }

    /// Count, median, 99th percentile and maximum over the window (ms); None before any pose.
    pub fn summary(&self) -> Option<serde_json::Value> {
        let mut v: Vec<i64> = self.ms.iter().copied().collect();
        if v.is_empty() {
            return None;
        }
        v.sort_unstable();
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Some(serde_json::json!({"n": v.len(), "p50": at(0.5), "p99": at(0.99), "max": at(1.0)}))
    }
}

/// What the station knows about one robot.
#[derive(Clone, Debug, Default)]
pub struct RobotState {
    /// Liveliness token present.
    pub online: bool,
    /// Last time anything was heard (or the token changed), Unix ms.
    pub last_seen_unix_ms: u64,
    /// Current session.
    pub session: Option<Session>,
    /// Datum of the current session.
    pub datum_id: Option<String>,
    /// Last pose.
    pub pose: Option<Pose>,
    /// Last status.
    pub status: Option<Status>,
    /// Last path.
    pub path: Option<Path>,
    /// Rates per topic.
    pub rates: BTreeMap<RateTopic, Rate>,
    /// Pose latencies (receive time minus stamp).
    pub pose_latency: Latency,
    /// Last stored track point: (time, x, y, yaw).
    pub last_track: Option<(u64, f64, f64, f64)>,
    /// When the last pose went out on the WebSocket.
    pub last_pose_event: Option<Instant>,
    /// When the last path was stored.
    pub last_path_store: Option<(Instant, u32)>,
    /// Tiles received before the session was known (merged once it is).
    pub pending_tiles: Vec<(common::grid::TileIndex, Vec<u8>)>,
}

/// Longest list of pending tiles kept per robot while its session is unknown.
pub const MAX_PENDING_TILES: usize = 4096;

/// Decimation of the stored track: a point when the robot moved this far...
pub const TRACK_MIN_STEP_M: f64 = 0.25;
/// ...or turned this much...
pub const TRACK_MIN_TURN_RAD: f64 = 0.17;
/// ...or this much time passed.
pub const TRACK_MAX_GAP_MS: u64 = 5000;

impl RobotState {
    /// Whether a pose should be stored in the track (and remembers it if so).
    pub fn track_point(&mut self, p: &Pose) -> bool {
        let take = match self.last_track {
            None => true,
            Some((t, x, y, yaw)) => {
                let dyaw = (p.yaw_rad as f64 - yaw + std::f64::consts::PI)
                    .rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                (p.x_m - x).hypot(p.y_m - y) >= TRACK_MIN_STEP_M
                    || dyaw.abs() >= TRACK_MIN_TURN_RAD
                    || p.t_unix_ms.saturating_sub(t) >= TRACK_MAX_GAP_MS
            }
        };
        if take {
            self.last_track = Some((p.t_unix_ms, p.x_m, p.y_m, p.yaw_rad as f64));
        }
        take
    }

    /// Records an arrival on a topic.
    pub fn hit(&mut self, topic: RateTopic, now: Instant, now_unix_ms: u64) {
        self.rates.entry(topic).or_default().hit(now);
        self.last_seen_unix_ms = self.last_seen_unix_ms.max(now_unix_ms);
    }

    /// Rates (Hz) and ages (ms) for the API.
    pub fn rates_and_ages(
        &self,
        now: Instant,
    ) -> (
        BTreeMap<&'static str, f64>,
        BTreeMap<&'static str, Option<u64>>,
    ) {
        let mut rates = BTreeMap::new();
        let mut ages = BTreeMap::new();
        for t in [RateTopic::Pose, RateTopic::Status, RateTopic::Tile] {
            let r = self.rates.get(&t);
            rates.insert(
                t.name(),
                r.map(|r| (r.hz(now) * 100.0).round() / 100.0)
                    .unwrap_or(0.0),
            );
            ages.insert(
                t.name(),
                r.and_then(|r| r.age(now)).map(|d| d.as_millis() as u64),
            );
        }
        (rates, ages)
    }
}

/// Every robot seen, by id (sorted).
#[derive(Clone, Debug, Default)]
pub struct Fleet {
    /// Robots by id.
    pub robots: BTreeMap<String, RobotState>,
}

impl Fleet {
    /// The robot's state, created on first sight.
    pub fn robot(&mut self, id: &str) -> &mut RobotState {
        self.robots.entry(id.to_string()).or_default()
    }

    /// Liveliness changed. Returns true when the online state flipped.
    pub fn set_online(&mut self, id: &str, online: bool, now_unix_ms: u64) -> bool {
        let r = self.robot(id);
        let flipped = r.online != online;
        r.online = online;
        r.last_seen_unix_ms = r.last_seen_unix_ms.max(now_unix_ms);
        flipped
    }

    /// Robots online.
    pub fn online_count(&self) -> usize {
        self.robots.values().filter(|r| r.online).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(t: u64, x: f64, yaw: f32) -> Pose {
        Pose {
            t_unix_ms: t,
            seq: 0,
            x_m: x,
            y_m: 0.0,
            z_m: 0.0,
            yaw_rad: yaw,
            pitch_rad: 0.0,
            roll_rad: 0.0,
            v_mps: 0.0,
            omega_rps: 0.0,
            fix: Default::default(),
            lat_lon_deg: None,
        }
    }

    #[test]
    fn track_is_decimated_by_distance_turn_and_time() {
        let mut r = RobotState::default();
        assert!(r.track_point(&pose(0, 0.0, 0.0)));
        assert!(!r.track_point(&pose(100, 0.1, 0.0)));
        assert!(r.track_point(&pose(200, 0.3, 0.0)));
        assert!(r.track_point(&pose(300, 0.3, 0.5)));
        assert!(!r.track_point(&pose(400, 0.3, 0.5)));
        assert!(r.track_point(&pose(6000, 0.3, 0.5)));
    }

    #[test]
    fn rates_count_the_window() {
        let mut r = Rate::default();
        let t0 = Instant::now();
        for i in 0..50 {
            r.hit(t0 + Duration::from_millis(100 * i));
        }
        let now = t0 + Duration::from_millis(4900);
        assert!((r.hz(now) - 10.0).abs() < 0.3, "{}", r.hz(now));
        assert_eq!(r.age(now), Some(Duration::ZERO));
    }

    #[test]
    fn online_flips_are_reported() {
        let mut f = Fleet::default();
        assert!(f.set_online("a", true, 1));
        assert!(!f.set_online("a", true, 2));
        assert_eq!(f.online_count(), 1);
        assert!(f.set_online("a", false, 3));
        assert_eq!(f.online_count(), 0);
    }

    #[test]
    fn pose_latency_keeps_a_window_and_reports_percentiles() {
        let mut l = Latency::default();
        assert!(l.summary().is_none());
        for ms in 1..=100 {
            l.record(ms);
        }
        let s = l.summary().unwrap();
        assert_eq!(
            (s["n"].as_u64(), s["p99"].as_i64(), s["max"].as_i64()),
            (Some(100), Some(99), Some(100))
        );
        for _ in 0..LATENCY_WINDOW {
            l.record(-3);
        }
        let s = l.summary().unwrap();
        assert_eq!(s["n"].as_u64(), Some(LATENCY_WINDOW as u64));
        assert_eq!(s["max"].as_i64(), Some(-3), "old values leave the window");
    }
}

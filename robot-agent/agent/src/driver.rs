//! The driver: turns a path or an operator's drive into a velocity command, under the safety
//! gate.
//!
//! Two pure-pursuit followers (docs/algorithms.md §6): one for planned paths, and the same
//! controller tuned for taught routes (shorter look-ahead, earlier turn in place). Every command
//! passes the gate: while the last sweep puts something in the stop zone, or the last sweep is
//! older than its trust time (a stale sweep cannot vouch for the space ahead), forward motion is
//! zeroed. The trust time is `safety_scan_timeout_s`, or 1.5 sweep periods for a LiDAR that spins
//! slower than that allows (a VLP-16 at 2 Hz); the speed is capped so that what the robot drives
//! between two sweeps plus its braking distance stays within the stop zone's depth
//! (`v P + v^2 / 2a <= stop_ahead_m`; at 10 Hz the cap lies above any Husky speed); turning in place stays allowed unless something stands where the body's
//! corners would sweep. A stop that holds for `safety_stop_block_s` is remembered with where it
//! stands, so the planner can treat it as a blockage
//! ([`crate::terrain::layers::stamp_blocked_disc`]).

use crate::localiser::PoseMap;
use common::geom::Pose2;

/// Sweep intervals longer than this are outages, not the sensor's period, seconds.
const SWEEP_PERIOD_MAX_S: f64 = 2.0;

/// A velocity command for the base.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Cmd {
    /// Forward speed, m/s.
    pub v_mps: f64,
    /// Turn rate, rad/s.
    pub omega_rps: f64,
}

/// An operator's drive command as the mission holds it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Teleop {
    /// When it arrived, seconds.
    pub t_s: f64,
    /// Sequence number.
    pub seq: u32,
    /// Forward speed, m/s.
    pub v_mps: f64,
    /// Turn rate, rad/s.
    pub omega_rps: f64,
    /// The operator holds the deadman.
    pub deadman: bool,
}

/// Which follower tracks a path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tracker {
    /// A planned path to a goal.
    Path,
    /// A taught route.
    Route,
}

/// The driver's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct DriverConfig {
    /// Path following and the safety stop.
    pub control: control::Config,
    /// Look-ahead on taught routes, metres.
    pub route_lookahead_m: f64,
    /// Heading error beyond which the route tracker turns in place, radians.
    pub route_rotate_in_place_rad: f64,
    /// Teleop silence after which the robot stops, seconds.
    pub deadman_s: f64,
    /// How long one sweep vouches for the space ahead, seconds.
    pub safety_scan_timeout_s: f64,
    /// A safety stop lasting this long is a blockage, seconds.
    pub safety_stop_block_s: f64,
    /// How hard the base brakes when commanded to stop (the robot profile's `max_accel_mps2`),
    /// m/s^2.
    pub brake_mps2: f64,
}

/// See the module docs.
pub struct Driver {
    cfg: DriverConfig,
    follower: control::Follower,
    route_tracker: control::Follower,
    speed_limit_mps: f64,
    safety: control::SafetyVerdict,
    safety_t_s: f64,
    /// The LiDAR's sweep period as observed (running mean of the intervals), seconds.
    sweep_period_s: Option<f64>,
    /// Since when (sweep time) the safety stop has held without a break, and where (map frame)
    /// the stop-zone point nearest the body stood in the last sweep.
    lasting_stop: Option<(f64, (f64, f64))>,
    /// The depth camera's last verdict and its time: a second, short-range witness of the
    /// space ahead (low obstacles under the LiDAR's lowest beam).
    depth_safety: Option<(control::SafetyVerdict, f64)>,
    last_cmd: Cmd,
    /// A slow zone's cap in force, m/s.
    zone_cap_mps: Option<f64>,
}

impl Driver {
    /// A driver at the controller's own speed limit, with no sweep seen yet (so stopped).
    pub fn new(cfg: DriverConfig) -> Self {
        let route_tracker = control::Follower::new(control::Config {
            lookahead_m: cfg.route_lookahead_m,
            rotate_in_place_rad: cfg.route_rotate_in_place_rad,
            ..cfg.control.clone()
        });
        Self {
            follower: control::Follower::new(cfg.control.clone()),
            route_tracker,
            speed_limit_mps: cfg.control.v_max_mps,
            safety: control::SafetyVerdict::default(),
            safety_t_s: f64::NEG_INFINITY,
            sweep_period_s: None,
            lasting_stop: None,
            depth_safety: None,
            last_cmd: Cmd::default(),
            zone_cap_mps: None,
            cfg,
        }
    }

    /// Checks one sweep's points (`base_link`, metres) against the stop zone; `pose` places a
    /// lasting stop in the map frame.
    pub fn on_sweep(
        &mut self,
        t_s: f64,
        points_base: impl IntoIterator<Item = (f64, f64, f64)>,
        pose: &PoseMap,
    ) {
        self.safety = control::safety::check(&self.cfg.control.safety, points_base);
        let dt = t_s - self.safety_t_s;
        // Gaps (a sensor outage, a restart) are not the sensor's period.
        if dt > 0.0 && dt < SWEEP_PERIOD_MAX_S {
            self.sweep_period_s = Some(match self.sweep_period_s {
                Some(p) => p + 0.2 * (dt - p),
                None => dt,
            });
        }
        self.safety_t_s = t_s;
        self.lasting_stop = match (self.safety.stop, self.safety.zone_nearest_m) {
            (true, Some((x, y))) => {
                let q = pose.iso * nalgebra::Point3::new(x, y, 0.0);
                let since = self.lasting_stop.map_or(t_s, |(t, _)| t);
                Some((since, (q.x, q.y)))
            }
            _ => None,
        };
    }

    /// Checks one depth-camera frame's points (`base_link`, metres) against the stop zone. A
    /// frame can only add a stop: the camera sees a narrow cone, so its empty view never clears
    /// what the LiDAR saw.
    pub fn on_depth_frame(
        &mut self,
        t_s: f64,
        points_base: impl IntoIterator<Item = (f64, f64, f64)>,
    ) {
        let v = control::safety::check(&self.cfg.control.safety, points_base);
        self.depth_safety = Some((v, t_s));
    }

    /// Whether forward motion is barred at `t_s`: something in the stop zone (LiDAR, or a fresh
    /// depth frame), or no fresh sweep.
    pub fn stop_ahead(&self, t_s: f64) -> bool {
        let depth_stop = self
            .depth_safety
            .is_some_and(|(v, t)| v.stop && t_s - t <= self.cfg.safety_scan_timeout_s);
        t_s - self.safety_t_s > self.sweep_trust_s() || self.safety.stop || depth_stop
    }

    /// How long one sweep vouches for the space ahead: `safety_scan_timeout_s`, or 1.5 observed
    /// sweep periods when the LiDAR spins slower than that allows, seconds.
    pub fn sweep_trust_s(&self) -> f64 {
        self.sweep_period_s
            .map_or(self.cfg.safety_scan_timeout_s, |p| {
                self.cfg.safety_scan_timeout_s.max(1.5 * p)
            })
    }

    /// The last sweep's verdict.
    pub fn safety(&self) -> control::SafetyVerdict {
        self.safety
    }

    /// Where a safety stop that has held for `safety_stop_block_s` stands (map frame):
    /// something the robot may not touch, beside the corridor or too low or too new to be in
    /// the map (a person who stopped to let the robot pass, at the robot's shoulder).
    pub fn lasting_stop_m(&self) -> Option<(f64, f64)> {
        let (since, at) = self.lasting_stop?;
        (self.safety_t_s - since >= self.cfg.safety_stop_block_s).then_some(at)
    }

    /// Sets the operator's speed limit, clamped to the controller's own.
    pub fn set_speed_limit(&mut self, v_mps: f64) {
        self.speed_limit_mps = v_mps.clamp(0.0, self.cfg.control.v_max_mps);
    }

    /// The operator's speed limit, m/s.
    pub fn speed_limit_mps(&self) -> f64 {
        self.speed_limit_mps
    }

    /// Caps the speed while a slow zone acts on the robot (None: no zone).
    pub fn set_zone_cap(&mut self, cap_mps: Option<f64>) {
        self.zone_cap_mps = cap_mps.filter(|c| c.is_finite() && *c >= 0.0);
    }

    /// The speed the driver allows now: the operator's limit, under a slow zone's cap and under
    /// the LiDAR's ([`Driver::sensor_cap_mps`]), m/s.
    pub fn limit_now_mps(&self) -> f64 {
        self.zone_cap_mps
            .map_or(self.speed_limit_mps, |c| c.min(self.speed_limit_mps))
            .min(self.sensor_cap_mps())
    }

    /// The fastest the robot may drive on the LiDAR's sweeps: what it drives between two sweeps
    /// (period `P`) plus its braking distance stays within the stop zone's depth `d`:
    /// `v P + v^2 / 2a = d`, so `v = sqrt((aP)^2 + 2ad) - aP`, m/s.
    pub fn sensor_cap_mps(&self) -> f64 {
        let a = self.cfg.brake_mps2;
        let Some(p) = self.sweep_period_s.filter(|_| a > 0.0) else {
            return f64::INFINITY;
        };
        let d = self.cfg.control.safety.stop_ahead_m.max(0.0);
        ((a * p).powi(2) + 2.0 * a * d).sqrt() - a * p
    }

    /// The operator's drive, while the deadman is held and fresh; forward motion gated.
    pub fn teleop(&self, t_s: f64, drive: Option<&Teleop>, stop_ahead: bool) -> Cmd {
        match drive {
            Some(d) if d.deadman && t_s - d.t_s <= self.cfg.deadman_s => {
                let limit = self.limit_now_mps();
                let v = d.v_mps.clamp(-limit, limit);
                Cmd {
                    v_mps: if stop_ahead && v > 0.0 { 0.0 } else { v },
                    omega_rps: d.omega_rps,
                }
            }
            _ => Cmd::default(),
        }
    }

    /// Follows `path` from `pose` with the chosen tracker, gated.
    pub fn follow(
        &self,
        tracker: Tracker,
        pose: &Pose2,
        path: &[(f64, f64)],
        stop_ahead: bool,
        to_end: bool,
    ) -> Cmd {
        if path.len() < 2 {
            return Cmd::default();
        }
        let follower = match tracker {
            Tracker::Path => &self.follower,
            Tracker::Route => &self.route_tracker,
        };
        let c = follower.command(
            pose,
            path,
            self.limit_now_mps(),
            self.safety.clearance_m,
            to_end,
        );
        self.gate(
            Cmd {
                v_mps: c.v_mps,
                omega_rps: c.omega_rps,
            },
            stop_ahead,
        )
    }

    fn gate(&self, mut cmd: Cmd, stop_ahead: bool) -> Cmd {
        if stop_ahead && cmd.v_mps > 0.0 {
            // The safety stop overrides everything: stop; rotating in place is still allowed...
            cmd.v_mps = 0.0;
        }
        if cmd.v_mps.abs() < 1e-3 && self.safety.turn_blocked {
            // ...unless something stands where the body's corners would sweep.
            cmd.omega_rps = 0.0;
        }
        cmd
    }

    /// Records the command sent to the base.
    pub fn set_last(&mut self, cmd: Cmd) {
        self.last_cmd = cmd;
    }

    /// The last command sent to the base.
    pub fn last_cmd(&self) -> Cmd {
        self.last_cmd
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Isometry3;

    fn driver() -> Driver {
        Driver::new(DriverConfig {
            control: control::Config::default(),
            route_lookahead_m: 0.6,
            route_rotate_in_place_rad: 0.5,
            deadman_s: 0.3,
            safety_scan_timeout_s: 0.35,
            safety_stop_block_s: 3.0,
            brake_mps2: 1.0,
        })
    }

    fn at_origin() -> PoseMap {
        PoseMap::from_iso(Isometry3::identity())
    }

    #[test]
    fn no_sweep_means_no_forward_motion() {
        let mut d = driver();
        assert!(d.stop_ahead(0.0), "never saw a sweep");
        d.on_sweep(1.0, std::iter::empty(), &at_origin());
        assert!(!d.stop_ahead(1.2));
        assert!(d.stop_ahead(1.4), "the sweep went stale");
        let path = [(0.0, 0.0), (5.0, 0.0)];
        let c = d.follow(Tracker::Path, &Pose2::default(), &path, true, true);
        assert_eq!(c.v_mps, 0.0);
    }

    #[test]
    fn a_slow_lidar_is_trusted_for_its_period_at_a_speed_that_keeps_the_distance() {
        let mut d = driver();
        let v_max = d.limit_now_mps();
        // 10 Hz: the configured trust and full speed.
        for i in 0..20 {
            d.on_sweep(i as f64 * 0.1, std::iter::empty(), &at_origin());
        }
        assert_eq!(d.sweep_trust_s(), 0.35);
        assert_eq!(d.limit_now_mps(), v_max, "10 Hz does not bind");
        // 2 Hz (a VLP-16 spun slowly): each sweep vouches until the next one is due ...
        let mut d = driver();
        for i in 0..20 {
            d.on_sweep(i as f64 * 0.5, std::iter::empty(), &at_origin());
        }
        assert!((d.sweep_trust_s() - 0.75).abs() < 1e-9);
        assert!(
            !d.stop_ahead(9.5 + 0.6),
            "a 2 Hz sweep 0.6 s old is the newest there is"
        );
        assert!(d.stop_ahead(9.5 + 0.8), "a missed 2 Hz sweep is stale");
        // ... and between two sweeps plus braking the robot stays within the stop zone's depth.
        let cap = d.limit_now_mps();
        let depth = control::Config::default().safety.stop_ahead_m;
        assert!(cap < v_max, "2 Hz binds: {cap}");
        assert!(
            (cap * 0.5 + cap * cap / 2.0 - depth).abs() < 1e-9,
            "cap {cap}"
        );
        // An outage is not a period.
        d.on_sweep(30.0, std::iter::empty(), &at_origin());
        assert!((d.sweep_trust_s() - 0.75).abs() < 1e-9);
    }

    #[test]
    fn teleop_needs_a_fresh_deadman_and_is_clamped() {
        let mut d = driver();
        d.set_speed_limit(0.3);
        let t = Teleop {
            t_s: 10.0,
            seq: 1,
            v_mps: 1.0,
            omega_rps: 0.2,
            deadman: true,
        };
        assert_eq!(d.teleop(10.1, Some(&t), false).v_mps, 0.3);
        d.set_zone_cap(Some(0.2));
        assert_eq!(d.teleop(10.1, Some(&t), false).v_mps, 0.2, "slow zone");
        d.set_zone_cap(None);
        assert_eq!(d.teleop(10.4, Some(&t), false), Cmd::default(), "deadman");
        assert_eq!(d.teleop(10.1, Some(&t), true).v_mps, 0.0, "gated");
        assert_eq!(
            d.teleop(10.1, Some(&t), true).omega_rps,
            0.2,
            "turning allowed"
        );
    }

    #[test]
    fn a_low_obstacle_only_the_depth_camera_sees_stops_the_robot_while_fresh() {
        let mut d = driver();
        // The LiDAR's sweeps see nothing (a low box below its lowest beam, close in).
        d.on_sweep(1.0, std::iter::empty(), &at_origin());
        let path = [(0.0, 0.0), (5.0, 0.0)];
        let go = d.follow(
            Tracker::Path,
            &Pose2::default(),
            &path,
            d.stop_ahead(1.05),
            true,
        );
        assert!(go.v_mps > 0.0, "nothing in the way: drives");
        // The camera's frame: a 0.25 m box 0.6 m ahead of the centre, in the stop zone.
        let box_pts: Vec<(f64, f64, f64)> = (0..10)
            .map(|i| (0.6, -0.05 + 0.01 * i as f64, 0.25))
            .collect();
        d.on_depth_frame(1.05, box_pts.iter().copied());
        assert!(
            d.stop_ahead(1.1),
            "the camera's obstacle stops forward motion"
        );
        let c = d.follow(
            Tracker::Path,
            &Pose2::default(),
            &path,
            d.stop_ahead(1.1),
            true,
        );
        assert_eq!(c.v_mps, 0.0);
        // A later LiDAR sweep that sees nothing does not clear the camera's stop ...
        d.on_sweep(1.2, std::iter::empty(), &at_origin());
        assert!(d.stop_ahead(1.25));
        // ... a camera frame without the box does, and so does a stale camera frame.
        d.on_depth_frame(1.3, std::iter::empty());
        assert!(!d.stop_ahead(1.35));
        d.on_depth_frame(1.3, box_pts.iter().copied());
        d.on_sweep(1.6, std::iter::empty(), &at_origin());
        assert!(
            !d.stop_ahead(1.7),
            "a camera frame older than the timeout no longer stops"
        );
    }

    #[test]
    fn a_stop_lasts_only_while_it_holds() {
        let mut d = driver();
        // A box of points 0.6 m ahead of the centre, 0.5 m up: in the stop zone.
        let pts: Vec<(f64, f64, f64)> = (0..10)
            .map(|i| (0.6, -0.05 + 0.01 * i as f64, 0.5))
            .collect();
        for k in 0..40 {
            d.on_sweep(k as f64 * 0.1, pts.iter().copied(), &at_origin());
        }
        let at = d.lasting_stop_m().expect("held 3.9 s");
        assert!((at.0 - 0.6).abs() < 1e-9);
        d.on_sweep(4.0, std::iter::empty(), &at_origin());
        assert!(d.lasting_stop_m().is_none());
    }
}

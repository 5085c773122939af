//! One robot's pipeline: sensors in, SLAM -> traversability mapping -> missions -> commands out.
//!
//! [`Agent`] is driven by a loop that feeds it timestamped sensor data and asks it for a command
//! at the control rate; it never reads a clock, so the same code runs in the headless simulator
//! (faster than real time), live on the bus, and in tests. The loops live in [`crate::run`].
//!
//! Frames: SLAM's own frame is the first scan's `base_link`; the agent anchors it in the `map`
//! frame at the first scan — ENU at the datum with the pose from an RTK fix and the dual-antenna
//! heading when GNSS allows, else the SLAM frame itself (and GNSS goals are refused).

pub mod config;

use crate::mission::gnss::{GnssGoal, GnssTracker};
use crate::mission::navigate::{Goal, Navigator};
use crate::mission::repeat::{RepeatState, RouteFollower};
use crate::mission::teach::RouteRecorder;
use crate::mission::teach_view::{TaughtCell, TeachView};
use common::geo::LocalFrame;
use common::geom::Pose2;
use common::grid::{Lattice, Tile};
use common::msg::{
    Datum, DriveCmd, GoalCmd, GoalTarget, MapFrame, MissionState, Mode, Pose, Route, RouteCmd,
    RouteDirection, RouteProgress, SlamHealth, Status,
};
pub use config::AgentConfig;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use planning::{CostRule, GridWindow, PlanGrid};
use sensing::{GnssSentence, ImuSample, OdomSample, Scan};

/// A velocity command for the base.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Cmd {
    /// Forward speed, m/s.
    pub v_mps: f64,
    /// Turn rate, rad/s.
    pub omega_rps: f64,
}

/// What one scan did.
#[derive(Clone, Debug, Default)]
pub struct ScanReport {
    /// SLAM fell back to its prior (or failed outright).
    pub slam_failed: bool,
    /// Grid cells reclassified.
    pub classified_cells: usize,
    /// The path ahead became blocked.
    pub path_blocked: bool,
}

/// The robot pose at one instant, map frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseMap {
    /// `map<-base_link`.
    pub iso: Isometry3<f64>,
    /// Planar part.
    pub planar: Pose2,
}

impl PoseMap {
    fn from_iso(iso: Isometry3<f64>) -> Self {
        Self {
            planar: Pose2::from_isometry3(&iso),
            iso,
        }
    }
}

/// The robot agent's state.
pub struct Agent {
    cfg: AgentConfig,
    slam: slam::Slam,
    mapper: mapping::Mapper,
    nav: Navigator,
    repeat: Option<(RouteFollower, Route)>,
    repeat_paused: bool,
    /// The last repeat cycle's outcome (a wait is logged when it begins).
    repeat_state: Option<RepeatState>,
    recorder: Option<RouteRecorder>,
    /// The local traversability seen while teaching, by route id (this session's routes).
    teach_views: Vec<(String, TeachView)>,
    /// The view of the route being repeated, if it was taught in this session.
    repeat_view: Option<TeachView>,
    gnss: GnssTracker,
    follower: control::Follower,
    /// The same controller tuned for taught routes (shorter look-ahead, earlier turn in place).
    route_tracker: control::Follower,
    /// Set at the first scan.
    anchor: Option<Anchor>,
    /// Pose and odometry at the last SLAM update, for interpolation between scans.
    at_scan: Option<(PoseMap, Option<Pose2>)>,
    /// `map<-odom` from the last SLAM update.
    map_from_odom: Option<Isometry3<f64>>,
    last_odom: Option<OdomSample>,
    mode: Mode,
    teleop: Option<(f64, DriveCmd)>,
    speed_limit_mps: f64,
    safety: control::SafetyVerdict,
    safety_t_s: f64,
    pending_tiles: Vec<Tile>,
    path_dirty: bool,
    recorded: Option<Route>,
    slam_health: SlamHealth,
    last_error: Option<String>,
    commands_refused: u32,
    scans: u32,
    session_id: String,
    robot: String,
    start_unix_ms: u64,
    last_plan_t_s: f64,
    last_cmd: Cmd,
    gnss_rejected: u32,
    /// When the last RTK fixed fix came and how far (horizontally) the pose was from it, metres.
    gnss_residual: Option<(f64, f64)>,
    /// Sweeps not mapped because their pose was not trusted.
    scans_not_mapped: u64,
    /// Since when (sweep time) the safety stop has held without a break, and where (map frame)
    /// the stop-zone point nearest the body stood in the last sweep.
    lasting_stop: Option<(f64, (f64, f64))>,
    /// Whether the last sweep's pose passed the trust gates (the pose until the next sweep is
    /// built on it, so no teach waypoint is taken from it either).
    scan_pose_trusted: bool,
    /// The SLAM frame's tilt against the GNSS track.
    tilt: crate::mission::gnss_tilt::TiltEstimator,
    /// The frame's tilt against the accelerometer's gravity.
    gravity: slam::gravity::GravityTilt,
    /// When the accelerometer last corrected the tilt (it then supersedes the GNSS track fit).
    gravity_t_s: f64,
    /// IMU samples refused (non-finite, out of order).
    imu_rejected: u64,
}

/// The accelerometer's tilt counts as live this long after its last correction (the GNSS track
/// fit then leaves the tilt alone), seconds.
const GRAVITY_FRESH_S: f64 = 5.0;

/// How the SLAM frame sits in the map frame.
#[derive(Clone, Debug)]
struct Anchor {
    map_from_slam: Isometry3<f64>,
    frame: MapFrame,
    local: Option<LocalFrame>,
}

impl Agent {
    /// A new agent for one session.
    pub fn new(
        cfg: AgentConfig,
        robot: &str,
        session_id: &str,
        start_unix_ms: u64,
    ) -> Result<Self, String> {
        let mapper =
            mapping::Mapper::new(cfg.mapper.clone()).map_err(|e| format!("mapper config: {e}"))?;
        Ok(Self {
            slam: slam::Slam::new(cfg.slam.clone()),
            mapper,
            nav: Navigator::new(cfg.nav.clone(), cfg.planner.clone()),
            repeat: None,
            repeat_paused: false,
            repeat_state: None,
            recorder: None,
            teach_views: Vec::new(),
            repeat_view: None,
            gnss: GnssTracker::new(cfg.gnss.clone()),
            follower: control::Follower::new(cfg.control.clone()),
            route_tracker: control::Follower::new(control::Config {
                lookahead_m: cfg.repeat.lookahead_m,
                rotate_in_place_rad: cfg.repeat.rotate_in_place_rad,
                ..cfg.control.clone()
            }),
            anchor: None,
            at_scan: None,
            map_from_odom: None,
            last_odom: None,
            mode: Mode::Idle,
            teleop: None,
            speed_limit_mps: cfg.control.v_max_mps,
            safety: control::SafetyVerdict::default(),
            safety_t_s: f64::NEG_INFINITY,
            pending_tiles: Vec::new(),
            path_dirty: false,
            recorded: None,
            slam_health: SlamHealth {
                ok: true,
                ..SlamHealth::default()
            },
            last_error: None,
            commands_refused: 0,
            scans: 0,
            session_id: session_id.to_string(),
            robot: robot.to_string(),
            start_unix_ms,
            last_plan_t_s: f64::NEG_INFINITY,
            last_cmd: Cmd::default(),
            gnss_rejected: 0,
            gnss_residual: None,
            scans_not_mapped: 0,
            scan_pose_trusted: true,
            lasting_stop: None,
            tilt: crate::mission::gnss_tilt::TiltEstimator::new(cfg.gnss.tilt.clone()),
            gravity: slam::gravity::GravityTilt::new(cfg.slam.gravity.clone()),
            gravity_t_s: f64::NEG_INFINITY,
            imu_rejected: 0,
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &AgentConfig {
        &self.cfg
    }

    /// Unix milliseconds of session time `t_s`.
    pub fn unix_ms(&self, t_s: f64) -> u64 {
        self.start_unix_ms + (t_s.max(0.0) * 1000.0) as u64
    }

    /// Feeds one wheel-odometry sample.
    pub fn on_odom(&mut self, o: OdomSample) {
        self.slam.push_odometry(o);
        self.last_odom = Some(o);
    }

    /// Feeds one IMU accelerometer sample; bad ones are counted, never fatal. Each is kept with
    /// the attitude the agent estimates at that moment (identity before the first scan: the
    /// body frame, which the anchor then turns into the map frame).
    pub fn on_imu(&mut self, s: &ImuSample) {
        if !self.cfg.slam.gravity.enabled {
            return;
        }
        let att = self
            .pose_now()
            .map_or_else(UnitQuaternion::identity, |p| p.iso.rotation);
        let (v, w) = self
            .last_odom
            .map_or((0.0, 0.0), |o| (o.v_mps, o.omega_rps));
        if !self
            .gravity
            .push(s.t_s, &Vector3::from(s.accel_mps2), &att, v, w)
        {
            self.imu_rejected += 1;
            self.last_error = Some(format!(
                "IMU: sample at {:.3} s refused (non-finite or out of order)",
                s.t_s
            ));
        }
    }

    /// IMU samples refused so far.
    pub fn imu_rejected(&self) -> u64 {
        self.imu_rejected
    }

    /// Feeds one NMEA sentence; bad ones are counted (and shown), never fatal.
    pub fn on_gnss(&mut self, s: &GnssSentence) {
        if let Err(e) = self.gnss.on_sentence(s.t_s, &s.text) {
            self.last_error = Some(format!("GNSS: {e}"));
            return;
        }
        self.fuse_gnss(s.t_s);
        // Re-evaluate a GNSS goal with each new fix (methods.md §5).
        if let (Some(fix), Some(pose)) = (self.gnss.fix(s.t_s), self.at_scan.map(|a| a.0.planar)) {
            let freeze = self.cfg.gnss.goal_freeze_distance_m;
            if let Some(goal) = self.nav.goal_mut() {
                if let Some(g) = goal.gnss.as_mut() {
                    g.refresh((pose.x_m, pose.y_m), &fix, freeze);
                    goal.goal_map = g.goal_map;
                }
            }
        }
    }

    /// GNSS-aided localisation: each fresh RTK fixed fix pulls the SLAM frame's anchor a little
    /// towards where GNSS puts the robot (a complementary filter), so SLAM drift stays bounded
    /// by RTK accuracy while GNSS is available; on loss, SLAM and odometry carry on alone.
    fn fuse_gnss(&mut self, t_s: f64) {
        let cfg = &self.cfg.gnss;
        let Some(fix) = self.gnss.fix(t_s) else {
            return;
        };
        // Once per fix (the sentence that brought it), RTK fixed only.
        if fix.t_s != t_s
            || fix.quality != common::geo::nmea::QUALITY_RTK_FIXED
            || cfg.fusion_gain <= 0.0
        {
            return;
        }
        let (Some(anchor), Some(est)) = (self.anchor.as_ref(), self.pose_now()) else {
            return;
        };
        let Some(local) = anchor.local.as_ref() else {
            return;
        };
        let enu = local.lla_to_enu(&fix.lla);
        let est_p = est.iso.translation.vector;
        let ant = self.cfg.gnss_antenna_xyz_m;
        let meas = enu - est.iso.rotation * Vector3::new(ant[0], ant[1], ant[2]);
        // The height creeps (height_gain << fusion_gain): pulling it fix by fix would lift and
        // drop whole sweeps against each other (rings of false steps), left alone it drifts by
        // decimetres over a few hundred metres and re-observed ground no longer meets old cells.
        let d = meas - est_p;
        self.gnss_residual = Some((t_s, d.xy().norm()));
        if d.xy().norm() > cfg.fusion_gate_m {
            self.gnss_rejected += 1;
            return;
        }
        let dyaw = self
            .gnss
            .yaw_enu_rad(t_s)
            .map(|y| common::geom::wrap_angle(y - est.planar.yaw_rad))
            .filter(|dy| dy.abs() < 10f64.to_radians())
            .map_or(0.0, |dy| dy * cfg.heading_gain);
        let k = Vector3::new(cfg.fusion_gain, cfg.fusion_gain, cfg.height_gain);
        let map_from_slam = anchor.map_from_slam;
        self.tilt.push(
            map_from_slam.inverse_transform_point(&est_p.into()).coords,
            meas,
        );
        let tilt = self
            .tilt
            .step(&map_from_slam.rotation.to_rotation_matrix())
            .unwrap_or_default();
        // The accelerometer measures the tilt directly; the track fit is for robots without one.
        let tilt = if t_s - self.gravity_t_s < GRAVITY_FRESH_S {
            Vector3::zeros()
        } else {
            tilt
        };
        // Rotate about the robot by the tilt and dyaw, then move it by k * d.
        let delta =
            Isometry3::from_parts(
                Translation3::from(est_p + d.component_mul(&k)),
                UnitQuaternion::from_scaled_axis(tilt)
                    * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), dyaw),
            ) * Isometry3::from_parts(Translation3::from(-est_p), UnitQuaternion::identity());
        self.move_frame(&delta);
    }

    /// Moves the map frame's anchoring by `delta` (map <- corrected map): the SLAM anchor, the
    /// odometry frame, the last pose, the recent map heights and the stored IMU samples all
    /// follow, so nothing measured before and after the correction disagrees by it.
    fn move_frame(&mut self, delta: &Isometry3<f64>) {
        if let Some(a) = self.anchor.as_mut() {
            a.map_from_slam = delta * a.map_from_slam;
        }
        self.mapper.follow_frame(
            delta,
            self.cfg.gnss.map_follow_radius_m,
            self.cfg.gnss.map_follow_age_s,
        );
        if let Some(m) = self.map_from_odom.as_mut() {
            *m = delta * *m;
        }
        if let Some((p, _)) = self.at_scan.as_mut() {
            *p = PoseMap::from_iso(delta * p.iso);
        }
        self.gravity.rotate_frame(&delta.rotation);
    }

    /// Tilts the frame about the robot at `pose` by the accelerometer's correction, when the
    /// last window gives one. Returns whether it did.
    fn correct_tilt_from_gravity(&mut self, t_s: f64, pose: &PoseMap) -> bool {
        let Ok(tilt) = self.gravity.correction() else {
            return false;
        };
        let p = pose.iso.translation.vector;
        let delta = Isometry3::from_parts(
            Translation3::from(p),
            UnitQuaternion::from_scaled_axis(tilt),
        ) * Isometry3::from_parts(Translation3::from(-p), UnitQuaternion::identity());
        self.move_frame(&delta);
        self.gravity_t_s = t_s;
        true
    }

    /// Anchors the SLAM frame in the map frame at the first scan.
    fn anchor_at(&mut self, t_s: f64) {
        if self.anchor.is_some() {
            return;
        }
        let fix = self.gnss.fix(t_s);
        let yaw = self.gnss.yaw_enu_rad(t_s);
        self.anchor = Some(match (self.gnss.can_anchor(t_s), fix, yaw) {
            (true, Some(fix), Some(yaw)) => {
                let datum = self.cfg.datum.unwrap_or(fix.lla);
                let local = LocalFrame::new(datum);
                let enu = local.lla_to_enu(&fix.lla);
                // The fix is the primary antenna; base_link is below/behind it.
                let ant = self.cfg.gnss_antenna_xyz_m;
                // The baseline's tilt gives the pitch (one baseline: no roll), so the map's z
                // is up along the heading from the start rather than tilted with the ground.
                let pitch = self.gnss.pitch_rad(t_s).unwrap_or(0.0);
                let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
                    * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch);
                // An accelerometer gives the roll too (and the pitch, better than a 1 m baseline).
                let rot = match self.gravity.measured_up(0.0) {
                    Ok(up_body) => {
                        let level = UnitQuaternion::from_scaled_axis(
                            slam::gravity::tilt_to_vertical(&up_body),
                        );
                        let x = level * Vector3::x();
                        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw - x.y.atan2(x.x))
                            * level
                    }
                    Err(_) => rot,
                };
                let base = enu - rot * Vector3::new(ant[0], ant[1], ant[2]);
                tracing::info!(
                    "map frame: ENU at datum {:.7}, {:.7}, {:.2} m; start pose ({:.2}, {:.2}) yaw {:.1} deg from GNSS",
                    datum.lat_deg, datum.lon_deg, datum.h_m, base.x, base.y, yaw.to_degrees()
                );
                Anchor {
                    map_from_slam: Isometry3::from_parts(Translation3::from(base), rot),
                    frame: MapFrame::EnuAtDatum,
                    local: Some(local),
                }
            }
            _ => {
                tracing::warn!("no RTK fix with heading at the first scan: the map frame is the first pose; GNSS goals are refused");
                Anchor {
                    map_from_slam: Isometry3::identity(),
                    frame: MapFrame::FirstPose,
                    local: None,
                }
            }
        });
        // IMU samples so far were kept in the body frame (no attitude yet).
        if let Some(a) = &self.anchor {
            let q = a.map_from_slam.rotation;
            self.gravity.rotate_frame(&q);
        }
    }

    /// The map frame's anchoring, once the first scan has arrived.
    pub fn map_frame(&self) -> Option<(MapFrame, Option<Datum>)> {
        self.anchor
            .as_ref()
            .map(|a| (a.frame, a.local.as_ref().map(|l| l.datum())))
    }

    /// Processes one LiDAR scan: SLAM, mapping, safety, path check.
    pub fn on_scan(&mut self, scan: &Scan) -> ScanReport {
        self.anchor_at(scan.stamp_s);
        let mut rep = ScanReport::default();
        let out = match self.slam.process(scan) {
            Ok(o) => o,
            Err(e) => {
                rep.slam_failed = true;
                self.slam_health.ok = false;
                self.slam_health.failures += 1;
                self.last_error = Some(format!("SLAM: {e}"));
                return rep;
            }
        };
        self.scans += 1;
        let d = &out.diagnostics;
        self.slam_health = SlamHealth {
            ok: !d.fell_back_to_prior,
            inlier_ratio: d.inlier_ratio as f32,
            iterations: d.iterations as u16,
            degenerate: d.degenerate,
            failures: self.slam_health.failures + u32::from(d.fell_back_to_prior),
        };
        rep.slam_failed = d.fell_back_to_prior;
        let anchored = |a: &Option<Anchor>| {
            a.as_ref()
                .map_or_else(Isometry3::identity, |a| a.map_from_slam)
        };
        let mut map_from_slam = anchored(&self.anchor);
        let mut pose = PoseMap::from_iso(map_from_slam * out.pose_map_base);
        let jump_m = self.pose_now().map_or(0.0, |p| {
            (p.iso.translation.vector - pose.iso.translation.vector)
                .xy()
                .norm()
        });
        if self.correct_tilt_from_gravity(scan.stamp_s, &pose) {
            map_from_slam = anchored(&self.anchor);
            pose = PoseMap::from_iso(map_from_slam * out.pose_map_base);
        }
        self.at_scan = Some((pose, None));
        self.map_from_odom = out.pose_map_odom.map(|m| map_from_slam * m);

        // Traversability from this sweep at the SLAM pose.
        let pose_map_lidar = map_from_slam * out.pose_map_lidar;
        let robot = mapping::RobotPose {
            x_m: pose.iso.translation.vector.x,
            y_m: pose.iso.translation.vector.y,
            z_m: pose.iso.translation.vector.z,
            yaw_rad: pose.planar.yaw_rad,
        };
        // The de-skewed sweep when SLAM made one: the raw one is smeared by the motion.
        let deskewed = out.deskewed.map(|points| Scan {
            stamp_s: scan.stamp_s,
            points,
        });
        // A sweep placed with a pose SLAM has just thrown off (or GNSS is still pulling back)
        // would paint the ground it saw, misplaced, as steps against what the map holds.
        let pitch_off = self.gnss.pitch_rad(scan.stamp_s).is_some_and(|gp| {
            let (_, pitch, _) = pose.iso.rotation.euler_angles();
            common::geom::wrap_angle(pitch - gp).abs()
                > self.cfg.gnss.pose_trust_pitch_deg.to_radians()
        });
        self.scan_pose_trusted = !(jump_m > self.cfg.gnss.pose_jump_max_m
            || pitch_off
            || !self.pose_trusted(scan.stamp_s));
        let mapped = if !self.scan_pose_trusted {
            self.scans_not_mapped += 1;
            tracing::debug!(
                "sweep at {:.2} s not mapped: pose jumped {jump_m:.2} m, or pitch or position disagrees with GNSS",
                scan.stamp_s
            );
            None
        } else {
            Some(self.mapper.update_scan(
                deskewed.as_ref().unwrap_or(scan),
                &pose_map_lidar,
                &robot,
                scan.stamp_s,
            ))
        };
        match mapped {
            None => {}
            Some(Ok(u)) => {
                rep.classified_cells = u.classified_cells;
                self.pending_tiles.extend(u.tiles);
                self.path_dirty |= u.class_changes > 0;
            }
            Some(Err(e)) => self.last_error = Some(format!("mapping: {e}")),
        }

        // Safety stop on the raw sweep, in base_link.
        let base_from_lidar = self.slam_base_from_lidar();
        self.safety = control::safety::check(
            &self.cfg.control.safety,
            scan.points.iter().map(|p| {
                let q = base_from_lidar
                    * nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                (q.x, q.y, q.z)
            }),
        );
        self.safety_t_s = scan.stamp_s;
        self.lasting_stop = match (self.safety.stop, self.safety.zone_nearest_m) {
            (true, Some((x, y))) => {
                let q = pose.iso * nalgebra::Point3::new(x, y, 0.0);
                let since = self.lasting_stop.map_or(scan.stamp_s, |(t, _)| t);
                Some((since, (q.x, q.y)))
            }
            _ => None,
        };

        // A grid change on the path asks for a replan now.
        if self.path_dirty && self.nav.is_driving() {
            let grid = self.plan_grid(&pose.planar);
            rep.path_blocked = self.nav.check_path(&grid, &pose.planar);
            self.path_dirty = false;
        }
        rep
    }

    fn slam_base_from_lidar(&self) -> Isometry3<f64> {
        let s = &self.cfg.slam.sensor;
        let [x, y, z] = s.lidar_xyz_m;
        let [r, p, yw] = s.lidar_rpy_rad;
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(r, p, yw),
        )
    }

    /// The pose now: `map<-base = map<-odom * odom<-base` with the newest odometry, so the
    /// controller sees the robot move between SLAM updates (methods.md §1).
    pub fn pose_now(&self) -> Option<PoseMap> {
        if let (Some(m), Some(o)) = (self.map_from_odom, self.last_odom) {
            return Some(PoseMap::from_iso(m * o.pose_odom.to_isometry3(0.0)));
        }
        let (at, odom_then) = self.at_scan?;
        let (Some(then), Some(now)) = (odom_then, self.last_odom.map(|o| o.pose_odom)) else {
            return Some(at);
        };
        let delta = then.inverse().compose(&now);
        let iso = at.iso * delta.to_isometry3(0.0);
        Some(PoseMap::from_iso(iso))
    }

    /// Changed tiles since the last call (already versioned by the mapper).
    pub fn take_tiles(&mut self) -> Vec<Tile> {
        std::mem::take(&mut self.pending_tiles)
    }

    /// All current tiles (for a late-joining station).
    pub fn all_tiles(&self) -> Vec<Tile> {
        self.mapper.tiles()
    }

    /// Sweeps left out of the map because their pose was not trusted (a SLAM glitch).
    pub fn scans_not_mapped(&self) -> u64 {
        self.scans_not_mapped
    }

    /// The safety check of the last sweep (diagnostics).
    pub fn safety(&self) -> control::SafetyVerdict {
        self.safety
    }

    /// The mapper (evaluation, rendering).
    pub fn mapper(&self) -> &mapping::Mapper {
        &self.mapper
    }

    /// The SLAM state (evaluation).
    pub fn slam(&self) -> &slam::Slam {
        &self.slam
    }

    /// The planning window around `pose` and the mapper's cells in it: what both the planning
    /// grid and a route's corridor grid are built from (read once per cycle).
    fn planning_window(&self, pose: &Pose2) -> (GridWindow, mapping::PlannerView) {
        let window = GridWindow::centred(
            self.mapper.lattice(),
            pose.x_m,
            pose.y_m,
            self.cfg.planner.num_of_grid_cells,
        );
        let view = self
            .mapper
            .view(window.min_cx, window.min_cy, window.width, window.height);
        (window, view)
    }

    /// How far either side of a taught route its corridor reaches: the robot's half width plus
    /// `corridor_margin_m`, metres.
    fn corridor_radius_m(&self) -> f64 {
        0.5 * self.cfg.profile.width_m + self.cfg.repeat.corridor_margin_m
    }

    /// Logs (debug) the obstacle cells within the corridor's reach of a blocked route point,
    /// with why each is what it is.
    fn log_blocking_cells(&self, at_m: (f64, f64)) {
        let lattice = self.mapper.lattice();
        let (cx, cy) = lattice.cell_of(at_m.0, at_m.1);
        let r = self.corridor_radius_m() / lattice.cell_size_f64();
        let r = r.ceil() as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                if self.mapper.class(cx + dx, cy + dy).is_obstacle() {
                    let taught = self
                        .repeat_view
                        .as_ref()
                        .and_then(|v| v.get(cx + dx, cy + dy));
                    tracing::debug!(
                        "repeat: blocking {}; at teach time {:?}; top now {:?}",
                        self.mapper.describe(cx + dx, cy + dy),
                        taught,
                        self.robust_top_m(cx + dx, cy + dy)
                    );
                }
            }
        }
    }

    /// Whether the pose agrees with the last RTK fixed fix (or there is no fresh one to ask).
    fn pose_trusted(&self, t_s: f64) -> bool {
        self.gnss_residual.is_none_or(|(t, r)| {
            t_s - t > self.cfg.gnss.fix_timeout_s || r <= self.cfg.gnss.pose_trust_residual_m
        })
    }

    /// The teach-time view of the cells a repeat's corridor check can reach along `points`.
    fn capture_teach_view(&self, points: &[common::msg::RoutePoint]) -> TeachView {
        let line: Vec<(f64, f64)> = points.iter().map(|p| (p.x_m, p.y_m)).collect();
        let r_m = self.corridor_radius_m();
        let m = &self.mapper;
        TeachView::capture(&line, r_m, &m.lattice(), |cx, cy| {
            let (ground, (_, top)) = (m.height_m(cx, cy)?, m.height_range(cx, cy)?);
            Some(TaughtCell {
                obstacle: m.class(cx, cy).is_obstacle(),
                ground_m: ground as f32,
                top_m: top,
            })
        })
    }

    /// How high a cell's evidence stands, robust to a stray return or two: its highest point,
    /// but no more than two standard deviations above its mean (a car or a trunk fills its
    /// cells with returns; a single point 30 cm up in grass does not).
    /// When the cell's newest evidence epoch alone holds `newest_evidence_min_points` returns,
    /// it is judged on that epoch: what stands there now (a person who crossed the route a
    /// minute ago left returns in the older epoch that the newer one, all ground, contradicts).
    fn robust_top_m(&self, cx: i64, cy: i64) -> Option<f32> {
        let newest = self.mapper.newest_height_stats(cx, cy);
        let s = if newest.n >= self.cfg.repeat.newest_evidence_min_points {
            newest
        } else {
            self.mapper.height_stats(cx, cy)
        };
        (s.n > 0).then(|| s.max_m.min(s.mean_m + 2.0 * s.var_m2.sqrt()) as f32)
    }

    /// The grid a taught route's corridor is checked on: only cells the mapper classified as
    /// obstacles (and, with the teach-time view, only those standing higher than at teach
    /// time), grown by the robot's half width plus `corridor_margin_m`.
    fn corridor_grid(&self, window: &GridWindow, view: &mapping::PlannerView) -> PlanGrid {
        let s = window.lattice.cell_size_f64();
        // The same cells as `plan_grid` (`PlanGrid::from_cells` puts the origin there too).
        let origin = (window.min_cx as f64 * s, window.min_cy as f64 * s);
        let mut grid = PlanGrid::new(window.width, window.height, s, origin);
        let r_m = self.corridor_radius_m();
        let r = (r_m / s).floor() as i64;
        let rise = self.cfg.repeat.new_obstacle_rise_m as f32;
        let disc: Vec<(i64, i64)> = (-r..=r)
            .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
            .filter(|(dx, dy)| ((dx * dx + dy * dy) as f64).sqrt() * s <= r_m)
            .collect();
        for gy in 0..i64::from(window.height) {
            for gx in 0..i64::from(window.width) {
                let (cx, cy) = (window.min_cx + gx, window.min_cy + gy);
                let c = view.get(cx, cy);
                let new = || {
                    self.repeat_view
                        .as_ref()
                        .is_none_or(|v| v.is_new_obstacle(cx, cy, self.robust_top_m(cx, cy), rise))
                };
                if c.state == common::grid::CellState::Obstacle && new() {
                    for (dx, dy) in &disc {
                        if grid.contains(gx + dx, gy + dy) {
                            grid.set_blocked(gx + dx, gy + dy);
                        }
                    }
                }
            }
        }
        grid
    }

    /// Where a safety stop that has held for `safety_stop_block_s` stands (map frame): something
    /// the robot may not touch, beside the corridor or too low or too new to be in the map (a
    /// person who stopped to let the robot pass, at the robot's shoulder).
    fn lasting_stop_m(&self) -> Option<(f64, f64)> {
        let (since, at) = self.lasting_stop?;
        (self.safety_t_s - since >= self.cfg.repeat.safety_stop_block_s).then_some(at)
    }

    /// Blocks the cells a lasting stop's point makes undriveable for the body's centre (within
    /// the stop zone's half width of it), except under the robot's own footprint (`keep_free`)
    /// where a plan has to start.
    fn stamp_lasting_stop(&self, grid: &mut PlanGrid, keep_free: Option<(&Pose2, f64)>) {
        let Some(p) = self.lasting_stop_m() else {
            return;
        };
        let sc = &self.cfg.control.safety;
        let s = grid.cell_size_m();
        let r_m = 0.5 * sc.body_width_m + sc.stop_side_m + s;
        let (px, py) = grid.world_to_cell_unbounded(p.0, p.1);
        let r = (r_m / s).ceil() as i64;
        for y in py - r..=py + r {
            for x in px - r..=px + r {
                if !grid.contains(x, y) {
                    continue;
                }
                let c = grid.cell_center_m(planning::CellXY {
                    x: x as u32,
                    y: y as u32,
                });
                let under_robot = keep_free
                    .is_some_and(|(robot, fr)| (c.0 - robot.x_m).hypot(c.1 - robot.y_m) <= fr);
                if (c.0 - p.0).hypot(c.1 - p.1) <= r_m && !under_robot {
                    grid.set_blocked(x, y);
                }
            }
        }
    }

    /// The planning grid around a pose, from the mapper's cells.
    pub fn plan_grid(&self, pose: &Pose2) -> PlanGrid {
        let (window, view) = self.planning_window(pose);
        self.plan_grid_in(pose, &window, &view)
    }

    fn plan_grid_in(
        &self,
        pose: &Pose2,
        window: &GridWindow,
        view: &mapping::PlannerView,
    ) -> PlanGrid {
        let lattice = window.lattice;
        let rule = CostRule::from_config(&self.cfg.planner);
        let mut grid = PlanGrid::from_cells(window, &rule, |cx, cy| view.get(cx, cy));
        // The robot stands on its footprint, so those cells are driveable whatever inflation says
        // (a walker passing close inflates the cells around the robot and would wall it in).
        // Cells classified as obstacles themselves stay blocked.
        let r_m = 0.5 * self.cfg.profile.length_m.max(self.cfg.profile.width_m);
        let s = lattice.cell_size_f64();
        let r_cells = (r_m / s).ceil() as i64;
        let (rcx, rcy) = lattice.cell_of(pose.x_m, pose.y_m);
        for cy in rcy - r_cells..=rcy + r_cells {
            for cx in rcx - r_cells..=rcx + r_cells {
                let (x, y) = lattice.cell_center_m(cx, cy);
                if (x - pose.x_m).hypot(y - pose.y_m) > r_m + 0.5 * s {
                    continue;
                }
                let (gx, gy) = (cx - window.min_cx, cy - window.min_cy);
                if view.get(cx, cy).state != common::grid::CellState::Obstacle
                    && !grid.is_free(gx, gy)
                    && grid.contains(gx, gy)
                {
                    grid.set(gx, gy, 0.0, false);
                }
            }
        }
        self.stamp_lasting_stop(&mut grid, Some((pose, r_m + 0.5 * s)));
        grid
    }

    /// The lattice tiles live on.
    pub fn lattice(&self) -> Lattice {
        self.mapper.lattice()
    }

    // ---- commands ----

    /// A goal command; refused ones set `last_error` and return the reason.
    pub fn on_goal(&mut self, g: &GoalCmd) -> Result<(), String> {
        let pose = self.pose_now().map(|p| p.planar).unwrap_or_default();
        let (goal_map, gnss) = match g.target {
            GoalTarget::Map { x_m, y_m } => ((x_m, y_m), None),
            GoalTarget::Gnss {
                lat_deg,
                lon_deg,
                h_m,
            } => {
                let local = self.anchor.as_ref().and_then(|a| a.local.as_ref());
                let fix = self.gnss.fix(
                    self.at_scan
                        .map(|_| self.last_odom.map_or(0.0, |o| o.t_s))
                        .unwrap_or(0.0),
                );
                match GnssGoal::new(
                    lat_deg,
                    lon_deg,
                    h_m,
                    local,
                    (pose.x_m, pose.y_m),
                    fix.as_ref(),
                ) {
                    Ok(gg) => (gg.goal_map, Some(gg)),
                    Err(e) => return Err(self.refuse(format!("goal: {e}"))),
                }
            }
        };
        self.repeat = None;
        self.teleop = None;
        self.mode = Mode::Goal;
        self.nav.set_goal(Goal {
            id: g.goal_id,
            goal_map,
            tolerance_m: f64::from(g.tolerance_m),
            gnss,
        });
        Ok(())
    }

    fn refuse(&mut self, reason: String) -> String {
        self.commands_refused += 1;
        self.last_error = Some(reason.clone());
        tracing::warn!("refused: {reason}");
        reason
    }

    /// Counts a command the bus refused (bad payload or out of range).
    pub fn on_refused(&mut self, reason: &str) {
        self.refuse(reason.to_string());
    }

    /// Stop now: ends any mission and teleop.
    pub fn on_stop(&mut self, reason: &str) {
        self.nav.stop(if reason.is_empty() {
            "stopped by the operator"
        } else {
            reason
        });
        self.repeat = None;
        self.teleop = None;
        self.mode = Mode::Idle;
    }

    /// Teleop: drive commands win over missions while they keep coming.
    pub fn on_drive(&mut self, t_s: f64, d: &DriveCmd) {
        if let Some((_, last)) = &self.teleop {
            if d.seq <= last.seq && d.seq != 0 {
                return;
            }
        }
        if self.mode != Mode::Teleop {
            self.nav.stop("operator took over (teleop)");
            self.repeat = None;
        }
        self.mode = Mode::Teleop;
        self.teleop = Some((t_s, d.clone()));
    }

    /// Speed limit, clamped to the controller's own.
    pub fn on_speed(&mut self, limit_mps: f64) {
        self.speed_limit_mps = limit_mps.clamp(0.0, self.cfg.control.v_max_mps);
    }

    /// Route commands: record, stop recording, repeat, pause, resume, cancel.
    pub fn on_route(&mut self, t_s: f64, cmd: &RouteCmd) -> Result<(), String> {
        match cmd {
            RouteCmd::Record { name } => {
                self.recorder = Some(RouteRecorder::new(self.cfg.teach.clone(), name.clone()));
                if let Some(p) = self.pose_now() {
                    let lla = self.lla_of(&p);
                    let ms = self.unix_ms(t_s);
                    if let Some(r) = self.recorder.as_mut() {
                        r.offer(p.planar, lla, ms);
                    }
                }
                Ok(())
            }
            RouteCmd::StopRecording => {
                let Some(rec) = self.recorder.take() else {
                    return Err(self.refuse("route: not recording".into()));
                };
                let pose = self.pose_now().map(|p| p.planar).unwrap_or_default();
                let lla = self.pose_now().and_then(|p| self.lla_of(&p));
                let name = rec.name().to_string();
                let points = rec.finish(pose, lla, self.unix_ms(t_s));
                let route_id = format!("{}-{}", self.session_id, self.unix_ms(t_s));
                let view = self.capture_teach_view(&points);
                tracing::info!(
                    "teach: route {route_id}, {} waypoints, {} cells of teach-time traversability kept",
                    points.len(),
                    view.len()
                );
                // A session teaches a handful of routes; keep the last few views.
                if self.teach_views.len() >= 8 {
                    self.teach_views.remove(0);
                }
                self.teach_views.push((route_id.clone(), view));
                self.recorded = Some(Route {
                    route_id,
                    name,
                    robot: self.robot.clone(),
                    session_id: self.session_id.clone(),
                    datum: self.map_frame().and_then(|f| f.1),
                    points,
                });
                Ok(())
            }
            RouteCmd::Repeat { route, direction } => {
                if route.points.len() < 2 {
                    return Err(self.refuse("route: fewer than 2 waypoints".into()));
                }
                let pts = self.route_in_map(route)?;
                let ordered: Vec<(f64, f64)> = match direction {
                    RouteDirection::Forward => pts,
                    RouteDirection::Reverse => pts.into_iter().rev().collect(),
                };
                let pose = self.pose_now().map(|p| p.planar).unwrap_or_default();
                self.nav.stop("route repeat started");
                self.teleop = None;
                self.mode = Mode::Repeat;
                self.repeat_paused = false;
                self.repeat_view = self
                    .teach_views
                    .iter()
                    .find(|(id, _)| *id == route.route_id && route.session_id == self.session_id)
                    .map(|(_, v)| v.clone());
                self.repeat = Some((
                    RouteFollower::new(self.cfg.repeat.clone(), &ordered, &pose),
                    route.clone(),
                ));
                Ok(())
            }
            RouteCmd::Pause => {
                self.repeat_paused = true;
                Ok(())
            }
            RouteCmd::Resume => {
                self.repeat_paused = false;
                Ok(())
            }
            RouteCmd::Cancel => {
                self.repeat = None;
                self.mode = Mode::Idle;
                self.nav.stop("route repeat cancelled");
                Ok(())
            }
        }
    }

    /// The route's waypoints in this session's map frame: through lat/lon when both have a
    /// datum, as recorded when the route was taught in this session's frame.
    fn route_in_map(&mut self, route: &Route) -> Result<Vec<(f64, f64)>, String> {
        let local = self.anchor.as_ref().and_then(|a| a.local);
        let same_session = route.session_id == self.session_id;
        match (
            local,
            route
                .points
                .iter()
                .all(|p| p.lat_deg.is_some() && p.lon_deg.is_some()),
        ) {
            (Some(l), true) if !same_session || route.datum != Some(l.datum()) => Ok(route
                .points
                .iter()
                .map(|p| {
                    let e = l.lla_to_enu(&Datum {
                        lat_deg: p.lat_deg.unwrap_or_default(),
                        lon_deg: p.lon_deg.unwrap_or_default(),
                        h_m: p.h_m.unwrap_or(l.datum().h_m),
                    });
                    (e.x, e.y)
                })
                .collect()),
            _ if same_session || route.datum.is_none() => {
                Ok(route.points.iter().map(|p| (p.x_m, p.y_m)).collect())
            }
            _ => Err(self
                .refuse("route: recorded in another frame and this session has no datum".into())),
        }
    }

    /// The recorded route, once, after recording stopped.
    pub fn take_recorded(&mut self) -> Option<Route> {
        self.recorded.take()
    }

    fn lla_of(&self, p: &PoseMap) -> Option<(f64, f64, f64)> {
        let l = self.anchor.as_ref()?.local.as_ref()?;
        let t = p.iso.translation.vector;
        let d = l.enu_to_lla(&Vector3::new(t.x, t.y, t.z));
        Some((d.lat_deg, d.lon_deg, d.h_m))
    }

    // ---- the loop's periodic work ----

    /// Plans when due (goal) or runs a repeat cycle; returns true when a plan was computed (the
    /// caller times this call).
    pub fn plan_if_due(&mut self, t_s: f64) -> bool {
        let Some(pose) = self.pose_now() else {
            return false;
        };
        if self.mode == Mode::Repeat {
            if t_s - self.last_plan_t_s < 1.0 / self.cfg.planner.replan_rate_hz {
                return false;
            }
            self.last_plan_t_s = t_s;
            let (window, view) = self.planning_window(&pose.planar);
            let grid = self.plan_grid_in(&pose.planar, &window, &view);
            let mut corridor = self.corridor_grid(&window, &view);
            // A stop that lasts is a blockage of the route (the person will not move while the
            // robot is in the way): wait, then detour round it, like any other.
            self.stamp_lasting_stop(&mut corridor, None);
            // Blocked points whose cells are worth a log line, once the follower is let go.
            let mut explain: Vec<(f64, f64)> = Vec::new();
            if let Some((f, _)) = self.repeat.as_mut() {
                let before = f.detours.last().map(|d| (f.detours.len(), d.replans));
                let state = f.update_with_corridor(&pose.planar, &grid, &corridor, t_s);
                // A wait is logged once, when it begins.
                let was_waiting = matches!(
                    self.repeat_state,
                    Some(RepeatState::Waiting { holding: true, .. })
                );
                self.repeat_state = Some(state.clone());
                if let Some(d) = f.detours.last() {
                    if before != Some((f.detours.len(), d.replans)) {
                        let (cx, cy) = self.mapper.lattice().cell_of(d.blocked_m.0, d.blocked_m.1);
                        tracing::info!(
                            "repeat: detour {} (re-plan {}) around ({:.1}, {:.1}) [{:?}], rejoins taught point {} at ({:.1}, {:.1}), {:.1} m",
                            f.detours.len(),
                            d.replans,
                            d.blocked_m.0,
                            d.blocked_m.1,
                            self.mapper.class(cx, cy),
                            d.rejoin_taught,
                            d.rejoin_m.0,
                            d.rejoin_m.1,
                            d.length_m
                        );
                        explain.push(d.blocked_m);
                    }
                }
                match state {
                    RepeatState::Following => {}
                    RepeatState::Waiting { at_m, holding } => {
                        if holding && !was_waiting {
                            tracing::info!(
                                "repeat: waiting for the route to clear at ({:.1}, {:.1})",
                                at_m.0,
                                at_m.1
                            );
                        }
                    }
                    RepeatState::Blocked(why) => {
                        let e = format!("repeat: holding: {why}");
                        if self.last_error.as_deref() != Some(e.as_str()) {
                            tracing::warn!("{e}");
                            explain.extend(f.blockage_m());
                        }
                        self.last_error = Some(e);
                    }
                    RepeatState::Finished => {
                        self.mode = Mode::Idle;
                        self.nav.stop("route finished");
                    }
                }
            }
            for at in explain {
                self.log_blocking_cells(at);
            }
            return true;
        }
        if !self.nav.wants_replan(t_s) {
            return false;
        }
        let grid = self.plan_grid(&pose.planar);
        self.nav.replan(t_s, &pose.planar, &grid);
        true
    }

    /// The command for now (call at the control rate).
    pub fn control(&mut self, t_s: f64) -> Cmd {
        let Some(pose) = self.pose_now() else {
            return Cmd::default();
        };
        let lla = self.lla_of(&pose);
        let ms = self.unix_ms(t_s);
        // A single sweep that SLAM placed 0.4 m off at a ramp's foot became a taught waypoint
        // the repeat then steered to.
        let trusted = self.pose_trusted(t_s) && self.scan_pose_trusted;
        if let Some(rec) = self.recorder.as_mut().filter(|_| trusted) {
            rec.offer(pose.planar, lla, ms);
        }
        // A stale sweep cannot vouch for the space ahead: treat it as a stop.
        let safety_fresh = t_s - self.safety_t_s <= self.cfg.safety_scan_timeout_s;
        let stop_ahead = !safety_fresh || self.safety.stop;
        let cmd = match self.mode {
            Mode::Teleop => match &self.teleop {
                Some((t, d)) if d.deadman && t_s - t <= self.cfg.deadman_s => {
                    let v = f64::from(d.v_mps).clamp(-self.speed_limit_mps, self.speed_limit_mps);
                    let v = if stop_ahead && v > 0.0 { 0.0 } else { v };
                    Cmd {
                        v_mps: v,
                        omega_rps: f64::from(d.omega_rps),
                    }
                }
                _ => Cmd::default(),
            },
            Mode::Goal => {
                if self.nav.check_reached(&pose.planar) {
                    self.mode = Mode::Idle;
                }
                self.nav.set_blocked(
                    self.nav.is_driving() && stop_ahead && self.safety.stop,
                    "safety stop: obstacle close to the robot",
                );
                if self.nav.is_driving()
                    || self.nav.state() == MissionState::Blocked && !self.nav.path().is_empty()
                {
                    let path = self.nav.path().to_vec();
                    self.follow(&pose.planar, &path, stop_ahead, true)
                } else {
                    Cmd::default()
                }
            }
            Mode::Repeat if self.repeat_holding() => Cmd::default(),
            Mode::Repeat if !self.repeat_paused => {
                let path = self
                    .repeat
                    .as_ref()
                    .map(|(f, _)| f.follow_path(&pose.planar))
                    .unwrap_or_default();
                self.follow_route(&pose.planar, &path, stop_ahead)
            }
            _ => Cmd::default(),
        };
        self.last_cmd = cmd;
        cmd
    }

    fn follow(&mut self, pose: &Pose2, path: &[(f64, f64)], stop_ahead: bool, to_end: bool) -> Cmd {
        self.follow_with(false, pose, path, stop_ahead, to_end)
    }

    fn follow_route(&mut self, pose: &Pose2, path: &[(f64, f64)], stop_ahead: bool) -> Cmd {
        self.follow_with(true, pose, path, stop_ahead, true)
    }

    /// Follows `path` with the goal controller or the taught-route tracker.
    fn follow_with(
        &self,
        route: bool,
        pose: &Pose2,
        path: &[(f64, f64)],
        stop_ahead: bool,
        to_end: bool,
    ) -> Cmd {
        if path.len() < 2 {
            return Cmd::default();
        }
        let follower = if route {
            &self.route_tracker
        } else {
            &self.follower
        };
        let c = follower.command(
            pose,
            path,
            self.speed_limit_mps,
            self.safety.clearance_m,
            to_end,
        );
        self.gate(c, stop_ahead)
    }

    fn gate(&self, c: control::FollowerCmd, stop_ahead: bool) -> Cmd {
        let mut cmd = Cmd {
            v_mps: c.v_mps,
            omega_rps: c.omega_rps,
        };
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

    // ---- what the agent tells the world ----

    /// The pose message for now.
    pub fn pose_msg(&self, t_s: f64, seq: u32) -> Option<Pose> {
        let p = self.pose_now()?;
        let (roll, pitch, yaw) = p.iso.rotation.euler_angles();
        let t = p.iso.translation.vector;
        Some(Pose {
            t_unix_ms: self.unix_ms(t_s),
            seq,
            x_m: t.x,
            y_m: t.y,
            z_m: t.z,
            yaw_rad: yaw as f32,
            pitch_rad: pitch as f32,
            roll_rad: roll as f32,
            v_mps: self.last_odom.map_or(0.0, |o| o.v_mps) as f32,
            omega_rps: self.last_odom.map_or(0.0, |o| o.omega_rps) as f32,
            fix: self.gnss.fix_state(t_s),
            lat_lon_deg: self.lla_of(&p).map(|l| (l.0, l.1)),
        })
    }

    /// The status message for now.
    pub fn status(&self, t_s: f64) -> Status {
        let pose = self.pose_now().map(|p| p.planar).unwrap_or_default();
        let (mission, reason) = match self.mode {
            Mode::Teleop => (MissionState::Driving, "teleop".to_string()),
            Mode::Repeat if self.repeat_paused => {
                (MissionState::Paused, "route repeat paused".into())
            }
            Mode::Repeat => (
                if self.safety.stop {
                    MissionState::Blocked
                } else {
                    MissionState::Driving
                },
                "repeating route".into(),
            ),
            _ => (self.nav.state(), self.nav.reason().to_string()),
        };
        let route = self.repeat.as_ref().map(|(f, r)| {
            let (k, n, left) = f.progress(&pose);
            RouteProgress {
                route_id: r.route_id.clone(),
                waypoint: k as u32,
                waypoints: n as u32,
                distance_left_m: left as f32,
                detours: f.detours.len() as u32,
            }
        });
        let anchored_by_gnss = self
            .anchor
            .as_ref()
            .is_some_and(|a| a.frame == MapFrame::EnuAtDatum);
        Status {
            t_unix_ms: self.unix_ms(t_s),
            mode: self.mode,
            mission,
            reason,
            goal_m: self.nav.goal().map(|g| g.goal_map),
            goal_id: self.nav.goal().map_or(0, |g| g.id),
            fix: self.gnss.fix_state(t_s),
            gnss_lost: anchored_by_gnss && self.gnss.fix(t_s).is_none(),
            slam: self.slam_health.clone(),
            speed_limit_mps: self.speed_limit_mps as f32,
            recording: self.recorder.is_some(),
            route,
            last_error: self.last_error.clone(),
            commands_refused: self.commands_refused,
            decode_errors: 0,
            collisions: 0,
            scan_hz: 0.0,
            plan_hz: 0.0,
        }
    }

    /// The path being followed (goal or route), map frame.
    pub fn current_path(&self) -> Vec<(f64, f64)> {
        match (&self.mode, &self.repeat, self.pose_now()) {
            (Mode::Repeat, Some((f, _)), Some(p)) => f.path_ahead(&p.planar),
            _ => self.nav.path().to_vec(),
        }
    }

    /// The navigator (state, replans).
    pub fn navigator(&self) -> &Navigator {
        &self.nav
    }

    /// The last repeat cycle's outcome, while repeating.
    pub fn repeat_state(&self) -> Option<&RepeatState> {
        self.repeat_state.as_ref()
    }

    /// The route follower, while repeating.
    pub fn route_follower(&self) -> Option<&RouteFollower> {
        self.repeat.as_ref().map(|(f, _)| f)
    }

    /// The last error or refusal, for operators and logs.
    pub fn last_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    /// Whether a repeat holds the robot still (waiting for, or unable to get round, a blockage).
    pub fn repeat_holding(&self) -> bool {
        self.repeat.as_ref().is_some_and(|(f, _)| f.holding())
    }

    /// The mode the agent is in.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The last command returned by [`Agent::control`].
    pub fn last_cmd(&self) -> Cmd {
        self.last_cmd
    }

    /// Scans processed.
    pub fn scans(&self) -> u32 {
        self.scans
    }
}

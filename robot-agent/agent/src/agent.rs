//! [`Agent`]: one robot's pipeline, a short orchestrator over its parts.
//!
//! ```text
//! odometry, IMU, GNSS, sweeps ─▶ Localiser ─▶ pose ─┬─▶ TerrainMap (mapper, planning grids)
//!                                   │ frame shifts ──┘          │
//!          commands ─▶ MissionMachine (Idle|Goal|Teleop|Teach|Repeat) ◀── plans ─┘
//!                                   │
//!                 sweep ─▶ Driver (followers, safety gate) ─▶ Cmd
//! ```
//!
//! The agent is driven by a loop that feeds it time-stamped data and asks for a command at the
//! control rate ([`Agent::tick`]); it never reads a clock, so the same code runs in the headless
//! simulator (faster than real time), on a real robot, in a replay and in tests.

use crate::command::TaughtRoute;
use crate::config::AgentConfig;
use crate::driver::{Cmd, Driver, DriverConfig, Tracker};
use crate::localiser::{Localiser, PoseMap};
use crate::mission::navigate::Navigator;
use crate::mission::repeat::RepeatState;
use crate::mission::teach_view::TeachView;
use crate::mission::{Event, MissionMachine, Mode, Phase};
use crate::terrain::TerrainMap;
use crate::zones::ZoneMap;
use common::grid::TileIndex;
use sensing::{GnssSentence, ImuSample, OdomSample, Scan};
use std::collections::BTreeSet;

mod commands;
mod report;

/// What one sweep did.
#[derive(Clone, Debug, Default)]
pub struct ScanReport {
    /// SLAM fell back to its prior (or failed outright).
    pub slam_failed: bool,
    /// Grid cells reclassified.
    pub classified_cells: usize,
    /// The path ahead became blocked.
    pub path_blocked: bool,
    /// The sweep was left out of the map (its pose was not trusted).
    pub not_mapped: bool,
}

/// Who the agent is: its robot and session.
#[derive(Clone, Debug, PartialEq)]
pub struct Identity {
    /// Robot id.
    pub robot: String,
    /// Session id.
    pub session_id: String,
    /// Unix milliseconds of session time 0.
    pub start_unix_ms: u64,
}

/// How many teach-time views a session keeps (a session teaches a handful of routes).
const TEACH_VIEWS_KEPT: usize = 8;

/// The robot agent. See the module docs.
pub struct Agent {
    cfg: AgentConfig,
    id: Identity,
    localiser: Localiser,
    terrain: TerrainMap,
    mission: MissionMachine,
    driver: Driver,
    /// The local traversability seen while teaching, by route id (this session's routes).
    teach_views: Vec<(String, TeachView)>,
    /// Tiles whose cells changed since they were last asked for.
    changed_tiles: BTreeSet<TileIndex>,
    /// The grid changed since the path was last checked against it.
    path_dirty: bool,
    taught: Option<TaughtRoute>,
    last_plan_t_s: f64,
    last_error: Option<String>,
    commands_refused: u32,
    scans_not_mapped: u64,
    /// The last sweep's pose was trusted for mapping (depth frames follow it).
    pose_trusted: bool,
    base_from_depth: nalgebra::Isometry3<f64>,
    depth_frames: u64,
    /// Keep-out and slow zones in the map frame.
    zones: ZoneMap,
    /// How far keep-out cells reach beyond a zone's edge: half the body's width and a margin
    /// for the follower, metres.
    keep_out_margin_m: f64,
}

/// Clearance kept between the body's side and a keep-out zone's edge, metres: pure pursuit cuts
/// corners by a few centimetres, and a zone is a line the body must not cross.
const KEEP_OUT_CLEARANCE_M: f64 = 0.2;

impl Agent {
    /// A new agent for one session.
    pub fn new(cfg: AgentConfig, id: Identity) -> Result<Self, mapping::MapError> {
        let driver = Driver::new(DriverConfig {
            control: cfg.control.clone(),
            route_lookahead_m: cfg.repeat.lookahead_m,
            route_rotate_in_place_rad: cfg.repeat.rotate_in_place_rad,
            deadman_s: cfg.deadman_s,
            safety_scan_timeout_s: cfg.safety_scan_timeout_s,
            safety_stop_block_s: cfg.repeat.safety_stop_block_s,
            brake_mps2: cfg.profile.max_accel_mps2,
        });
        Ok(Self {
            localiser: Localiser::new(&cfg),
            terrain: TerrainMap::new(&cfg)?,
            mission: MissionMachine::new(Navigator::new(cfg.nav.clone(), cfg.planner.clone())),
            driver,
            teach_views: Vec::new(),
            changed_tiles: BTreeSet::new(),
            path_dirty: false,
            taught: None,
            last_plan_t_s: f64::NEG_INFINITY,
            last_error: None,
            commands_refused: 0,
            scans_not_mapped: 0,
            pose_trusted: false,
            base_from_depth: cfg.profile.depth_camera.isometry(),
            depth_frames: 0,
            zones: ZoneMap::default(),
            keep_out_margin_m: 0.5 * cfg.profile.width_m + KEEP_OUT_CLEARANCE_M,
            cfg,
            id,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &AgentConfig {
        &self.cfg
    }

    /// Who the agent is.
    pub fn identity(&self) -> &Identity {
        &self.id
    }

    /// Unix milliseconds of session time `t_s`.
    pub fn unix_ms(&self, t_s: f64) -> u64 {
        self.id.start_unix_ms + (t_s.max(0.0) * 1000.0) as u64
    }

    // ---- sensor data ----

    /// Feeds one wheel-odometry sample.
    pub fn on_odom(&mut self, o: OdomSample) {
        self.localiser.on_odom(o);
    }

    /// Feeds one IMU sample; a bad one is counted and shown, never fatal.
    pub fn on_imu(&mut self, s: &ImuSample) {
        if let Err(e) = self.localiser.on_imu(s) {
            self.last_error = Some(e);
        }
    }

    /// Feeds one NMEA sentence; a bad one is counted and shown, never fatal.
    pub fn on_gnss(&mut self, s: &GnssSentence) {
        let update = self.localiser.on_gnss(s);
        self.after_gnss(s.t_s, update);
    }

    /// Feeds one fix a driver decoded (ROS `NavSatFix`, gpsd); a bad one is counted and shown.
    pub fn on_gnss_fix(&mut self, f: &sensing::GnssFixSample) {
        let update = self.localiser.on_gnss_fix(f);
        self.after_gnss(f.t_s, update);
    }

    /// Feeds one true heading a driver decoded; a bad one is counted and shown.
    pub fn on_gnss_heading(&mut self, h: &sensing::GnssHeadingSample) {
        if let Err(e) = self.localiser.on_gnss_heading(h) {
            self.last_error = Some(e);
        }
    }

    fn after_gnss(&mut self, t_s: f64, update: Result<crate::localiser::GnssUpdate, String>) {
        let update = match update {
            Ok(u) => u,
            Err(e) => {
                self.last_error = Some(e);
                return;
            }
        };
        if let Some(shift) = update.shift {
            self.terrain.follow_frame(&shift);
        }
        // Re-evaluate a GNSS goal with each new fix (docs/algorithms.md §5.2).
        if let (Some(fix), Some(pose)) = (self.localiser.fix(t_s), self.localiser.pose_now()) {
            let freeze = self.localiser.gnss_config().goal_freeze_distance_m;
            if let Some(goal) = self.mission.nav_mut().goal_mut() {
                if let Some(g) = goal.gnss.as_mut() {
                    g.refresh((pose.planar.x_m, pose.planar.y_m), &fix, freeze);
                    goal.goal_map = g.goal_map;
                }
            }
        }
    }

    /// Processes one LiDAR sweep: localisation, mapping, the safety check, the path check.
    pub fn on_scan(&mut self, scan: &Scan) -> ScanReport {
        self.on_scan_probed(scan, &mut crate::NoProbe)
    }

    /// [`Agent::on_scan`], marking the end of each stage on `probe` (how the pipeline bench
    /// times the stages without the agent reading a clock).
    pub fn on_scan_probed(&mut self, scan: &Scan, probe: &mut dyn crate::Probe) -> ScanReport {
        use crate::Stage;
        let mut rep = ScanReport::default();
        let loc = self.localiser.on_scan(scan);
        probe.mark(Stage::Localise);
        let loc = match loc {
            Ok(l) => l,
            Err(e) => {
                rep.slam_failed = true;
                self.last_error = Some(e.to_string());
                return rep;
            }
        };
        rep.slam_failed = loc.fell_back;
        self.pose_trusted = loc.trusted;
        for shift in &loc.shifts {
            self.terrain.follow_frame(shift);
        }
        // The pose graph moved the past: the map is rebuilt at the corrected poses, a few
        // kept sweeps per live sweep, and replaces the live map once it has caught up.
        let localiser = &self.localiser;
        let base_from_lidar = *localiser.base_from_lidar();
        let rebuilt = if loc.graph_optimised {
            self.terrain.correct(scan.stamp_s, &base_from_lidar, |t| {
                localiser.graph_map_from_slam_at(t)
            })
        } else {
            Ok(Vec::new())
        }
        .and_then(|mut tiles| {
            tiles.extend(
                self.terrain
                    .advance_rebuild(scan.stamp_s, &base_from_lidar)?,
            );
            Ok(tiles)
        });
        match rebuilt {
            Ok(tiles) => {
                if !tiles.is_empty() {
                    let (n, kept) = self.terrain.rebuild_counts();
                    tracing::info!(
                        "map rebuilt at {:.2} s after a pose graph correction (rebuild {n}, {kept} sweeps): {} tiles to publish again",
                        scan.stamp_s,
                        tiles.len()
                    );
                    self.path_dirty = true;
                }
                self.changed_tiles.extend(tiles);
            }
            Err(e) => self.last_error = Some(format!("map rebuild: {e}")),
        }
        if loc.trusted {
            // The de-skewed sweep when SLAM made one: the raw one is smeared by the motion.
            let deskewed = loc.deskewed.map(|points| Scan {
                stamp_s: scan.stamp_s,
                points,
            });
            let sweep = deskewed.as_ref().unwrap_or(scan);
            match self.terrain.update(sweep, &loc.pose_map_lidar, &loc.pose) {
                Ok(u) => {
                    rep.classified_cells = u.classified_cells;
                    self.changed_tiles.extend(u.changed_tiles);
                    self.path_dirty |= u.class_changes > 0;
                    self.terrain.keep_sweep(
                        sweep.stamp_s,
                        &loc.slam_from_base,
                        &loc.pose,
                        &sweep.points,
                    );
                }
                Err(e) => {
                    // Counted with the sweeps left out of the map: the operator sees a map
                    // that stopped growing explained.
                    self.scans_not_mapped += 1;
                    rep.not_mapped = true;
                    tracing::debug!("sweep at {:.2} s not mapped: {e}", scan.stamp_s);
                    self.last_error = Some(format!("mapping: {e}"));
                }
            }
        } else {
            self.scans_not_mapped += 1;
            rep.not_mapped = true;
            tracing::debug!(
                "sweep at {:.2} s not mapped: pose jumped {:.2} m, or pitch or position disagrees with GNSS",
                scan.stamp_s,
                loc.jump_m
            );
        }
        probe.mark(Stage::Map);
        // The safety stop judges the raw sweep, in base_link.
        let base_from_lidar = *self.localiser.base_from_lidar();
        self.driver.on_sweep(
            scan.stamp_s,
            scan.points.iter().map(|p| {
                let q = base_from_lidar
                    * nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                (q.x, q.y, q.z)
            }),
            &loc.pose,
        );
        // A grid change on the path asks for a replan now.
        if self.path_dirty && self.mission.nav().is_driving() {
            let pose = loc.pose.planar;
            let mut grid = self.terrain.path_check_grid(
                &pose,
                self.mission.nav().path_ahead(&pose),
                self.driver.lasting_stop_m(),
            );
            self.zones
                .stamp_keep_out(&mut grid, self.keep_out_margin_m, (pose.x_m, pose.y_m));
            rep.path_blocked = self.mission.nav_mut().check_path(&grid, &pose);
            self.path_dirty = false;
        }
        probe.mark(Stage::Safety);
        rep
    }

    /// Processes one depth-camera frame (camera frame, the profile's `depth_camera` mount): its
    /// points enter the traversability map like a sweep's, at the localiser's current pose, and
    /// the safety gate, so a low obstacle only the camera sees stops or reroutes the robot.
    pub fn on_depth(&mut self, frame: &Scan) -> Result<(), String> {
        let Some(pose) = self.localiser.pose_now() else {
            return Ok(());
        };
        let base = self.base_from_depth;
        self.driver.on_depth_frame(
            frame.stamp_s,
            frame.points.iter().filter(|p| p.is_finite()).map(|p| {
                let q =
                    base * nalgebra::Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                (q.x, q.y, q.z)
            }),
        );
        if !self.pose_trusted {
            return Ok(());
        }
        let pose_map_cam = pose.iso * base;
        let u = self
            .terrain
            .update(frame, &pose_map_cam, &pose)
            .map_err(|e| format!("mapping a depth frame: {e}"))?;
        self.depth_frames += 1;
        self.changed_tiles.extend(u.changed_tiles);
        self.path_dirty |= u.class_changes > 0;
        Ok(())
    }

    /// Depth frames mapped so far.
    pub fn depth_frames(&self) -> u64 {
        self.depth_frames
    }

    /// Maps a sweep at a pose given from outside instead of the localiser's: the upper bound of
    /// an evaluation that knows the truth (`robot-agent map eval --use-truth-poses`). `points_map`
    /// is the sweep in the map frame, `sensor_m` where it was seen from, `robot` the robot.
    pub fn map_at_given_pose(
        &mut self,
        points_map: Vec<[f32; 3]>,
        sensor_m: [f64; 3],
        robot: &mapping::RobotPose,
        t_s: f64,
    ) -> Result<mapping::UpdateReport, mapping::MapError> {
        let u = self.terrain.update_at(points_map, sensor_m, robot, t_s)?;
        self.changed_tiles.extend(u.changed_tiles.iter().copied());
        Ok(u)
    }

    // ---- the loop's periodic work ----

    /// Plans when due and returns the command for now (call at the control rate). The bool says
    /// whether a plan was computed (the caller may time the call).
    pub fn tick(&mut self, t_s: f64) -> (Cmd, bool) {
        let planned = self.plan_if_due(t_s);
        (self.control(t_s), planned)
    }

    /// Plans when due (goal) or runs a repeat cycle; true when a plan was computed.
    pub fn plan_if_due(&mut self, t_s: f64) -> bool {
        let Some(pose) = self.localiser.pose_now() else {
            return false;
        };
        if self.mission.mode() == Mode::Repeat {
            if t_s - self.last_plan_t_s < 1.0 / self.cfg.planner.replan_rate_hz {
                return false;
            }
            self.last_plan_t_s = t_s;
            self.repeat_cycle(t_s, &pose);
            return true;
        }
        if !self.mission.nav().wants_replan(t_s) {
            return false;
        }
        let grid = self.plan_grid(&pose.planar);
        self.mission.nav_mut().replan(t_s, &pose.planar, &grid);
        true
    }

    /// The planning grid around `pose`: the terrain's, a lasting stop, the keep-out zones.
    fn plan_grid(&self, pose: &common::geom::Pose2) -> planning::PlanGrid {
        let mut grid = self.terrain.plan_grid(pose, self.driver.lasting_stop_m());
        self.zones
            .stamp_keep_out(&mut grid, self.keep_out_margin_m, (pose.x_m, pose.y_m));
        grid
    }

    /// One repeat cycle: the route ahead checked against the corridor, detours planned.
    fn repeat_cycle(&mut self, t_s: f64, pose: &PoseMap) {
        let stop_m = self.driver.lasting_stop_m();
        let (window, view) = self.terrain.window(&pose.planar);
        let mut grid = self
            .terrain
            .plan_grid_in(&pose.planar, &window, &view, stop_m);
        let robot = (pose.planar.x_m, pose.planar.y_m);
        self.zones
            .stamp_keep_out(&mut grid, self.keep_out_margin_m, robot);
        let Some(r) = self.mission.repeat_mut() else {
            return;
        };
        // A stop that lasts is a blockage of the route (the person will not move while the
        // robot is in the way): wait, then detour round it, like any other. A keep-out zone
        // across the route is one too.
        let mut corridor = self
            .terrain
            .corridor_grid(&window, &view, r.view.as_ref(), stop_m);
        self.zones
            .stamp_keep_out(&mut corridor, self.keep_out_margin_m, robot);
        // Blocked points whose cells are worth a log line.
        let mut explain: Vec<(f64, f64)> = Vec::new();
        let f = &mut r.follower;
        let before = f.detours.last().map(|d| (f.detours.len(), d.replans));
        let state = f.update_with_corridor(&pose.planar, &grid, &corridor, t_s);
        // A wait is logged once, when it begins.
        let was_waiting = matches!(r.last, Some(RepeatState::Waiting { holding: true, .. }));
        r.last = Some(state.clone());
        if let Some(d) = f.detours.last() {
            if before != Some((f.detours.len(), d.replans)) {
                let (cx, cy) = self.terrain.lattice().cell_of(d.blocked_m.0, d.blocked_m.1);
                tracing::info!(
                    "repeat: detour {} (re-plan {}) around ({:.1}, {:.1}) [{:?}], rejoins taught point {} at ({:.1}, {:.1}), {:.1} m",
                    f.detours.len(),
                    d.replans,
                    d.blocked_m.0,
                    d.blocked_m.1,
                    self.terrain.mapper().class(cx, cy),
                    d.rejoin_taught,
                    d.rejoin_m.0,
                    d.rejoin_m.1,
                    d.length_m
                );
                explain.push(d.blocked_m);
            }
        }
        let mut finished = false;
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
            RepeatState::Finished => finished = true,
        }
        let view = self.mission.repeat().and_then(|r| r.view.clone());
        for at in explain {
            self.terrain.log_blocking_cells(at, view.as_ref());
        }
        if finished {
            // Internal events never refuse.
            let _ = self.mission.transition(Event::RouteFinished);
        }
    }

    /// The command for now (call at the control rate, after [`Agent::plan_if_due`]).
    pub fn control(&mut self, t_s: f64) -> Cmd {
        let Some(pose) = self.localiser.pose_now() else {
            return Cmd::default();
        };
        // A single sweep that SLAM placed 0.4 m off at a ramp's foot became a taught waypoint
        // the repeat then steered to: only trusted poses are taught.
        if self.localiser.pose_teachable(t_s) {
            let lla = self.localiser.lla_of(&pose);
            let ms = self.unix_ms(t_s);
            if let Some(rec) = self.mission.recorder_mut() {
                rec.offer(pose.planar, lla, ms);
            }
        }
        let stop_ahead = self.driver.stop_ahead(t_s);
        let cap = self.zone_cap(&pose.planar);
        self.driver.set_zone_cap(cap);
        let cmd = match self.mission.mode() {
            Mode::Teleop | Mode::Teach => {
                self.driver.teleop(t_s, self.mission.teleop(), stop_ahead)
            }
            Mode::Goal => {
                if self.mission.nav_mut().check_reached(&pose.planar) {
                    let _ = self.mission.transition(Event::GoalReached);
                }
                let safety_stop = self.driver.safety().stop;
                let nav = self.mission.nav_mut();
                nav.set_blocked(
                    nav.is_driving() && stop_ahead && safety_stop,
                    "safety stop: obstacle close to the robot",
                );
                if nav.is_driving() || nav.state() == Phase::Blocked && !nav.path().is_empty() {
                    self.driver
                        .follow(Tracker::Path, &pose.planar, nav.path(), stop_ahead, true)
                } else {
                    Cmd::default()
                }
            }
            Mode::Repeat => match self.mission.repeat() {
                Some(r) if !r.follower.holding() && !r.paused => {
                    let path = r.follower.follow_path(&pose.planar);
                    self.driver
                        .follow(Tracker::Route, &pose.planar, &path, stop_ahead, true)
                }
                _ => Cmd::default(),
            },
            Mode::Idle => Cmd::default(),
        };
        self.driver.set_last(cmd);
        cmd
    }

    /// The slow-zone cap at `pose`: zones within the distance needed to slow down from the
    /// speed limit to the cap (and half the body length) count, so the robot is slow on entry.
    fn zone_cap(&self, pose: &common::geom::Pose2) -> Option<f64> {
        let v = self.driver.speed_limit_mps();
        let decel = self.cfg.control.goal_decel_mps2.max(0.1);
        let lead = 0.5 * self.cfg.profile.length_m + v * v / (2.0 * decel);
        self.zones
            .speed_cap((pose.x_m, pose.y_m), lead)
            .map(|(cap, _)| cap)
    }

    /// The zones in force.
    pub fn zones(&self) -> &ZoneMap {
        &self.zones
    }
}

//! The loops that drive an [`Agent`] with the built-in simulator: headless missions that run as
//! fast as the CPU allows and print a report, and the live robot on the Zenoh bus.
//!
//! The simulator is the robot here: the agent only sees its sensor outputs (scans, odometry,
//! NMEA), never its truth; the truth is used only to score the outcome.

pub mod bag_play;
pub mod convert;
pub mod gnss_sources;
pub mod io_config;
pub mod live;
pub mod map_eval;
pub mod robot;
pub mod ros2;
pub mod stages;
pub mod world;

use crate::runtime::Input;
use agent::command::{Command, CommandKind, Direction, GoalTarget};
use agent::mission::{Mode, Phase};
use agent::{Agent, AgentConfig, Cmd, Identity};
use common::geom::Pose2;
use serde::Serialize;
use std::time::Instant;

/// Simulator step, seconds (plant and sensor timing resolution).
pub const SIM_DT_S: f64 = 0.01;
pub use crate::runtime::CONTROL_DT_S;

/// Options of a headless run.
#[derive(Clone, Debug)]
pub struct HeadlessOptions {
    /// Simulator seed (walkers, noise).
    pub seed: u64,
    /// Give up after this much simulated time, seconds.
    pub timeout_s: f64,
    /// Start pose override (else the scenario's).
    pub start: Option<Pose2>,
    /// Stop at the first collision.
    pub stop_on_collision: bool,
    /// Teach and repeat: draw the robot's map with the repeat's driven path (truth) into this
    /// PNG at the end.
    pub map_png: Option<std::path::PathBuf>,
    /// Record the run to MCAP.
    pub mcap: Option<crate::record::RecordOptions>,
    /// Record the CPU time (this thread) of the agent's stages ([`Rig::stage_times`]).
    pub time_stages: bool,
    /// Live robot: write the simulator's truth here ([`crate::truth_log`]).
    pub truth_out: Option<std::path::PathBuf>,
}

impl Default for HeadlessOptions {
    fn default() -> Self {
        Self {
            seed: 1,
            timeout_s: 600.0,
            start: None,
            stop_on_collision: true,
            map_png: None,
            mcap: None,
            time_stages: false,
            truth_out: None,
        }
    }
}

/// The report of a headless goal mission (`robot-agent sim --headless --goal`).
#[derive(Clone, Debug, Serialize)]
pub struct MissionReport {
    /// `reached`, `no_path`, `timeout` or `collision`.
    pub outcome: String,
    /// Truth distance from the robot to the goal at the end, metres.
    pub final_error_m: f64,
    /// Simulated time, seconds.
    pub time_s: f64,
    /// Distance driven (truth), metres.
    pub path_length_m: f64,
    /// Collisions (simulator truth).
    pub collisions: u32,
    /// Plans computed.
    pub replans: u32,
    /// Mean wall-clock time of a plan, milliseconds.
    pub plan_ms_mean: f64,
    /// Worst plan, milliseconds.
    pub plan_ms_max: f64,
    /// The mission's last reason.
    pub reason: String,
    /// Goal in the map frame, metres.
    pub goal_m: (f64, f64),
    /// Final truth position, metres.
    pub final_m: (f64, f64),
    /// Mean wall-clock time of a scan (SLAM + mapping), milliseconds.
    pub scan_ms_mean: f64,
    /// Simulated seconds per wall-clock second.
    pub realtime_factor: f64,
    /// SLAM fallbacks to the prior.
    pub slam_failures: u32,
    /// Worst localisation errors against the truth.
    pub localisation: LocalisationError,
    /// Truth trajectory, decimated to 0.5 m, for scenario checks.
    pub trajectory_m: Vec<(f64, f64)>,
    /// [`common::grid::map_digest`] of the robot's map at the end.
    pub map_digest: String,
    /// The recording (`--mcap`), with the run's digest.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub record: Option<crate::record::RecordSummary>,
}

/// Timing statistics.
#[derive(Default, Clone, Copy, Debug)]
struct Stat {
    n: u32,
    sum: f64,
    max: f64,
}

impl Stat {
    fn add(&mut self, ms: f64) {
        self.n += 1;
        self.sum += ms;
        self.max = self.max.max(ms);
    }
    fn mean(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum / f64::from(self.n)
        }
    }
}

/// How the rig's sweeps reach the agent's map.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScanMode {
    /// Through the agent's own pipeline: localiser, terrain map, safety stop (the product).
    #[default]
    Localised,
    /// Mapped at the simulator's true poses, de-skewed with the true motion: the upper bound an
    /// evaluation can compare the product against, never the product itself.
    TruthPoses,
}

/// Where a rig hands each published tile (a corpus writer, a counter).
pub type TileSink = Box<dyn FnMut(&common::grid::Tile)>;

/// A simulator with an agent on it, stepped together.
pub struct Rig {
    /// The world.
    pub sim: sim::Simulation,
    /// The robot's brain.
    pub agent: Agent,
    cmd: Cmd,
    next_control_s: f64,
    plan: Stat,
    scan: Stat,
    /// Collisions so far (truth).
    pub collisions: u32,
    /// Worst localisation errors so far (agent pose vs truth, right after each scan).
    pub loc: LocalisationError,
    driven_m: f64,
    last_truth: (f64, f64),
    trajectory: Vec<(f64, f64)>,
    /// How sweeps reach the map.
    pub scan_mode: ScanMode,
    /// When set, the wall time of every stage of the agent is recorded here (the pipeline
    /// bench); the agent itself never reads a clock.
    pub stage_times: Option<stages::StageTimes>,
    /// When set, drives the plant instead of the agent's command (a scripted survey drive).
    pub drive_override: Option<Cmd>,
    /// Tiles the agent published so far, with their encoded bytes.
    pub tiles_published: usize,
    /// Encoded bytes of those tiles.
    pub tile_bytes: usize,
    /// When set, every published tile (exact) is handed here.
    pub tile_sink: Option<TileSink>,
    /// The rig runs the tile policy itself (evaluations); off when a bus loop publishes the
    /// agent's changed tiles instead.
    pub own_tiles: bool,
    /// What the robot would publish, with the live robot's policy.
    publisher: crate::bus::tiles::TilePublisher,
    lidar_ext: nalgebra::Isometry3<f64>,
    /// The recording, when the run is recorded (`--mcap`).
    pub recorder: Option<crate::record::SessionRecorder>,
    /// The outputs a headless recorded run draws into its recording (a live rig's loop
    /// publishes them itself).
    outputs: Option<crate::runtime::outputs::Outputs>,
}

impl Rig {
    /// Builds the simulator and the agent. The agent shares the scenario's datum so that
    /// several robots in one world share one map frame (what an operator does by setting it).
    pub fn new(
        scenario: &sim::Scenario,
        mut cfg: AgentConfig,
        opts: &HeadlessOptions,
        robot: &str,
    ) -> anyhow::Result<Self> {
        cfg.datum = Some(scenario.datum());
        let mut sim_cfg = sim::SimConfig {
            seed: opts.seed,
            ..sim::SimConfig::default()
        };
        if let Some(s) = opts.start {
            sim_cfg.start = Some(s);
        }
        sim_cfg.robot = cfg.profile.clone();
        let sim = sim::Simulation::new(scenario, sim_cfg);
        let now_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_millis() as u64)
            .unwrap_or(0);
        let agent = Agent::new(
            cfg,
            Identity {
                robot: robot.to_string(),
                session_id: format!("{robot}-{now_ms}"),
                start_unix_ms: now_ms,
            },
        )
        .map_err(|e| anyhow::anyhow!("mapper configuration: {e}"))?;
        let t = sim.truth_pose().translation.vector;
        let lidar_ext = sim.lidar_extrinsic();
        let publisher = crate::bus::tiles::TilePublisher::new(
            crate::bus::tiles::TilePolicy::default(),
            agent.lattice(),
            now_ms,
        );
        Ok(Self {
            recorder: None,
            outputs: None,
            publisher,
            scan_mode: ScanMode::Localised,
            stage_times: None,
            drive_override: None,
            tiles_published: 0,
            tile_bytes: 0,
            tile_sink: None,
            own_tiles: true,
            lidar_ext,
            sim,
            agent,
            cmd: Cmd::default(),
            next_control_s: 0.0,
            plan: Stat::default(),
            scan: Stat::default(),
            collisions: 0,
            loc: LocalisationError::default(),
            driven_m: 0.0,
            last_truth: (t.x, t.y),
            trajectory: vec![(t.x, t.y)],
        })
    }

    /// Records this rig's run to MCAP: inputs, commands and control periods, and with
    /// `own_outputs` the outputs a live robot would publish (a live rig's loop publishes them
    /// into the recording itself).
    pub fn record_to(
        &mut self,
        opts: &crate::record::RecordOptions,
        source: &str,
        own_outputs: bool,
    ) -> anyhow::Result<()> {
        use crate::runtime::stamps::Topic;
        let cfg = self.agent.config().clone();
        let meta = crate::record::SessionMeta {
            identity: self.agent.identity().clone(),
            // The rig's agent runs on the simulator's clock from 0.
            t0_s: 0.0,
            source: source.to_string(),
            inputs: vec![Topic::Lidar, Topic::Odom, Topic::Imu, Topic::Gnss],
            config_files: opts.config_files.clone(),
            datum: cfg.datum,
            config_digest: crate::record::config_digest(&cfg),
        };
        self.recorder = Some(crate::record::SessionRecorder::start(opts, &meta, &cfg)?);
        if own_outputs {
            self.outputs = Some(crate::runtime::outputs::Outputs::new(&self.agent, source));
        }
        Ok(())
    }

    /// Gives the agent a command (recorded when the run is).
    pub fn command(&mut self, c: Command) -> Result<(), common::command::Refusal> {
        if let Some(r) = self.recorder.as_mut() {
            r.command(&crate::runtime::AgentCommand::Do(c.clone()));
        }
        self.agent.on_command(c)
    }

    /// Closes the recording, with the run's digest.
    pub fn finish_recording(&mut self) -> Option<crate::record::RecordSummary> {
        self.recorder.take().map(|r| r.finish(Some(&self.agent)))
    }

    /// Session time, seconds.
    pub fn t_s(&self) -> f64 {
        self.sim.time_s()
    }

    /// Truth planar pose.
    pub fn truth(&self) -> Pose2 {
        Pose2::from_isometry3(&self.sim.truth_pose())
    }

    /// Draws the robot's traversability map with `path_m` over it into the PNG `out`.
    pub fn draw_map(&self, path_m: &[(f64, f64)], out: &std::path::Path) -> anyhow::Result<()> {
        use anyhow::Context;
        let file =
            std::fs::File::create(out).with_context(|| format!("creating {}", out.display()))?;
        mapping::render::render_png(
            self.agent.mapper(),
            None,
            3,
            path_m,
            std::io::BufWriter::new(file),
        )
        .with_context(|| format!("drawing {}", out.display()))?;
        Ok(())
    }

    /// One simulator step: sensors into the agent, the agent's command into the plant.
    /// `override_cmd` replaces the agent's command (teach drives by teleop through the agent's
    /// own teleop path instead, so this is only for tests).
    pub fn step(&mut self) -> StepEvents {
        let drive = self.drive_override.unwrap_or(self.cmd);
        let mut out = self.sim.step(SIM_DT_S, drive.v_mps, drive.omega_rps);
        let mut ev = StepEvents::default();
        // The sensors' outputs reach the agent as the runtime hands them over (and in its
        // order), so that a recording of this run replays through the runtime call for call.
        let t_inputs = stages::thread_cpu_ms();
        let scan = out.scan.take();
        let mut inputs: Vec<Input> = Vec::with_capacity(2 + out.imu.len() + out.gnss.len());
        inputs.extend(out.odom.map(Input::Odom));
        inputs.extend(out.imu.iter().copied().map(Input::Imu));
        inputs.extend(std::mem::take(&mut out.gnss).into_iter().map(Input::Gnss));
        for input in &inputs {
            if let Some(r) = self.recorder.as_mut() {
                r.input(input);
            }
            crate::runtime::deliver(&mut self.agent, input);
        }
        if let Some(times) = self.stage_times.as_mut() {
            // GNSS fusion moves the frame, and the map follows: part of the robot's load.
            times.add("odom_imu_gnss", stages::thread_cpu_ms() - t_inputs);
        }
        let scan_stamp = scan.as_ref().map(|s| s.stamp_s);
        if let Some(scan) = scan {
            let t0 = Instant::now();
            match self.scan_mode {
                ScanMode::Localised => {
                    let input = Input::Scan(scan);
                    if let Some(r) = self.recorder.as_mut() {
                        r.input(&input);
                    }
                    ev.slam_failed = match (self.stage_times.as_mut(), &input) {
                        // Timed by stage: the same agent call, with a probe.
                        (Some(times), Input::Scan(s)) => {
                            times.begin_sweep();
                            self.agent.on_scan_probed(s, times).slam_failed
                        }
                        _ => crate::runtime::deliver(&mut self.agent, &input).slam_failed,
                    };
                }
                ScanMode::TruthPoses => {
                    let (points, origin, robot) = self.truth_sweep(&scan);
                    if let Err(e) =
                        self.agent
                            .map_at_given_pose(points, origin, &robot, scan.stamp_s)
                    {
                        tracing::warn!("mapping at {:.2} s: {e}", scan.stamp_s);
                    }
                }
            }
            self.scan.add(t0.elapsed().as_secs_f64() * 1e3);
            ev.scan = true;
        }
        if ev.scan && self.own_tiles && self.outputs.is_none() {
            let stamp = scan_stamp.unwrap_or(self.sim.time_s());
            let changed = self.agent.take_changed_tiles();
            let agent = &self.agent;
            let tiles = self
                .publisher
                .publish(stamp, &changed, |i| agent.tile_cells(i), false);
            for t in tiles {
                self.tiles_published += 1;
                self.tile_bytes += common::grid::encode_tile(&t).len();
                if let Some(sink) = self.tile_sink.as_mut() {
                    sink(&t);
                }
            }
        }
        if scan_stamp.is_some() {
            // The agent's localisation against the truth, right after the scan.
            if let Some(est) = self.agent.localiser().pose_now() {
                let truth = self.sim.truth_pose();
                let d = est.iso.translation.vector - truth.translation.vector;
                self.loc.xy_max_m = self.loc.xy_max_m.max(d.xy().norm());
                self.loc.z_max_m = self.loc.z_max_m.max(d.z.abs());
                let tilt = (est.iso.rotation * nalgebra::Vector3::z())
                    .angle(&(truth.rotation * nalgebra::Vector3::z()))
                    .to_degrees();
                self.loc.tilt_max_deg = self.loc.tilt_max_deg.max(tilt);
                self.loc.scans += 1;
                self.loc.tilt_mean_deg +=
                    (tilt - self.loc.tilt_mean_deg) / f64::from(self.loc.scans);
                if trace_enabled() {
                    let h = self.agent.localiser().health();
                    eprintln!(
                        "trace scan t {:.1} {} slam inliers {:.2} iter {} degenerate {} mapped {}",
                        self.t_s(),
                        self.pose_error_text(),
                        h.inlier_ratio,
                        h.iterations,
                        h.degenerate,
                        self.agent.scans_not_mapped()
                    );
                }
            }
        }
        for c in &out.collisions {
            tracing::warn!(
                "collision at {:.2} s: {:?} (object {}) at ({:.2}, {:.2}), detail {:.3}",
                c.t_s,
                c.kind,
                c.object,
                c.x_m,
                c.y_m,
                c.detail
            );
        }
        self.collisions += out.collisions.len() as u32;
        ev.collisions = out.collisions.len() as u32;
        let t = self.sim.time_s();
        if t + 1e-9 >= self.next_control_s {
            self.next_control_s += CONTROL_DT_S;
            let t0 = Instant::now();
            let c0 = stages::thread_cpu_ms();
            if self.agent.plan_if_due(t) {
                self.plan.add(t0.elapsed().as_secs_f64() * 1e3);
                if let Some(times) = self.stage_times.as_mut() {
                    times.add("planning", stages::thread_cpu_ms() - c0);
                }
            }
            let c1 = stages::thread_cpu_ms();
            self.cmd = self.agent.control(t);
            if let Some(times) = self.stage_times.as_mut() {
                times.add("control", stages::thread_cpu_ms() - c1);
            }
            if let Some(r) = self.recorder.as_mut() {
                r.control(t, &self.agent, self.cmd);
            }
            ev.control = true;
        }
        if let Some(o) = self.outputs.as_mut() {
            let counters = crate::runtime::outputs::LoopCounters {
                collisions: self.collisions,
                ..Default::default()
            };
            o.publish(
                None,
                self.recorder.as_mut(),
                &mut self.agent,
                t,
                ev.scan,
                &counters,
            );
        }
        let p = self.sim.truth_pose().translation.vector;
        let d = (p.x - self.last_truth.0).hypot(p.y - self.last_truth.1);
        self.driven_m += d;
        self.last_truth = (p.x, p.y);
        if self
            .trajectory
            .last()
            .is_none_or(|q| (q.0 - p.x).hypot(q.1 - p.y) >= 0.5)
        {
            self.trajectory.push((p.x, p.y));
        }
        ev
    }

    /// The command currently applied to the plant.
    pub fn cmd(&self) -> Cmd {
        self.drive_override.unwrap_or(self.cmd)
    }

    /// A sweep at the true pose: every return at the true lidar pose of its own firing time
    /// (1 ms bins), seen from the lidar's true position at mid-sweep, with the robot's true pose
    /// at the sweep's stamp.
    fn truth_sweep(&self, scan: &sensing::Scan) -> (Vec<[f32; 3]>, [f64; 3], mapping::RobotPose) {
        let t = scan.stamp_s;
        let base = self
            .sim
            .truth_pose_at(t)
            .unwrap_or_else(|| self.sim.truth_pose());
        let mid = self
            .sim
            .truth_pose_at(t + 0.05)
            .unwrap_or_else(|| self.sim.truth_pose())
            * self.lidar_ext;
        let o = mid.translation.vector;
        let mut poses: Vec<Option<nalgebra::Matrix4<f32>>> = vec![None; 201];
        let fallback = self.sim.truth_pose() * self.lidar_ext;
        let points = scan
            .points
            .iter()
            .map(|p| {
                let k = ((f64::from(p.t_s) * 1000.0).round().max(0.0) as usize).min(200);
                let m = poses[k].get_or_insert_with(|| {
                    let tk = scan.stamp_s + k as f64 * 1e-3;
                    (self
                        .sim
                        .truth_pose_at(tk)
                        .map_or(fallback, |b| b * self.lidar_ext))
                    .to_homogeneous()
                    .cast::<f32>()
                });
                let q = m.transform_point(&nalgebra::Point3::new(p.x, p.y, p.z));
                [q.x, q.y, q.z]
            })
            .collect();
        let b = base.translation.vector;
        let fwd = base.rotation * nalgebra::Vector3::x();
        let robot = mapping::RobotPose {
            x_m: b.x,
            y_m: b.y,
            z_m: b.z,
            yaw_rad: fwd.y.atan2(fwd.x),
        };
        (points, [o.x, o.y, o.z], robot)
    }

    /// The agent's pose against the truth for trace lines: position, and the error's
    /// height, roll and pitch in the robot's frame (what tilts the map it draws).
    pub fn pose_error_text(&self) -> String {
        let truth = self.sim.truth_pose();
        let t = truth.translation.vector;
        let Some(est) = self.agent.localiser().pose_now() else {
            return format!("truth {:.2} {:.2} {:.3} est none", t.x, t.y, t.z);
        };
        let e = est.iso.translation.vector;
        let (roll, pitch, _) = (truth.rotation.inverse() * est.iso.rotation).euler_angles();
        format!(
            "truth {:.2} {:.2} {:.3} est {:.2} {:.2} {:.3} err xy {:.3} z {:+.3} roll {:+.2} pitch {:+.2} deg",
            t.x,
            t.y,
            t.z,
            e.x,
            e.y,
            e.z,
            (e - t).xy().norm(),
            e.z - t.z,
            roll.to_degrees(),
            pitch.to_degrees()
        )
    }
}

/// Whether `TERRANAV_TRACE` asks for per-cycle trace lines on stderr (a debugging aid for
/// the headless runs; the reports do not depend on it).
fn trace_enabled() -> bool {
    std::env::var_os("TERRANAV_TRACE").is_some()
}

/// Worst localisation errors of a run, measured against the simulator's truth.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LocalisationError {
    /// Horizontal position, metres.
    pub xy_max_m: f64,
    /// Height, metres.
    pub z_max_m: f64,
    /// Angle between the estimated and the true up axis, degrees.
    pub tilt_max_deg: f64,
    /// Mean of that angle over the sweeps, degrees.
    pub tilt_mean_deg: f64,
    /// Sweeps measured.
    pub scans: u32,
}

/// What one [`Rig::step`] did.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepEvents {
    /// A scan was processed.
    pub scan: bool,
    /// The control loop ran.
    pub control: bool,
    /// SLAM fell back to its prior (or failed) on this step's sweep.
    pub slam_failed: bool,
    /// Collisions in this step.
    pub collisions: u32,
}

/// How far past a walker detour's rejoin point the robot still counts as on the detour for the
/// tracking numbers (it is converging onto the line there), metres.
const REJOIN_SETTLE_M: f64 = 1.0;

/// Runs a goal mission headless to its end.
pub fn run_goal(
    scenario: &sim::Scenario,
    cfg: AgentConfig,
    target: GoalTarget,
    opts: &HeadlessOptions,
) -> anyhow::Result<MissionReport> {
    run_goal_rig(scenario, cfg, target, opts).map(|(r, _)| r)
}

/// [`run_goal`], also handing back the rig (the agent's map, the simulator) for rendering.
pub fn run_goal_rig(
    scenario: &sim::Scenario,
    cfg: AgentConfig,
    target: GoalTarget,
    opts: &HeadlessOptions,
) -> anyhow::Result<(MissionReport, Rig)> {
    let mut rig = Rig::new(scenario, cfg, opts, "sim")?;
    if let Some(m) = &opts.mcap {
        rig.record_to(m, &format!("sim:{}", scenario.name), true)?;
    }
    if opts.time_stages {
        rig.stage_times = Some(stages::StageTimes::default());
    }
    let wall = Instant::now();
    // Let the first scans arrive so the map frame is anchored before the goal is converted.
    while rig.agent.scans() < 3 && rig.t_s() < 5.0 {
        rig.step();
    }
    let goal = CommandKind::Goal {
        id: 1,
        target,
        tolerance_m: 0.0,
    };
    let t = rig.t_s();
    if let Err(e) = rig.command(Command::at(t, goal)) {
        anyhow::bail!("{e}");
    }
    let goal_m = rig
        .agent
        .mission()
        .nav()
        .goal()
        .map(|g| g.goal_map)
        .unwrap_or_default();
    let outcome = loop {
        let ev = rig.step();
        if ev.collisions > 0 && opts.stop_on_collision {
            break "collision";
        }
        if !ev.control {
            continue;
        }
        if trace_enabled() {
            eprintln!(
                "trace t {:.1} {} state {:?}",
                rig.t_s(),
                rig.pose_error_text(),
                rig.agent.mission().nav().state()
            );
        }
        let nav = rig.agent.mission().nav();
        match nav.state() {
            Phase::Reached => break "reached",
            Phase::NoPath if nav.goal().is_none() => break "no_path",
            _ => {}
        }
        if rig.t_s() > opts.timeout_s {
            break "timeout";
        }
    };
    // Let the robot come to rest so the final error is where it stopped.
    for _ in 0..100 {
        rig.step();
    }
    let truth = rig.truth();
    let goal_now = rig
        .agent
        .mission()
        .nav()
        .goal()
        .map(|g| g.goal_map)
        .unwrap_or(goal_m);
    let report = MissionReport {
        outcome: if rig.collisions > 0 {
            "collision".into()
        } else {
            outcome.into()
        },
        final_error_m: (truth.x_m - goal_now.0).hypot(truth.y_m - goal_now.1),
        time_s: rig.t_s(),
        path_length_m: rig.driven_m,
        collisions: rig.collisions,
        replans: rig.agent.mission().nav().replans,
        plan_ms_mean: rig.plan.mean(),
        plan_ms_max: rig.plan.max,
        reason: rig.agent.mission().nav().reason().to_string(),
        goal_m: goal_now,
        final_m: (truth.x_m, truth.y_m),
        scan_ms_mean: rig.scan.mean(),
        realtime_factor: rig.t_s() / wall.elapsed().as_secs_f64().max(1e-9),
        slam_failures: rig.agent.status(rig.t_s()).slam.failures,
        localisation: rig.loc,
        trajectory_m: rig.trajectory.clone(),
        map_digest: common::grid::map_digest(&rig.agent.all_tiles()),
        record: None,
    };
    let mut report = report;
    report.record = rig.finish_recording();
    Ok((report, rig))
}

/// The report of a teach-and-repeat run (`robot-agent sim --headless --teach-repeat`).
#[derive(Clone, Debug, Serialize)]
pub struct TeachRepeatReport {
    /// `reached`, `blocked`, `timeout` or `collision`.
    pub outcome: String,
    /// RMS lateral distance to the taught path on free stretches, metres. Not free: within 3 m
    /// of an added obstacle, and any detour (round a person or an added obstacle) until 1 m past its
    /// rejoin point.
    pub tracking_rms_m: f64,
    /// Worst lateral distance on free stretches, metres.
    pub tracking_max_m: f64,
    /// Detours spliced in.
    pub detours: u32,
    /// Of those, detours around a person standing on the route (a walker within 2 m of the
    /// blockage when the detour was planned); their stretches are not free.
    pub walker_detours: u32,
    /// Per detour: straight-line distance from the rejoin point to the nearest added obstacle's
    /// footprint (for a detour around a person, to where the person stood), metres.
    pub rejoin_distance_m: Vec<f64>,
    /// Where detours began that no added obstacle explains (blocked point more than 3 m from
    /// every added obstacle), map frame, metres.
    pub unexplained_detours_m: Vec<[f64; 2]>,
    /// Collisions (truth).
    pub collisions: u32,
    /// Distance from the taught start (home) at the end, metres.
    pub final_error_m: f64,
    /// Taught waypoints.
    pub waypoints: usize,
    /// Taught route length, metres.
    pub route_length_m: f64,
    /// Simulated time of the return, seconds.
    pub time_s: f64,
    /// Sweeps (teach and return) left out of the map because SLAM's pose was thrown off.
    pub scans_not_mapped: u64,
    /// [`common::grid::map_digest`] of the robot's map at the end.
    pub map_digest: String,
    /// The recording (`--mcap`), with the run's digest.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub record: Option<crate::record::RecordSummary>,
}

/// Teach along the scenario's teach path by teleop, add obstacles, return home along the route.
pub fn run_teach_repeat(
    scenario: &sim::Scenario,
    cfg: AgentConfig,
    obstacles: Option<&ObstacleFile>,
    opts: &HeadlessOptions,
) -> anyhow::Result<TeachRepeatReport> {
    let teach = scenario
        .teach
        .clone()
        .ok_or_else(|| anyhow::anyhow!("scenario {} has no [teach] route", scenario.name))?;
    let mut rig = Rig::new(scenario, cfg, opts, "sim")?;
    if let Some(m) = &opts.mcap {
        rig.record_to(m, &format!("sim:{}", scenario.name), true)?;
    }
    while rig.agent.scans() < 3 {
        rig.step();
    }
    let t = rig.t_s();
    rig.command(Command::at(
        t,
        CommandKind::Record {
            name: "teach".into(),
        },
    ))?;
    // The operator: a scripted driver on the truth pose, sent through the agent's teleop path
    // exactly as the station's drive commands arrive.
    let mut driver = sim::drive::PathDriver::new(&teach.points, teach.speed_mps.min(0.5));
    let mut seq = 0u32;
    let mut taught_truth: Vec<(f64, f64)> = Vec::new();
    while !driver.is_done() {
        let ev = rig.step();
        if ev.control {
            let (v, w) = driver.command(&rig.truth());
            seq += 1;
            let t = rig.t_s();
            rig.command(Command::at(
                t,
                CommandKind::Drive {
                    seq,
                    // As the station's drive commands arrive: f32 on the wire.
                    v_mps: f64::from(v as f32),
                    omega_rps: f64::from(w as f32),
                    deadman: true,
                },
            ))?;
            let p = rig.truth();
            if trace_enabled() {
                eprintln!("trace teach t {:.1} {}", rig.t_s(), rig.pose_error_text());
            }
            if taught_truth
                .last()
                .is_none_or(|q| (q.0 - p.x_m).hypot(q.1 - p.y_m) >= 0.05)
            {
                taught_truth.push((p.x_m, p.y_m));
            }
        }
        if rig.t_s() > opts.timeout_s {
            anyhow::bail!("teach drive did not finish within {} s", opts.timeout_s);
        }
    }
    // The robot coasts to a stop; that is still the taught path.
    for _ in 0..50 {
        rig.step();
        let p = rig.truth();
        if taught_truth
            .last()
            .is_none_or(|q| (q.0 - p.x_m).hypot(q.1 - p.y_m) >= 0.05)
        {
            taught_truth.push((p.x_m, p.y_m));
        }
    }
    let t = rig.t_s();
    rig.command(Command::at(t, CommandKind::StopRecording))?;
    let route = rig
        .agent
        .take_taught_route()
        .ok_or_else(|| anyhow::anyhow!("no route recorded"))?;
    let waypoints = route.points.len();
    let route_length_m: f64 = route
        .points
        .windows(2)
        .map(|w| (w[1].x_m - w[0].x_m).hypot(w[1].y_m - w[0].y_m))
        .sum();
    let home = taught_truth.first().copied().unwrap_or_default();
    if let Some(obs) = obstacles {
        rig.sim.add_obstacles(&obs.obstacles());
    }
    let collisions_before = rig.collisions;
    let t = rig.t_s();
    rig.command(Command::at(
        t,
        CommandKind::Repeat {
            route: route.clone(),
            direction: Direction::Reverse,
        },
    ))?;
    let t_start = rig.t_s();
    // Per control cycle: lateral distance to the taught path, position, and whether the robot
    // was on a detour (not a free stretch, whatever the map says).
    let mut lateral: Vec<(f64, (f64, f64), bool)> = Vec::new();
    let mut seen_detours = (0usize, 0u32);
    // (detour index, where the walker stood when it was planned).
    let mut walker_detours: Vec<(usize, (f64, f64))> = Vec::new();
    // The rejoin point of the detour the robot is on or has just left.
    let mut settling: Option<(f64, f64)> = None;
    let outcome = loop {
        let ev = rig.step();
        if ev.collisions > 0 && opts.stop_on_collision {
            break "collision";
        }
        if ev.control {
            let p = rig.truth();
            // A detour (or re-plan) that begins with a walker within 2 m of the blockage is a
            // detour around that person.
            if let Some(f) = rig.agent.mission().repeat_or_last().map(|r| &r.follower) {
                if let Some(d) = f.detours.last() {
                    let now = (f.detours.len(), d.replans);
                    if now != seen_detours {
                        seen_detours = now;
                        let by_walker = rig.sim.walkers().into_iter().find(|w| {
                            (w.x_m - d.blocked_m.0).hypot(w.y_m - d.blocked_m.1) < 2.0 + w.radius_m
                        });
                        let k = f.detours.len() - 1;
                        if let Some(w) = by_walker {
                            walker_detours.retain(|(j, _)| *j != k);
                            walker_detours.push((k, (w.x_m, w.y_m)));
                        }
                    }
                }
            }
            // Any detour (round a person or round an added obstacle) is off the taught line on
            // purpose: not a free stretch, however far it swings from the obstacle (a wide
            // detour's return leg can pass more than the 3 m round the obstacle).
            let detour = rig
                .agent
                .mission()
                .repeat_or_last()
                .map(|r| &r.follower)
                .and_then(|f| {
                    let k = f.detours.len().checked_sub(1)?;
                    f.on_detour().then(|| f.detours[k].rejoin_m)
                });
            // The follower is back on the route once the rejoin point is within its reach
            // (`reached_radius_m`), still converging onto the line: that approach belongs to the
            // detour until the robot is `REJOIN_SETTLE_M` past the rejoin point.
            if let Some(j) = detour {
                settling = Some(j);
            }
            let near_rejoin =
                settling.is_some_and(|j| (p.x_m - j.0).hypot(p.y_m - j.1) <= REJOIN_SETTLE_M);
            if detour.is_none() && !near_rejoin {
                settling = None;
            }
            let on_detour = detour.is_some() || near_rejoin;
            lateral.push((
                distance_to_polyline(&taught_truth, (p.x_m, p.y_m)),
                (p.x_m, p.y_m),
                on_detour,
            ));
            if trace_enabled() {
                let est = rig
                    .agent
                    .localiser()
                    .pose_now()
                    .map(|p| p.planar)
                    .unwrap_or_default();
                let cmd = rig.agent.driver().last_cmd();
                let sv = rig.agent.driver().safety();
                let walker = rig
                    .sim
                    .walkers()
                    .iter()
                    .map(|w| {
                        let (c, s) = (p.yaw_rad.cos(), p.yaw_rad.sin());
                        let (dx, dy) = (w.x_m - p.x_m, w.y_m - p.y_m);
                        (c * dx + s * dy, -s * dx + c * dy)
                    })
                    .min_by(|a, b| a.0.hypot(a.1).total_cmp(&b.0.hypot(b.1)));
                eprintln!(
                    "trace   safety stop {} turn_blocked {} clearance {:.2} nearest walker (body frame) {:?}",
                    sv.stop, sv.turn_blocked, sv.clearance_m, walker
                );
                eprintln!(
                    "trace t {:.1} {} lat {:.3} cmd {:.2} {:.2} hold {} err {:?}",
                    rig.t_s(),
                    rig.pose_error_text(),
                    lateral.last().map_or(0.0, |l| l.0),
                    cmd.v_mps,
                    cmd.omega_rps,
                    rig.agent
                        .mission()
                        .repeat()
                        .is_some_and(|r| r.follower.holding()),
                    rig.agent.last_error()
                );
                if let Some(f) = rig.agent.mission().repeat_or_last().map(|r| &r.follower) {
                    let (k, n, left) = f.progress(&est);
                    let path = f.follow_path(&est);
                    eprintln!(
                        "trace   repeat {:?} next {k}/{n} ({:?}) left {left:.1} m follow {:?}",
                        rig.agent.mission().repeat().and_then(|r| r.last.as_ref()),
                        f.waypoints().get(k).map(|w| w.taught),
                        &path[..path.len().min(4)]
                    );
                }
            }
            if rig.agent.mode() != Mode::Repeat {
                break "reached";
            }
        }
        if rig.t_s() - t_start > opts.timeout_s {
            break "timeout";
        }
    };
    for _ in 0..100 {
        rig.step();
    }
    let detours = rig
        .agent
        .mission()
        .repeat_or_last()
        .map(|r| r.follower.detours.clone())
        .unwrap_or_default();
    // Free stretches: away from every obstacle that was added (their footprint plus 3 m), and
    // not on a detour.
    let near_obstacle = |p: (f64, f64)| obstacles.is_some_and(|o| o.distance_to(p) < 3.0);
    let free: Vec<f64> = lateral
        .iter()
        .filter(|(_, p, detour)| !near_obstacle(*p) && !detour)
        .map(|(d, _, _)| *d)
        .collect();
    let rms = if free.is_empty() {
        0.0
    } else {
        (free.iter().map(|d| d * d).sum::<f64>() / free.len() as f64).sqrt()
    };
    let max = free.iter().copied().fold(0.0, f64::max);
    // Past the obstacle: the added one, or where the person stood.
    let walker_at = |k: usize| walker_detours.iter().find(|(j, _)| *j == k).map(|w| w.1);
    let rejoin_distance_m = detours
        .iter()
        .enumerate()
        .map(|(k, d)| match walker_at(k) {
            Some(w) => (d.rejoin_m.0 - w.0).hypot(d.rejoin_m.1 - w.1),
            None => obstacles.map_or(0.0, |o| o.distance_to(d.rejoin_m)),
        })
        .collect();
    // Detours whose blockage is nowhere near an added obstacle or a walker: the mapper saw
    // something on a free stretch.
    let unexplained_detours_m = detours
        .iter()
        .enumerate()
        .filter(|(k, d)| {
            obstacles.is_none_or(|o| o.distance_to(d.blocked_m) > 3.0) && walker_at(*k).is_none()
        })
        .map(|(_, d)| [d.blocked_m.0, d.blocked_m.1])
        .collect();
    if let Some(png) = &opts.map_png {
        let path: Vec<(f64, f64)> = lateral.iter().map(|(_, p, _)| *p).collect();
        rig.draw_map(&path, png)?;
    }
    let truth = rig.truth();
    Ok(TeachRepeatReport {
        outcome: if rig.collisions > collisions_before {
            "collision".into()
        } else {
            outcome.into()
        },
        tracking_rms_m: rms,
        tracking_max_m: max,
        detours: detours.len() as u32,
        walker_detours: walker_detours.len() as u32,
        rejoin_distance_m,
        unexplained_detours_m,
        collisions: rig.collisions - collisions_before,
        final_error_m: (truth.x_m - home.0).hypot(truth.y_m - home.1),
        waypoints,
        route_length_m,
        time_s: rig.t_s() - t_start,
        scans_not_mapped: rig.agent.scans_not_mapped(),
        map_digest: common::grid::map_digest(&rig.agent.all_tiles()),
        record: rig.finish_recording(),
    })
}

/// Obstacles added to a world at run time (`--add-obstacles FILE`): the scenario's own tables.
#[derive(Clone, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleFile {
    /// Parked cars.
    #[serde(default)]
    pub car: Vec<sim::scenario::CarSpec>,
    /// Boxes (debris).
    #[serde(default, rename = "box")]
    pub boxes: Vec<sim::scenario::BoxSpec>,
    /// Walls; a fallen trunk is a low wall.
    #[serde(default)]
    pub wall: Vec<sim::scenario::WallSpec>,
    /// Standing trees.
    #[serde(default)]
    pub tree: Vec<sim::scenario::TreeSpec>,
    /// Poles.
    #[serde(default)]
    pub pole: Vec<sim::scenario::PoleSpec>,
}

impl ObstacleFile {
    /// Reads an obstacle file.
    pub fn load(path: &std::path::Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)?;
        Ok(toml::from_str(&text)?)
    }

    /// The obstacles for [`sim::Simulation::add_obstacles`].
    pub fn obstacles(&self) -> Vec<sim::Obstacle> {
        let mut v: Vec<sim::Obstacle> = self.car.iter().map(|c| sim::Obstacle::Car(*c)).collect();
        v.extend(self.boxes.iter().map(|b| sim::Obstacle::Box(*b)));
        v.extend(self.wall.iter().map(|w| sim::Obstacle::Wall(w.clone())));
        v.extend(self.tree.iter().map(|t| sim::Obstacle::Tree(*t)));
        v.extend(self.pole.iter().map(|p| sim::Obstacle::Pole(*p)));
        v
    }

    /// Distance from `p` to the nearest obstacle's footprint (0 inside), metres.
    pub fn distance_to(&self, p: (f64, f64)) -> f64 {
        // Distance to a rotated rectangle given by centre, size and heading.
        let rect = |cx: f64, cy: f64, len: f64, wid: f64, yaw_deg: f64| {
            let (s, co) = yaw_deg.to_radians().sin_cos();
            let (dx, dy) = (p.0 - cx, p.1 - cy);
            let (lx, ly) = (co * dx + s * dy, -s * dx + co * dy);
            ((lx.abs() - len / 2.0).max(0.0)).hypot((ly.abs() - wid / 2.0).max(0.0))
        };
        let mut d = f64::INFINITY;
        for c in &self.car {
            d = d.min(rect(c.x_m, c.y_m, c.length_m, c.width_m, c.yaw_deg));
        }
        for b in &self.boxes {
            let r = &b.rect;
            d = d.min(rect(
                r.center_m[0],
                r.center_m[1],
                r.size_m[0],
                r.size_m[1],
                r.yaw_deg,
            ));
        }
        for w in &self.wall {
            let line: Vec<(f64, f64)> = w.points.iter().map(|q| (q[0], q[1])).collect();
            d = d.min((distance_to_polyline(&line, p) - w.thickness_m / 2.0).max(0.0));
        }
        for t in &self.tree {
            d = d.min(((p.0 - t.x_m).hypot(p.1 - t.y_m) - t.trunk_radius_m).max(0.0));
        }
        for q in &self.pole {
            d = d.min(((p.0 - q.x_m).hypot(p.1 - q.y_m) - q.radius_m).max(0.0));
        }
        d
    }
}

/// Distance from `p` to a polyline, metres.
pub fn distance_to_polyline(line: &[(f64, f64)], p: (f64, f64)) -> f64 {
    if line.len() == 1 {
        return (line[0].0 - p.0).hypot(line[0].1 - p.1);
    }
    line.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let len2 = dx * dx + dy * dy;
            let t = if len2 > 0.0 {
                (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (a.0 + t * dx - p.0).hypot(a.1 + t * dy - p.1)
        })
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polyline_distance() {
        let l = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)];
        assert!((distance_to_polyline(&l, (5.0, 1.0)) - 1.0).abs() < 1e-12);
        assert!((distance_to_polyline(&l, (11.0, 5.0)) - 1.0).abs() < 1e-12);
        assert!((distance_to_polyline(&l, (-3.0, -4.0)) - 5.0).abs() < 1e-12);
    }
}

#[cfg(test)]
mod scenario_tests {
    use super::*;
    use nalgebra::Vector3;

    /// A 40 x 30 m field with a crate across the straight line to the goal.
    pub(super) const FIELD: &str = r#"
name = "field"
datum = { lat_deg = 48.0, lon_deg = 11.0, h_m = 500.0 }
extent = { x_min_m = -10.0, x_max_m = 30.0, y_min_m = -15.0, y_max_m = 15.0 }
terrain = { undulation_amplitude_m = 0.05, grass_amplitude_m = 0.02 }
start = [{ x_m = 0.0, y_m = 0.0, yaw_deg = 0.0 }]
[[box]]
rect = { center_m = [8.0, 0.0], size_m = [1.0, 3.0] }
height_m = 0.8
[[tree]]
x_m = 5.0
y_m = 9.0
[[tree]]
x_m = 15.0
y_m = -9.0
[[tree]]
x_m = 24.0
y_m = 7.0
[[pole]]
x_m = 12.0
y_m = 5.0
[[pole]]
x_m = 20.0
y_m = -4.0
[[wall]]
points = [[-8.0, -12.0], [28.0, -12.0]]
height_m = 1.5
"#;

    /// The field with a taught route (three legs, 30 m) for teach and repeat.
    fn taught_field() -> sim::Scenario {
        let text = format!("{FIELD}\n[teach]\npoints = [[0.0, 0.0], [4.0, -6.0], [20.0, -6.0], [24.0, 0.0]]\nspeed_mps = 0.5\n");
        sim::Scenario::from_toml_str(&text, "<taught field>").unwrap()
    }

    #[test]
    fn teach_and_repeat_detours_around_a_car_and_a_fallen_tree_and_rejoins() {
        // A car parked on the long leg and a fallen trunk (a low wall) across the diagonal one.
        let car: ObstacleFile = toml::from_str(
            "[[car]]\nx_m = 12.0\ny_m = -6.0\nyaw_deg = 0.0\nlength_m = 3.0\n\
             [[wall]]\npoints = [[23.04, -3.69], [20.96, -2.31]]\nthickness_m = 0.4\nheight_m = 0.4\n",
        )
        .unwrap();
        let opts = HeadlessOptions {
            timeout_s: 240.0,
            ..HeadlessOptions::default()
        };
        let rep =
            run_teach_repeat(&taught_field(), AgentConfig::default(), Some(&car), &opts).unwrap();
        eprintln!("{}", serde_json::to_string(&rep).unwrap());
        assert_eq!(rep.outcome, "reached", "{rep:?}");
        assert_eq!(rep.collisions, 0);
        assert_eq!(rep.detours, 2, "one detour per obstacle: {rep:?}");
        assert!(rep.rejoin_distance_m.iter().all(|d| *d <= 2.0), "{rep:?}");
        assert!(rep.final_error_m <= 0.3, "{rep:?}");
        // Issue 9: on free stretches RMS <= 5 cm, max <= 15 cm against the taught truth path.
        assert!(
            rep.tracking_rms_m <= 0.05 && rep.tracking_max_m <= 0.15,
            "{rep:?}"
        );
    }

    /// Up-axis error (degrees) of the agent on hilly ground: at the first scan, and the mean and
    /// worst over the scans of a 20 m drive (each against the truth at mid-sweep, where the
    /// de-skewed pose sits); also the true tilt at the start.
    fn tilt_errors_on_hills(gravity: bool) -> (f64, f64, f64, f64) {
        let text = FIELD.replace(
            "terrain = { undulation_amplitude_m = 0.05, grass_amplitude_m = 0.02 }",
            "terrain = { undulation_amplitude_m = 0.4, undulation_wavelength_m = 12.0, grass_amplitude_m = 0.0 }",
        );
        let scenario = sim::Scenario::from_toml_str(&text, "<hills>").unwrap();
        let mut cfg = AgentConfig::default();
        cfg.slam.gravity.enabled = gravity;
        let mut rig = Rig::new(&scenario, cfg, &HeadlessOptions::default(), "hills").unwrap();
        let up_err = |rig: &Rig| {
            let truth = rig.sim.truth_pose_at(rig.t_s() - 0.05).unwrap().rotation;
            let est = rig.agent.localiser().pose_now().unwrap().iso.rotation;
            (est.inverse() * Vector3::z())
                .angle(&(truth.inverse() * Vector3::z()))
                .to_degrees()
        };
        let true_tilt = (rig.sim.truth_pose().rotation * Vector3::z())
            .angle(&Vector3::z())
            .to_degrees();
        while !rig.step().scan {}
        let first = up_err(&rig);
        let t = rig.t_s();
        rig.agent
            .on_command(Command::at(
                t,
                CommandKind::Goal {
                    id: 1,
                    target: GoalTarget::Map {
                        x_m: 20.0,
                        y_m: 3.0,
                    },
                    tolerance_m: 0.0,
                },
            ))
            .unwrap();
        let (mut worst, mut sum, mut n) = (0.0f64, 0.0, 0.0);
        while rig.t_s() < 90.0 && rig.agent.mission().nav().state() != Phase::Reached {
            if rig.step().scan && rig.t_s() > 2.0 {
                let e = up_err(&rig);
                worst = worst.max(e);
                sum += e;
                n += 1.0;
            }
        }
        assert_eq!(rig.agent.mission().nav().state(), Phase::Reached);
        (true_tilt, first, sum / n, worst)
    }

    #[test]
    fn the_accelerometer_gives_the_frame_its_roll_on_hilly_ground() {
        let (tilt, first, mean, worst) = tilt_errors_on_hills(true);
        eprintln!("with IMU: start tilt {tilt:.2} deg; error at the first scan {first:.3}, while driving mean {mean:.3} worst {worst:.3}");
        assert!(
            tilt > 2.0,
            "the start must be on a slope for this test to mean anything: {tilt}"
        );
        assert!(
            first < 0.15,
            "start attitude from gravity: {first:.3} deg off"
        );
        assert!(
            mean < 0.2 && worst < 0.6,
            "attitude while driving: mean {mean:.3}, worst {worst:.3} deg off"
        );
        // The control: without the accelerometer the roll at the start is unknown (one antenna
        // baseline) and the GNSS track fit needs tens of metres to find it.
        let (_, first_blind, mean_blind, worst_blind) = tilt_errors_on_hills(false);
        eprintln!("without IMU: error at the first scan {first_blind:.3}, while driving mean {mean_blind:.3} worst {worst_blind:.3}");
        assert!(
            first_blind > 4.0 * first.max(0.05),
            "{first_blind} vs {first}"
        );
        assert!(mean_blind > 3.0 * mean, "{mean_blind} vs {mean}");
    }

    #[test]
    fn a_pole_at_the_robots_shoulder_stops_it_then_is_detoured() {
        // A pole beside the long leg: its edge 0.38 m from the taught line, inside the safety
        // stop zone (half width 0.35 + 0.08) but outside the corridor the map is checked on
        // (narrowed here so that the map alone cannot see the pole in the way, as with a person
        // standing at the robot's shoulder whom the map has not caught).
        let narrow = || {
            let mut cfg = AgentConfig::default();
            cfg.repeat.corridor_margin_m = -0.25;
            cfg
        };
        let pole: ObstacleFile =
            toml::from_str("[[pole]]\nx_m = 12.0\ny_m = -5.54\nradius_m = 0.08\nheight_m = 1.5\n")
                .unwrap();
        let opts = HeadlessOptions {
            timeout_s: 150.0,
            ..HeadlessOptions::default()
        };
        let rep = run_teach_repeat(&taught_field(), narrow(), Some(&pole), &opts).unwrap();
        eprintln!("{}", serde_json::to_string(&rep).unwrap());
        assert_eq!(rep.outcome, "reached", "{rep:?}");
        assert_eq!(rep.collisions, 0);
        assert!(rep.detours >= 1, "{rep:?}");
        assert!(rep.final_error_m <= 0.3, "{rep:?}");
        // The control: a stop that never turns into a blockage waits at the pole for ever.
        let mut cfg = narrow();
        cfg.repeat.safety_stop_block_s = f64::INFINITY;
        // (Unhindered, the return takes 80 s.)
        let short = HeadlessOptions {
            timeout_s: 110.0,
            ..HeadlessOptions::default()
        };
        let stuck = run_teach_repeat(&taught_field(), cfg, Some(&pole), &short).unwrap();
        assert_eq!(stuck.outcome, "timeout", "{stuck:?}");
    }

    #[test]
    fn drives_around_a_crate_to_a_map_goal() {
        let scenario = sim::Scenario::from_toml_str(FIELD, "<field>").unwrap();
        let rep = run_goal(
            &scenario,
            AgentConfig::default(),
            GoalTarget::Map {
                x_m: 16.0,
                y_m: 0.0,
            },
            &HeadlessOptions {
                timeout_s: 120.0,
                ..HeadlessOptions::default()
            },
        )
        .unwrap();
        eprintln!("{}", serde_json::to_string(&rep).unwrap());
        assert_eq!(rep.outcome, "reached", "{rep:?}");
        assert_eq!(rep.collisions, 0);
        assert!(rep.final_error_m < 0.5, "{}", rep.final_error_m);
        assert!(
            rep.path_length_m > 16.3,
            "went around the crate: {}",
            rep.path_length_m
        );
    }
}

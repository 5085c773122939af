//! The rig: a simulator with an agent on it, stepped together, and what it measures of a run
//! against the simulator's truth (timings, localisation error, distance driven).

use super::{stages, HeadlessOptions, CONTROL_DT_S, SIM_DT_S};
use crate::runtime::Input;
use agent::command::Command;
use agent::{Agent, AgentConfig, Cmd, Identity};
use common::geom::Pose2;
use serde::Serialize;
use std::time::Instant;

/// Timing statistics.
#[derive(Default, Clone, Copy, Debug)]
pub(super) struct Stat {
    pub(super) n: u32,
    sum: f64,
    pub(super) max: f64,
}

impl Stat {
    fn add(&mut self, ms: f64) {
        self.n += 1;
        self.sum += ms;
        self.max = self.max.max(ms);
    }
    pub(super) fn mean(&self) -> f64 {
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
    pub(super) plan: Stat,
    pub(super) scan: Stat,
    /// Collisions so far (truth).
    pub collisions: u32,
    /// Worst localisation errors so far (agent pose vs truth, right after each scan).
    pub loc: LocalisationError,
    /// Per sweep localised (not with truth poses): the height error of the agent's pose and
    /// the angle between its up axis and the true one, degrees (`map eval`'s percentiles).
    pub loc_samples: Vec<[f64; 2]>,
    pub(super) driven_m: f64,
    last_truth: (f64, f64),
    pub(super) trajectory: Vec<(f64, f64)>,
    /// How sweeps reach the map.
    pub scan_mode: ScanMode,
    /// When set (evaluations only), every localised sweep is also mapped here at its true
    /// pose, de-skewed with the true motion: the same sweeps' map without the pose error.
    pub truth_twin: Option<mapping::Mapper>,
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
            lidar: opts.lidar.clone(),
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
            truth_twin: None,
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
            loc_samples: Vec::new(),
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
                    let stamp_s = scan.stamp_s;
                    let twin_sweep = self.truth_twin.is_some().then(|| self.truth_sweep(&scan));
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
                    if let (Some(twin), Some((points, origin, robot))) =
                        (self.truth_twin.as_mut(), twin_sweep)
                    {
                        if let Err(e) = twin.update_sweep(points, origin, &robot, stamp_s) {
                            tracing::warn!("truth twin at {stamp_s:.2} s: {e}");
                        }
                    }
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
                // Bounded (a day of sweeps at 10 Hz): a live rig may run for long.
                if self.scan_mode == ScanMode::Localised && self.loc_samples.len() < 1 << 20 {
                    self.loc_samples.push([d.z, tilt]);
                }
                self.loc.scans += 1;
                self.loc.tilt_mean_deg +=
                    (tilt - self.loc.tilt_mean_deg) / f64::from(self.loc.scans);
                if trace_enabled() {
                    let h = self.agent.localiser().health();
                    eprintln!(
                        "trace scan t {:.1} {} slam inliers {:.2} iter {} degenerate {} eig {:.1e} mapped {}",
                        self.t_s(),
                        self.pose_error_text(),
                        h.inlier_ratio,
                        h.iterations,
                        h.degenerate,
                        h.eig_ratio,
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
pub(super) fn trace_enabled() -> bool {
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

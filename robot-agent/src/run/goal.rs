//! Headless goal missions: the options every headless run takes, and a goal mission driven to
//! its end with its report.

use super::rig::{trace_enabled, LocalisationError, Rig};
use super::stages;
use agent::command::{Command, CommandKind, GoalTarget};
use agent::mission::Phase;
use agent::AgentConfig;
use common::geom::Pose2;
use serde::Serialize;
use std::time::Instant;

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
    /// The simulated LiDAR (model and rotation rate).
    pub lidar: sim::LidarConfig,
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
            lidar: sim::LidarConfig::default(),
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

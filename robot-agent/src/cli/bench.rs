//! `robot-agent bench pipeline`: the whole agent per VLP-16 sweep on a goal mission in the
//! built-in world (localisation, map update, safety, planning, control, and their total per
//! sensor period), median and p99 against the sensor period. The agent runs on one thread and
//! its CPU time is what is measured (other programs on the machine do not inflate it); the
//! simulator's own time is not counted. `--drive` drives the scenario's `[drive]` polyline with
//! the scripted driver instead (the `loop` scenario's 353 m with `--graph on`: the map rebuild
//! after a pose graph correction is then in the per-sweep times).

use crate::run::{self, HeadlessOptions};
use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `robot-agent bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[command(subcommand)]
    pub what: BenchWhat,
}

/// Benchmarks.
#[derive(Debug, clap::Subcommand)]
pub enum BenchWhat {
    /// The agent's stages per sweep on a simulated goal mission.
    Pipeline(PipelineArgs),
}

/// `bench pipeline` options.
#[derive(Debug, clap::Args)]
pub struct PipelineArgs {
    /// Scenario.
    #[arg(long, default_value = "config/scenarios/park.toml")]
    pub scenario: PathBuf,
    /// Map goal `X,Y` (the park scenario test's first goal by default).
    #[arg(long, default_value = "-12,0", allow_hyphen_values = true)]
    pub goal: String,
    /// Drive the scenario's `[drive]` polyline (scripted) instead of a goal mission.
    #[arg(long)]
    pub drive: bool,
    /// Run the pose graph (`on`) or not (`off`) whatever `[graph] enabled` in
    /// config/slam.toml says.
    #[arg(long, value_name = "on|off", value_parser = super::map::parse_on_off)]
    pub graph: Option<bool>,
    /// Override `map_rebuild_sweeps_per_tick` (0: the whole rebuild inside one sweep).
    #[arg(long)]
    pub rebuild_sweeps_per_tick: Option<usize>,
    /// Simulator seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Configuration folder (default: config/).
    #[arg(long)]
    pub config_dir: Option<PathBuf>,
    /// Print one JSON object only.
    #[arg(long)]
    pub json: bool,
}

/// The LiDAR period the totals are compared with, milliseconds (a VLP-16 at 10 Hz).
const SENSOR_PERIOD_MS: f64 = 100.0;

/// A scripted drive stops after this much simulated time even if not done, seconds.
const DRIVE_MAX_S: f64 = 1200.0;

/// Drives the scenario's `[drive]` polyline with the agent running and its stages timed;
/// returns the outcome and the rig.
fn drive_rig(
    scenario: &sim::Scenario,
    cfg: agent::AgentConfig,
    opts: &HeadlessOptions,
) -> anyhow::Result<(&'static str, run::Rig)> {
    let drive = scenario
        .drive
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("scenario {} has no [drive] polyline", scenario.name))?;
    let mut rig = run::Rig::new(scenario, cfg, opts, "sim")?;
    rig.stage_times = Some(run::stages::StageTimes::default());
    let mut driver = sim::drive::PathDriver::new(&drive.points, drive.speed_mps);
    while !driver.is_done() && rig.t_s() < DRIVE_MAX_S {
        let (v, w) = driver.command(&rig.sim.truth_pose2());
        rig.drive_override = Some(agent::Cmd {
            v_mps: v,
            omega_rps: w,
        });
        rig.step();
    }
    let outcome = if driver.is_done() {
        "drive done"
    } else {
        "drive not done in time"
    };
    Ok((outcome, rig))
}

/// Runs `robot-agent bench`.
pub fn run(a: BenchArgs) -> anyhow::Result<()> {
    match a.what {
        BenchWhat::Pipeline(p) => pipeline(p),
    }
}

fn pipeline(a: PipelineArgs) -> anyhow::Result<()> {
    let scenario = sim::Scenario::load(&a.scenario)
        .with_context(|| format!("loading {}", a.scenario.display()))?;
    let dir = a
        .config_dir
        .clone()
        .unwrap_or_else(crate::config::default_config_dir);
    let mut cfg = crate::config::load_agent_config(&dir)?;
    if let Some(on) = a.graph {
        cfg.slam.graph.enabled = on;
    }
    if let Some(n) = a.rebuild_sweeps_per_tick {
        cfg.slam.graph.map_rebuild_sweeps_per_tick = n;
    }
    let v = super::mission::numbers(&a.goal, "--goal", 2..=2)?;
    let target = agent::command::GoalTarget::Map {
        x_m: v[0],
        y_m: v[1],
    };
    let opts = HeadlessOptions {
        seed: a.seed,
        time_stages: true,
        ..HeadlessOptions::default()
    };
    if !a.json {
        let what = if a.drive {
            "its [drive]".to_string()
        } else {
            format!("goal {}", a.goal)
        };
        eprintln!(
            "bench pipeline: {} {what} (seed {}) ...",
            scenario.name, a.seed
        );
    }
    let (outcome, rig) = if a.drive {
        let (o, rig) = drive_rig(&scenario, cfg, &opts)?;
        (serde_json::json!(o), rig)
    } else {
        let (report, rig) = run::run_goal_rig(&scenario, cfg, target, &opts)?;
        (serde_json::json!(report.outcome), rig)
    };
    let terrain = rig.agent.terrain();
    let (rebuilds, kept_sweeps) = terrain.rebuild_counts();
    let (kept_bytes, kept_dropped) = terrain.rebuild_memory();
    let rebuild = serde_json::json!({
        "rebuilds": rebuilds,
        "retargets": terrain.rebuild_retargets(),
        "kept_sweeps": kept_sweeps,
        "kept_mb": kept_bytes as f64 * 1e-6,
        "kept_dropped": kept_dropped,
        "optimisations": rig.agent.localiser().graph_stats().map(|g| g.optimisations),
    });
    let stages = rig
        .stage_times
        .as_ref()
        .map(|t| t.summary())
        .unwrap_or_default();
    let total = stages.get("total").copied().unwrap_or_default();
    let out = serde_json::json!({
        "scenario": scenario.name,
        "outcome": outcome,
        "rebuild": rebuild,
        "sweeps": total.n,
        "sensor_period_ms": SENSOR_PERIOD_MS,
        "total_median_share_of_period": total.median_ms / SENSOR_PERIOD_MS,
        "total_p99_share_of_period": total.p99_ms / SENSOR_PERIOD_MS,
        "stages": stages,
    });
    if !a.json {
        eprintln!(
            "{:<14} {:>6} {:>10} {:>10} {:>10}",
            "stage", "n", "median ms", "p99 ms", "max ms"
        );
        for (k, s) in &stages {
            eprintln!(
                "{k:<14} {:>6} {:>10.2} {:>10.2} {:>10.2}",
                s.n, s.median_ms, s.p99_ms, s.max_ms
            );
        }
        eprintln!(
            "total per sweep: median {:.1} % of the {SENSOR_PERIOD_MS} ms sensor period, p99 {:.1} %",
            100.0 * total.median_ms / SENSOR_PERIOD_MS,
            100.0 * total.p99_ms / SENSOR_PERIOD_MS
        );
        eprintln!("map rebuild: {rebuild}");
    }
    println!("{out}");
    Ok(())
}

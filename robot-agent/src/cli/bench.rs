//! `robot-agent bench pipeline`: the whole agent per VLP-16 sweep on a goal mission in the
//! built-in world (localisation, map update, safety, planning, control, and their total per
//! sensor period), median and p99 against the sensor period. The agent runs on one thread and
//! its CPU time is what is measured (other programs on the machine do not inflate it); the
//! simulator's own time is not counted.

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
    let cfg = crate::config::load_agent_config(&dir)?;
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
        eprintln!(
            "bench pipeline: {} goal {} (seed {}) ...",
            scenario.name, a.goal, a.seed
        );
    }
    let (report, rig) = run::run_goal_rig(&scenario, cfg, target, &opts)?;
    let stages = rig
        .stage_times
        .as_ref()
        .map(|t| t.summary())
        .unwrap_or_default();
    let total = stages.get("total").copied().unwrap_or_default();
    let out = serde_json::json!({
        "scenario": scenario.name,
        "outcome": report.outcome,
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
    }
    println!("{out}");
    Ok(())
}

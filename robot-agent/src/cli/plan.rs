//! `robot-agent plan`: planning tools.
//!
//! `plan bench MAP SCEN [--json]` plans every scenario of a Moving AI benchmark map with our A*
//! and (feature `bench-baseline`) with the `pathfinding` crate's A* on the same grid and the same
//! movement rule (8-connected, no corner cutting), timed in the same run. Last line:
//! `scenarios N exact E max_abs_err X ms_total T baseline_ms B`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use planning::movingai::{load_map, load_scen};
use planning::{PlanError, Planner};

/// Arguments of `robot-agent plan`.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    #[command(subcommand)]
    command: PlanCommand,
}

#[derive(Debug, clap::Subcommand)]
enum PlanCommand {
    /// Plan every scenario of a Moving AI map (.map + .scen) and compare with the optimal lengths
    /// and the `pathfinding` crate's A*.
    Bench {
        /// The `.map` file.
        map: PathBuf,
        /// The `.scen` file.
        scen: PathBuf,
        /// Print one JSON object per scenario before the summary line.
        #[arg(long)]
        json: bool,
    },
}

/// Runs `robot-agent plan`.
pub fn run(args: PlanArgs) -> anyhow::Result<()> {
    match args.command {
        PlanCommand::Bench { map, scen, json } => bench(&map, &scen, json),
    }
}

/// A scenario's result with our planner.
struct Outcome {
    length: Option<f64>,
    expansions: usize,
}

fn bench(
    map_path: &std::path::Path,
    scen_path: &std::path::Path,
    json: bool,
) -> anyhow::Result<()> {
    let map = load_map(map_path).context("loading the map")?;
    let scens = load_scen(scen_path).context("loading the scenarios")?;
    let grid = map.to_grid();

    // Our A*, timed over the planning calls only (grid built once, outside the timing).
    let mut planner = Planner::new();
    let mut outcomes = Vec::with_capacity(scens.len());
    let t0 = Instant::now();
    for s in &scens {
        outcomes.push(match planner.plan(&grid, s.start, s.goal) {
            Ok(p) => Outcome {
                length: Some(p.length_m),
                expansions: p.expansions,
            },
            Err(PlanError::NoPath { expansions }) => Outcome {
                length: None,
                expansions,
            },
            Err(_) => Outcome {
                length: None,
                expansions: 0,
            },
        });
    }
    let ms_total = t0.elapsed().as_secs_f64() * 1e3;
    let baseline_ms = baseline_ms(&grid, &scens);

    let mut exact = 0usize;
    let mut max_abs_err = 0.0f64;
    for (i, (s, o)) in scens.iter().zip(&outcomes).enumerate() {
        // A missing path counts as an infinite error: every benchmark scenario is solvable.
        let err = o
            .length
            .map_or(f64::INFINITY, |l| (l - s.optimal_length).abs());
        if err < 1e-5 {
            exact += 1;
        }
        max_abs_err = max_abs_err.max(err);
        if json {
            println!(
                "{}",
                serde_json::json!({
                    "index": i,
                    "bucket": s.bucket,
                    "start": [s.start.x, s.start.y],
                    "goal": [s.goal.x, s.goal.y],
                    "optimal_length": s.optimal_length,
                    "length": o.length,
                    "abs_err": o.length.map(|l| (l - s.optimal_length).abs()),
                    "expansions": o.expansions,
                })
            );
        }
    }
    println!(
        "scenarios {} exact {} max_abs_err {:.3e} ms_total {:.3} baseline_ms {}",
        scens.len(),
        exact,
        max_abs_err,
        ms_total,
        baseline_ms.map_or_else(|| "nan".to_string(), |b| format!("{b:.3}")),
    );
    Ok(())
}

/// Total time of the `pathfinding` crate's A* over all scenarios, milliseconds.
#[cfg(feature = "bench-baseline")]
fn baseline_ms(grid: &planning::PlanGrid, scens: &[planning::movingai::Scenario]) -> Option<f64> {
    let t0 = Instant::now();
    let mut lengths = Vec::with_capacity(scens.len());
    for s in scens {
        lengths.push(planning::baseline::pathfinding_astar(grid, s.start, s.goal).map(|p| p.1));
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let exact = scens
        .iter()
        .zip(&lengths)
        .filter(|(s, l)| l.is_some_and(|l| (l - s.optimal_length).abs() < 1e-5))
        .count();
    eprintln!(
        "baseline (pathfinding::astar): {exact}/{} exact",
        scens.len()
    );
    Some(ms)
}

/// Without the feature there is no baseline; say how to get one.
#[cfg(not(feature = "bench-baseline"))]
fn baseline_ms(_grid: &planning::PlanGrid, _scens: &[planning::movingai::Scenario]) -> Option<f64> {
    eprintln!(
        "note: no baseline timed; rebuild with `cargo build --release -p robot-agent --features bench-baseline` \
         to time the pathfinding crate's A* on the same grid"
    );
    None
}

//! `robot-agent sim`: run a simulated robot in the built-in world.
//!
//! - `robot-agent sim --scenario FILE --headless --duration S (--drive V,W | --follow-drive)
//!   [--record DIR] [--seed N]`: drives the plant headless and (optionally) records the sequence
//!   folder (`clouds/NNN.pcd`, `poses.txt`, `stamps.txt`, `odom.txt`, `nmea.log`, `meta.toml`).
//!   Prints one JSON summary line.
//! - `robot-agent sim render --scenario FILE --png OUT [--labels]`: top-down PNG of the world.
//!
//! Live mode (on the bus) is not built yet; it will be a sibling of [`run_headless`].

use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `robot-agent sim`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct SimArgs {
    /// Sub-tools (`render`); without one, run the simulation.
    #[command(subcommand)]
    pub tool: Option<SimTool>,
    /// Scenario TOML (`config/scenarios/park.toml`).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Run offline to completion and print a report (without it, the robot runs live on the bus).
    #[arg(long)]
    pub headless: bool,
    /// Simulated duration, seconds.
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Constant command `V,W` (m/s, rad/s).
    #[arg(long, value_parser = parse_drive, allow_hyphen_values = true)]
    pub drive: Option<(f64, f64)>,
    /// Follow the scenario's `[drive]` polyline with the scripted driver (truth pose).
    #[arg(long, conflicts_with = "drive")]
    pub follow_drive: bool,
    /// Record the run into this folder.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Also record depth-camera frames (`depth/NNN.pcd`).
    #[arg(long)]
    pub record_depth: bool,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulation step, seconds.
    #[arg(long, default_value_t = 0.02)]
    pub dt: f64,
    /// Missions and the live robot (`--goal`, `--goal-gnss`, `--teach-repeat`, `--robot`, `--connect`).
    #[command(flatten)]
    pub mission: super::mission::MissionArgs,
}

/// `robot-agent sim` sub-tools.
#[derive(Debug, clap::Subcommand)]
pub enum SimTool {
    /// Draw a scenario's height field (and truth labels) as a top-down PNG.
    Render(RenderArgs),
}

/// Arguments of `robot-agent sim render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Scenario TOML.
    #[arg(long)]
    pub scenario: PathBuf,
    /// Output PNG.
    #[arg(long)]
    pub png: PathBuf,
    /// Tint cells by their truth traversability label.
    #[arg(long)]
    pub labels: bool,
    /// Metres per pixel.
    #[arg(long, default_value_t = 0.1)]
    pub m_per_px: f64,
}

fn parse_drive(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once(',').ok_or("want V,W (m/s,rad/s)")?;
    let v: f64 = a.trim().parse().map_err(|e| format!("V: {e}"))?;
    let w: f64 = b.trim().parse().map_err(|e| format!("W: {e}"))?;
    if !(v.is_finite() && w.is_finite()) {
        return Err("V and W must be finite".into());
    }
    Ok((v, w))
}

/// Runs `robot-agent sim`.
pub fn run(args: SimArgs) -> anyhow::Result<()> {
    if let Some(SimTool::Render(r)) = &args.tool {
        return run_render(r);
    }
    if args.mission.is_mission() || !args.headless {
        let path = args
            .scenario
            .as_ref()
            .context("--scenario FILE is required")?;
        let scenario = sim::Scenario::load(path)?;
        if !args.headless {
            anyhow::ensure!(!args.mission.is_mission(), "--goal/--goal-gnss/--teach-repeat need --headless (live robots take goals over the bus)");
            let name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            return super::mission::run_live(&scenario, &name, &args.mission, args.seed);
        }
        return super::mission::run_headless(&scenario, &args.mission, args.seed);
    }
    run_headless(&args)
}

/// How the headless run is driven.
enum Driver {
    Constant(f64, f64),
    Path(sim::drive::PathDriver),
}

/// Headless run: drive the plant, optionally record, print a JSON summary.
pub fn run_headless(args: &SimArgs) -> anyhow::Result<()> {
    let path = args
        .scenario
        .as_ref()
        .context("--scenario FILE is required")?;
    let scenario = sim::Scenario::load(path)?;
    if !(args.duration.is_finite() && args.duration > 0.0) {
        anyhow::bail!("--duration must be > 0");
    }
    if !(args.dt.is_finite() && args.dt > 0.0 && args.dt <= 0.1) {
        anyhow::bail!("--dt must be within (0, 0.1] s");
    }
    let mut driver = match (args.drive, args.follow_drive) {
        (Some((v, w)), _) => Driver::Constant(v, w),
        (None, true) => {
            let d = scenario
                .drive
                .as_ref()
                .context("scenario has no [drive] polyline")?;
            Driver::Path(sim::drive::PathDriver::new(&d.points, d.speed_mps))
        }
        (None, false) => anyhow::bail!("give --drive V,W or --follow-drive"),
    };
    let cfg = sim::SimConfig {
        seed: args.seed,
        depth: sim::DepthConfig {
            enabled: args.record_depth,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut simu = sim::Simulation::new(&scenario, cfg);
    let mut rec = match &args.record {
        Some(dir) => Some(
            sim::record::Recorder::create(dir, args.record_depth)
                .with_context(|| format!("creating {}", dir.display()))?,
        ),
        None => None,
    };
    let steps = (args.duration / args.dt).round() as usize;
    let mut collisions = Vec::new();
    let mut scans = 0usize;
    let mut path_m = 0.0;
    let mut last = simu.truth_pose2();
    for _ in 0..steps {
        let (v, w) = match &mut driver {
            Driver::Constant(v, w) => (*v, *w),
            Driver::Path(d) => d.command(&simu.truth_pose2()),
        };
        let out = simu.step(args.dt, v, w);
        scans += out.scan.is_some() as usize;
        for c in &out.collisions {
            tracing::warn!(t_s = c.t_s, kind = ?c.kind, object = c.object, x_m = c.x_m, y_m = c.y_m, "collision");
        }
        collisions.extend(out.collisions.iter().copied());
        if let Some(r) = &mut rec {
            r.write_step(&simu, &out).context("writing the recording")?;
        }
        let p = simu.truth_pose2();
        path_m += p.distance_to(&last);
        last = p;
    }
    if let Some(r) = rec {
        r.finish(&simu).context("writing meta.toml")?;
    }
    let p = simu.truth_pose();
    let t = p.translation.vector;
    let summary = serde_json::json!({
        "scenario": scenario.name,
        "seed": args.seed,
        "duration_s": simu.time_s(),
        "scans": scans,
        "path_m": path_m,
        "final_pose_m": [t.x, t.y, t.z],
        "final_yaw_rad": simu.truth_pose2().yaw_rad,
        "collisions": collisions.len(),
        "collision_kinds": collisions.iter().map(|c| format!("{:?}", c.kind)).collect::<Vec<_>>(),
        "drive_done": matches!(&driver, Driver::Path(d) if d.is_done()),
        "record": args.record.as_ref().map(|d| d.display().to_string()),
    });
    println!("{summary}");
    Ok(())
}

fn run_render(r: &RenderArgs) -> anyhow::Result<()> {
    let scenario = sim::Scenario::load(&r.scenario)?;
    let world = sim::World::new(&scenario);
    let opt = sim::render::RenderOptions {
        m_per_px: r.m_per_px,
        labels: r.labels,
        ..Default::default()
    };
    let png = sim::render::render_png(&scenario, &world, &sim::LabelParams::default(), &opt)?;
    std::fs::write(&r.png, png).with_context(|| format!("writing {}", r.png.display()))?;
    println!(
        "{}",
        serde_json::json!({"scenario": scenario.name, "png": r.png.display().to_string(), "bytes_written": true})
    );
    Ok(())
}

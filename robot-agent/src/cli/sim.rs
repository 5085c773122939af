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
    /// Follow the scenario's `[drive]` polyline with the scripted driver (truth pose); live, the
    /// robot drives it once and then stands, taking commands as before.
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
    /// Serve the world as a robot's hardware: publish its sensors as ROS 2 topics over Zenoh and
    /// drive it by `cmd_vel` (no agent; run `robot-agent run` against it).
    #[arg(long)]
    pub serve_ros2: bool,
    /// `--serve-ros2`: key form, `bridge` (zenoh-bridge-ros2dds) or `rmw` (rmw_zenoh).
    #[arg(long, default_value = "bridge", value_name = "FORM")]
    pub ros2_keys: String,
    /// `--serve-ros2`: namespace of the topics.
    #[arg(long, default_value = "", value_name = "NS")]
    pub ros2_namespace: String,
    /// `--serve-ros2`: ROS_DOMAIN_ID (rmw form).
    #[arg(long, default_value_t = 0, value_name = "ID")]
    pub ros2_domain_id: u32,
    /// Zenoh endpoint to listen on: with `--serve-ros2` the hardware's, e.g. tcp/127.0.0.1:7450
    /// (as a bridge does); live, so stations can link to the robot directly (with --pki:
    /// quic/ADDR:PORT; default a loopback port, or none with --pki). Off loopback needs --pki.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// `--serve-ros2`: also publish the depth camera (`depth/points`).
    #[arg(long)]
    pub depth: bool,
    /// `--serve-ros2`: hold a sensor silent, `STREAM@FROM_S+FOR_S` (lidar, depth, odom, imu,
    /// gnss), e.g. `lidar@20+2`; repeatable.
    #[arg(long, value_name = "SPEC")]
    pub silence: Vec<crate::run::world::Silence>,
    /// `--serve-ros2`: period of the simulator's truth lines on stdout, seconds.
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub truth_period_s: f64,
    /// `--serve-ros2`: also be the robot's navigation computer on UDP, `udp:PORT` (loopback) or
    /// `udp:HOST:PORT`: it drives the robot along the waypoint lists `robot-agent run
    /// --nav-computer orpheus-udp:...` sends (Orpheus protocol, methods.md §7).
    #[arg(long, value_name = "udp:[HOST:]PORT")]
    pub nav_computer_listen: Option<String>,
    /// `--serve-ros2`: obstacles that appear at a simulated time, `FILE@T_S` (FILE in the
    /// format of `--add-obstacles`), e.g. a car parked on a taught route; repeatable.
    #[arg(long, value_name = "FILE@T_S")]
    pub obstacles_at: Vec<String>,
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
    if args.serve_ros2 {
        return run_world(&args);
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
            return super::mission::run_live(
                &scenario,
                &name,
                &args.mission,
                &args.listen,
                args.seed,
                args.follow_drive,
            );
        }
        return super::mission::run_headless(&scenario, &args.mission, args.seed);
    }
    run_headless(&args)
}

/// `--serve-ros2`: the world as hardware until SIGINT/SIGTERM.
fn run_world(args: &SimArgs) -> anyhow::Result<()> {
    use crate::run::world::{serve_world, WorldOptions};
    anyhow::ensure!(
        !args.headless && !args.mission.is_mission(),
        "--serve-ros2 runs the world live; missions come from `robot-agent run` against it"
    );
    let path = args
        .scenario
        .as_ref()
        .context("--scenario FILE is required")?;
    anyhow::ensure!(
        args.truth_period_s.is_finite() && args.truth_period_s >= 0.01,
        "--truth-period-s must be at least 0.01"
    );
    let scenario = sim::Scenario::load(path)?;
    let dir = args
        .mission
        .config_dir
        .clone()
        .unwrap_or_else(crate::config::default_config_dir);
    let cfg = crate::config::load_agent_config(&dir)
        .with_context(|| format!("loading configuration from {}", dir.display()))?;
    let mut sim_cfg = sim::SimConfig {
        seed: args.seed,
        robot: cfg.profile,
        depth: sim::DepthConfig {
            enabled: args.depth,
            ..Default::default()
        },
        lidar: args.mission.lidar_config()?,
        ..sim::SimConfig::default()
    };
    if let Some(s) = &args.mission.start {
        let v = super::mission::numbers(s, "--start", 3..=3)?;
        sim_cfg.start = Some(common::geom::Pose2::new(v[0], v[1], v[2].to_radians()));
    }
    let form = args
        .ros2_keys
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--ros2-keys: {e}"))?;
    let zenoh = crate::bus::ZenohSettings {
        file: args.mission.zenoh.clone(),
        connect: args.mission.connect.iter().cloned().collect(),
        listen: args.listen.clone(),
        ..Default::default()
    };
    let nav_computer = args
        .nav_computer_listen
        .as_deref()
        .map(parse_udp_listen)
        .transpose()?;
    let mut obstacles_at = Vec::new();
    for spec in &args.obstacles_at {
        let (file, at) = spec
            .rsplit_once('@')
            .context("--obstacles-at: want FILE@T_S")?;
        let at: f64 = at
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite() && *t >= 0.0)
            .with_context(|| format!("--obstacles-at {spec:?}: T_S must be seconds >= 0"))?;
        let obstacles = crate::run::ObstacleFile::load(std::path::Path::new(file))
            .with_context(|| format!("--obstacles-at {file}"))?
            .obstacles();
        obstacles_at.push((at, obstacles));
    }
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    super::run::stop_on_signals(stop.clone())?;
    if args.mission.exit_with_parent {
        super::mission::watch_parent(stop.clone());
    }
    serve_world(
        &scenario,
        WorldOptions {
            sim: sim_cfg,
            graph: io::ros2::Ros2Graph {
                form,
                domain_id: args.ros2_domain_id,
                namespace: args.ros2_namespace.clone(),
            },
            zenoh,
            topics: Default::default(),
            silences: args.silence.clone(),
            truth_period_s: args.truth_period_s,
            nav_computer,
            obstacles_at,
        },
        stop,
    )
}

/// `udp:PORT` (on loopback) or `udp:HOST:PORT`.
fn parse_udp_listen(s: &str) -> anyhow::Result<std::net::SocketAddr> {
    use std::net::ToSocketAddrs;
    let rest = s
        .strip_prefix("udp:")
        .with_context(|| format!("--nav-computer-listen {s:?}: want udp:PORT or udp:HOST:PORT"))?;
    let addr = match rest.parse::<u16>() {
        Ok(port) => std::net::SocketAddr::from(([127, 0, 0, 1], port)),
        Err(_) => rest
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .with_context(|| format!("--nav-computer-listen {s:?}: not HOST:PORT"))?,
    };
    Ok(addr)
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
        lidar: args.mission.lidar_config()?,
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

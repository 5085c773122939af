//! The mission flags of `robot-agent sim`: headless goal missions, teach-and-repeat, and the live
//! robot on the bus.

use crate::bus::{secure, BusConfig, ZenohSettings};
use crate::config::{default_config_dir, load_agent_config};
use crate::run::{self, HeadlessOptions};
use agent::command::GoalTarget;
use agent::AgentConfig;
use anyhow::Context;
use common::geom::Pose2;
use common::keys::RobotId;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Mission flags, flattened into `robot-agent sim`.
#[derive(Debug, Clone, clap::Args)]
pub struct MissionArgs {
    /// Headless: drive to this map-frame goal and print a JSON report (`X,Y` metres).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub goal: Option<String>,
    /// Headless: drive to this GNSS goal (`LAT,LON[,H]` degrees, metres) through the datum.
    #[arg(long, value_name = "LAT,LON[,H]", allow_hyphen_values = true)]
    pub goal_gnss: Option<String>,
    /// Headless: teach the scenario's [teach] path by teleop, then return home along it.
    #[arg(long)]
    pub teach_repeat: bool,
    /// Obstacles (a scenario-format TOML with `[[car]]`, `[[box]]`, `[[tree]]`...) added before the return.
    #[arg(long, value_name = "FILE")]
    pub add_obstacles: Option<PathBuf>,
    /// Robot id on the bus (live mode).
    #[arg(long, default_value = "husky-1")]
    pub robot: String,
    /// Zenoh endpoint to connect to (live mode), e.g. tcp/127.0.0.1:7447 (with --pki:
    /// quic/STATION:7447; default quic/127.0.0.1:7447). Plain endpoints off loopback are refused.
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Option<String>,
    /// The robot's certificates (live mode): the folder `operator-station pki issue --robot ID`
    /// wrote (PKI/robots/ID/, copied to the robot), or the fleet's PKI folder itself. Turns on
    /// TLS with mutual authentication and the robot's access rules.
    #[arg(long, value_name = "DIR")]
    pub pki: Option<PathBuf>,
    /// Zenoh json5 config file (live mode).
    #[arg(long, value_name = "FILE")]
    pub zenoh: Option<PathBuf>,
    /// Live mode: budget for everything the robot publishes, kilobits per second (0 =
    /// unlimited); default `[bus] uplink_budget_kbps` of robot.toml.
    #[arg(long, value_name = "KBPS")]
    pub uplink_budget_kbps: Option<f64>,
    /// Live mode: stop when the process that started this one exits (how `operator-station
    /// demo` keeps its simulated robots from outliving it when it is killed outright).
    #[arg(long)]
    pub exit_with_parent: bool,
    /// Folder with robot.toml, slam.toml, mapper.toml, planner.toml, control.toml, mission.toml.
    #[arg(long, value_name = "DIR")]
    pub config_dir: Option<PathBuf>,
    /// Headless: give up after this much simulated time, seconds.
    #[arg(long, default_value_t = 600.0)]
    pub timeout: f64,
    /// Start pose `X,Y,YAW_DEG` instead of the scenario's.
    #[arg(long, value_name = "X,Y,YAW_DEG", allow_hyphen_values = true)]
    pub start: Option<String>,
    /// Live mode: write the simulator's true pose (`t_unix_ms x y yaw`, every 0.1 s) to this
    /// file, for tests that judge where the robot really drove.
    #[arg(long, value_name = "FILE")]
    pub truth_out: Option<PathBuf>,
    /// Headless goal or teach and repeat: draw the robot's traversability map with the driven
    /// path (truth; for teach and repeat the return) and the goal into this PNG at the end.
    #[arg(long, value_name = "FILE")]
    pub png: Option<PathBuf>,
    /// The simulated LiDAR, `MODEL[@HZ]`: `vlp16` (the default, 10 Hz), `hdl32e`, `os1-64`;
    /// e.g. `vlp16@2` spins a VLP-16 at 2 Hz. The agent is not told: it adapts to the data.
    #[arg(long, value_name = "MODEL[@HZ]", default_value = "vlp16")]
    pub lidar: String,
    /// Record the run to MCAP (headless missions and the live robot).
    #[command(flatten)]
    pub mcap: crate::record::McapArgs,
}

impl MissionArgs {
    /// The simulated LiDAR `--lidar` asks for.
    pub fn lidar_config(&self) -> anyhow::Result<sim::LidarConfig> {
        sim::LidarConfig::parse_spec(&self.lidar).map_err(|e| anyhow::anyhow!("--lidar: {e}"))
    }
}

impl MissionArgs {
    /// True when these flags ask for a mission (otherwise `sim` records or drives).
    pub fn is_mission(&self) -> bool {
        self.goal.is_some() || self.goal_gnss.is_some() || self.teach_repeat
    }
}

/// Parses `A,B,...` numbers (`what` names the flag in errors), expecting a count within `n`.
pub fn numbers(
    s: &str,
    what: &str,
    n: std::ops::RangeInclusive<usize>,
) -> anyhow::Result<Vec<f64>> {
    let v: Result<Vec<f64>, _> = s.split(',').map(|t| t.trim().parse::<f64>()).collect();
    let v = v.with_context(|| format!("{what}: {s:?} is not a comma-separated list of numbers"))?;
    anyhow::ensure!(
        n.contains(&v.len()),
        "{what}: expected {n:?} numbers, got {}",
        v.len()
    );
    anyhow::ensure!(
        v.iter().all(|x| x.is_finite()),
        "{what}: numbers must be finite"
    );
    Ok(v)
}

fn agent_config(args: &MissionArgs) -> anyhow::Result<AgentConfig> {
    let dir = args.config_dir.clone().unwrap_or_else(default_config_dir);
    load_agent_config(&dir).with_context(|| format!("loading configuration from {}", dir.display()))
}

fn options(args: &MissionArgs, seed: u64) -> anyhow::Result<HeadlessOptions> {
    let dir = args.config_dir.clone().unwrap_or_else(default_config_dir);
    let mcap = args.mcap.options(&dir, &dir.join("robot.toml"))?;
    let start = match &args.start {
        Some(s) => {
            let v = numbers(s, "--start", 3..=3)?;
            Some(Pose2::new(v[0], v[1], v[2].to_radians()))
        }
        None => None,
    };
    Ok(HeadlessOptions {
        seed,
        timeout_s: args.timeout,
        start,
        map_png: args.png.clone(),
        truth_out: args.truth_out.clone(),
        mcap,
        lidar: args.lidar_config()?,
        ..HeadlessOptions::default()
    })
}

/// Runs a headless mission and prints its JSON report (last line).
pub fn run_headless(scenario: &sim::Scenario, args: &MissionArgs, seed: u64) -> anyhow::Result<()> {
    let cfg = agent_config(args)?;
    let opts = options(args, seed)?;
    if args.teach_repeat {
        let obstacles = match &args.add_obstacles {
            Some(p) => Some(
                run::ObstacleFile::load(p)
                    .with_context(|| format!("--add-obstacles {}", p.display()))?,
            ),
            None => None,
        };
        let rep = run::run_teach_repeat(scenario, cfg, obstacles.as_ref(), &opts)?;
        println!("{}", serde_json::to_string(&rep)?);
        return Ok(());
    }
    let target = match (&args.goal, &args.goal_gnss) {
        (Some(g), None) => {
            let v = numbers(g, "--goal", 2..=2)?;
            GoalTarget::Map {
                x_m: v[0],
                y_m: v[1],
            }
        }
        (None, Some(g)) => {
            let v = numbers(g, "--goal-gnss", 2..=3)?;
            anyhow::ensure!(
                v[0].abs() <= 90.0 && v[1].abs() <= 180.0,
                "--goal-gnss: latitude/longitude out of range"
            );
            GoalTarget::Geodetic {
                lat_deg: v[0],
                lon_deg: v[1],
                h_m: v.get(2).copied(),
            }
        }
        _ => anyhow::bail!("give one of --goal, --goal-gnss, --teach-repeat"),
    };
    let (rep, rig) = run::run_goal_rig(scenario, cfg, target, &opts)?;
    if let Some(png) = &args.png {
        let mut path = rep.trajectory_m.clone();
        path.push(rep.final_m);
        rig.draw_map(&path, png)?;
        eprintln!("map drawn to {}", png.display());
    }
    eprintln!(
        "{}: {:.1} s simulated, {:.1} m driven, {} replans ({:.2} ms mean), {:.1}x real time",
        rep.outcome,
        rep.time_s,
        rep.path_length_m,
        rep.replans,
        rep.plan_ms_mean,
        rep.realtime_factor
    );
    println!("{}", serde_json::to_string(&rep)?);
    Ok(())
}

/// Runs the robot live on the bus until Ctrl-C.
pub fn run_live(
    scenario: &sim::Scenario,
    scenario_name: &str,
    args: &MissionArgs,
    listen: &[String],
    seed: u64,
    follow_drive: bool,
) -> anyhow::Result<()> {
    let cfg = agent_config(args)?;
    let opts = options(args, seed)?;
    let drive = if follow_drive {
        Some(
            scenario
                .drive
                .as_ref()
                .context("--follow-drive: the scenario has no [drive] polyline")?,
        )
    } else {
        None
    };
    let robot = RobotId::new(args.robot.clone()).map_err(|e| anyhow::anyhow!("--robot: {e}"))?;
    let bus = bus_config(args, listen, &robot)?;
    let stop = Arc::new(AtomicBool::new(false));
    // SIGINT/SIGTERM end the loop, so that a recording closes with its summary.
    super::run::stop_on_signals(stop.clone())?;
    if args.exit_with_parent {
        watch_parent(stop.clone());
    }
    let world = run::live::LiveWorld {
        scenario,
        name: scenario_name,
        drive,
    };
    run::live::run_live(world, cfg, robot, bus, &opts, stop)
}

/// The live robot's bus: endpoints, certificates; checked here, before the world is built, so a
/// refused endpoint is reported at once.
/// `listen`: `sim --listen`, so stations can link to the robot directly (with --pki: quic/...);
/// default a loopback port, or none with --pki.
fn bus_config(args: &MissionArgs, listen: &[String], robot: &RobotId) -> anyhow::Result<BusConfig> {
    let mut bus = BusConfig::new(robot.clone());
    let dir = args.config_dir.clone().unwrap_or_else(default_config_dir);
    bus.uplink = crate::config::load_run_file(&dir.join("robot.toml"))?
        .bus
        .uplink(args.uplink_budget_kbps)?;
    let tls = match &args.pki {
        Some(dir) => Some(secure::robot_files(dir, robot)?),
        None => None,
    };
    if args.zenoh.is_some() || args.connect.is_some() || !listen.is_empty() || tls.is_some() {
        let default_connect = match (&args.zenoh, &tls) {
            (None, Some(_)) => vec![format!(
                "{}/{}",
                common::security::SECURE_SCHEME,
                crate::bus::DEFAULT_STATION_ENDPOINT
                    .split_once('/')
                    .map_or("127.0.0.1:7447", |(_, a)| a)
            )],
            (None, None) => vec![crate::bus::DEFAULT_STATION_ENDPOINT.to_string()],
            (Some(_), _) => Vec::new(),
        };
        bus.zenoh = ZenohSettings {
            file: args.zenoh.clone(),
            connect: args.connect.clone().map_or(default_connect, |c| vec![c]),
            listen: listen.to_vec(),
            tls,
            ..ZenohSettings::default()
        };
    }
    bus.zenoh.to_config()?;
    Ok(bus)
}

/// The parent process as it was when this process started ([`note_parent`]).
static PARENT: std::sync::OnceLock<u32> = std::sync::OnceLock::new();

/// Notes this process's parent; call first thing in `main`, so that [`watch_parent`], installed
/// only once the sources are open, still sees a parent that died during the start.
pub fn note_parent() {
    #[cfg(unix)]
    let _ = PARENT.set(std::os::unix::process::parent_id());
}

/// Raises `stop` once this process's parent has exited (Unix: the process is handed to another
/// parent then, or was already when it started under init). Checked five times a second on its
/// own thread.
pub fn watch_parent(stop: Arc<AtomicBool>) {
    #[cfg(unix)]
    {
        let parent = *PARENT.get_or_init(std::os::unix::process::parent_id);
        std::thread::spawn(move || loop {
            if parent == 1 || std::os::unix::process::parent_id() != parent {
                tracing::warn!("parent process {parent} exited: stopping");
                stop.store(true, Ordering::Relaxed);
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(200));
        });
    }
    #[cfg(not(unix))]
    let _ = stop;
}

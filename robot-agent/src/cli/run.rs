//! `robot-agent run`: the agent on a real robot (or on the simulator served as hardware) until
//! SIGINT/SIGTERM. Sources and the base come from the `[io]` section of the robot file, each
//! overridable here; see `run::io_config` and `io::source` for the specs.

use crate::bus::{secure, BusConfig, ZenohSettings};
use crate::config::{default_config_dir, load_agent_config_with, load_run_file};
use crate::run::io_config::IoConfig;
use crate::run::nav_computer::NavComputerBase;
use crate::run::robot::{run_robot, Base, NoBase, RobotRun, SourceStart};
use crate::run::ros2::{Ros2Input, Ros2Link};
use crate::runtime::stamps::Topic;
use anyhow::Context;
use common::keys::RobotId;
use common::msg::Datum;
use io::ros2::{KeyForm, Ros2Graph};
use io::source::SourceSpec;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Arguments of `robot-agent run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Robot id on the bus.
    #[arg(long, default_value = "husky-1")]
    pub robot: String,
    /// The robot file (body, mounts, `[io]`, `[runtime]`); the algorithm files (slam.toml,
    /// mapper.toml, ...) are read from its folder. Default: `config/robot.toml`.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Zenoh endpoint of the operator station, e.g. tcp/192.168.1.10:7447.
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Zenoh json5 config file for the station session.
    #[arg(long, value_name = "FILE")]
    pub zenoh: Option<PathBuf>,
    /// Budget for everything the robot publishes, kilobits per second (0 = unlimited); default
    /// `[bus] uplink_budget_kbps`.
    #[arg(long, value_name = "KBPS")]
    pub uplink_budget_kbps: Option<f64>,
    /// The robot's certificates: the folder `operator-station pki issue --robot ID` wrote
    /// (PKI/robots/ID/, copied to the robot), or the fleet's PKI folder. The station link is then
    /// QUIC with mutual TLS authentication under the robot's access rules (default
    /// quic/127.0.0.1:7447; tls/ is accepted too). Without it, a station endpoint off loopback is refused.
    #[arg(long, value_name = "DIR")]
    pub pki: Option<PathBuf>,
    /// LiDAR source (`ros2:TOPIC`, `vlp16-udp:PORT`); overrides `[io] lidar`.
    #[arg(long, value_name = "SPEC")]
    pub lidar: Option<String>,
    /// Message type of a `ros2:` LiDAR topic: `PointCloud2` (sensor_msgs) or `VelodyneScan`
    /// (velodyne_msgs: a VLP-16 driver's raw packets, e.g. `--lidar ros2:velodyne_packets`).
    #[arg(long, value_name = "TYPE")]
    pub lidar_msg: Option<String>,
    /// Run without a LiDAR, to bring up and watch the other sensors (GNSS, odometry, IMU):
    /// nothing is mapped, and the base is never driven (nothing vouches for the space ahead).
    #[arg(long)]
    pub no_lidar: bool,
    /// Depth-camera source (`ros2:TOPIC`, or "" for none).
    #[arg(long, value_name = "SPEC")]
    pub depth: Option<String>,
    /// Odometry source (`ros2:TOPIC`).
    #[arg(long, value_name = "SPEC")]
    pub odom: Option<String>,
    /// IMU source (`ros2:TOPIC`, or "").
    #[arg(long, value_name = "SPEC")]
    pub imu: Option<String>,
    /// GNSS source (`ros2:TOPIC`, `nmea-serial:DEV@BAUD`, `nmea-tcp:HOST:PORT`, `nmea-udp:PORT`,
    /// `gpsd:HOST[:PORT]`, or "").
    #[arg(long, value_name = "SPEC")]
    pub gnss: Option<String>,
    /// Heading source (`ros2:TOPIC`, geometry_msgs/QuaternionStamped, or "").
    #[arg(long, value_name = "SPEC")]
    pub heading: Option<String>,
    /// Base command sink (`ros2:TOPIC`, or "" to never drive).
    #[arg(long, value_name = "SPEC")]
    pub cmd_vel: Option<String>,
    /// A navigation computer that follows waypoint lists itself (`orpheus-udp:HOST:PORT`):
    /// goals and route repeats go to it as waypoint lists and edits (methods.md §7); `cmd_vel`
    /// then carries only the operator's driving.
    #[arg(long, value_name = "SPEC")]
    pub nav_computer: Option<String>,
    /// Print every GNSS fix the agent takes as a JSON line on stdout (`{"fix": {...}}`).
    #[arg(long)]
    pub print_fixes: bool,
    /// ROS 2 key form: `bridge` (zenoh-bridge-ros2dds) or `rmw` (rmw_zenoh).
    #[arg(long, value_name = "FORM")]
    pub ros2_keys: Option<String>,
    /// ROS 2 namespace of the robot's topics.
    #[arg(long, value_name = "NS")]
    pub ros2_namespace: Option<String>,
    /// ROS_DOMAIN_ID (rmw form).
    #[arg(long, value_name = "ID")]
    pub ros2_domain_id: Option<u32>,
    /// Zenoh endpoint of the robot's ROS 2 side (the bridge or rmw_zenoh's router).
    #[arg(long, value_name = "ENDPOINT")]
    pub ros2_connect: Vec<String>,
    /// The map frame's datum `LAT,LON,H` (degrees, metres above the ellipsoid); default: the
    /// first RTK fix. Robots sharing a datum share one map frame.
    #[arg(long, value_name = "LAT,LON,H", allow_hyphen_values = true)]
    pub datum: Option<String>,
    /// Stop when the parent process exits (how `operator-station demo` runs its robots).
    #[arg(long)]
    pub exit_with_parent: bool,
    /// Recording (`--mcap PATH`, `--mcap-split-mb`, `--mcap-split-s`).
    #[command(flatten)]
    pub record: crate::record::McapArgs,
    /// Replay a recording (an MCAP file or folder of one, or a ROS 2 bag: MCAP or `.db3`) through
    /// the runtime instead of running on sensors; the report is the last line. The outputs go to a
    /// station only with --connect or --zenoh.
    #[arg(long, value_name = "FILE")]
    pub replay: Option<PathBuf>,
    /// Replay at this multiple of the recorded time.
    #[arg(long, value_name = "X", default_value_t = 1.0, requires = "replay")]
    pub speed: f64,
    /// Replay as fast as the CPU allows.
    #[arg(long, requires = "replay", conflicts_with = "speed")]
    pub as_fast_as_possible: bool,
}

/// One input's spec, checked.
fn spec(name: &str, cli: &Option<String>, file: &str) -> anyhow::Result<Option<SourceSpec>> {
    let s = cli.as_deref().unwrap_or(file).trim();
    if s.is_empty() {
        return Ok(None);
    }
    let spec = SourceSpec::parse(s).with_context(|| format!("--{name}"))?;
    if spec == SourceSpec::Sim {
        anyhow::bail!(
            "--{name} sim: run the world as hardware with `robot-agent sim --scenario F --serve-ros2` \
             and point `run` at its topics (the defaults match)"
        );
    }
    Ok(Some(spec))
}

/// What a `ros2:` LiDAR topic carries, from `--lidar-msg` / `[io] lidar_msg`.
fn lidar_msg(s: &str) -> anyhow::Result<Ros2Input> {
    match s.trim() {
        "PointCloud2" | "sensor_msgs/msg/PointCloud2" => Ok(Ros2Input::Lidar),
        "VelodyneScan" | "velodyne_msgs/msg/VelodyneScan" => Ok(Ros2Input::VelodynePackets),
        other => anyhow::bail!(
            "--lidar-msg {other:?}: PointCloud2 (sensor_msgs) or VelodyneScan (velodyne_msgs)"
        ),
    }
}

fn parse_datum(s: &str) -> anyhow::Result<Datum> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--datum {s:?}: want LAT,LON,H in degrees and metres"))?;
    anyhow::ensure!(v.len() == 3, "--datum {s:?}: want LAT,LON,H");
    anyhow::ensure!(
        v[0].is_finite() && (-90.0..=90.0).contains(&v[0]),
        "--datum: latitude {} out of range -90..90 (LAT comes first)",
        v[0]
    );
    anyhow::ensure!(
        v[1].is_finite() && (-180.0..=180.0).contains(&v[1]),
        "--datum: longitude {} out of range -180..180",
        v[1]
    );
    anyhow::ensure!(v[2].is_finite(), "--datum: height must be finite");
    Ok(Datum {
        lat_deg: v[0],
        lon_deg: v[1],
        h_m: v[2],
    })
}

/// Raises `stop` on SIGINT or SIGTERM (on its own thread).
pub fn stop_on_signals(stop: Arc<AtomicBool>) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            rt.block_on(async {
                #[cfg(unix)]
                {
                    use tokio::signal::unix::{signal, SignalKind};
                    let (Ok(mut int), Ok(mut term)) = (
                        signal(SignalKind::interrupt()),
                        signal(SignalKind::terminate()),
                    ) else {
                        tracing::warn!("cannot watch SIGINT/SIGTERM");
                        return;
                    };
                    tokio::select! {
                        _ = int.recv() => tracing::info!("SIGINT: stopping"),
                        _ = term.recv() => tracing::info!("SIGTERM: stopping"),
                    }
                }
                #[cfg(not(unix))]
                {
                    let _ = tokio::signal::ctrl_c().await;
                }
                stop.store(true, Ordering::Relaxed);
            })
        })?;
    Ok(())
}

/// Runs `robot-agent run`.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let robot_file = args
        .config
        .clone()
        .unwrap_or_else(|| default_config_dir().join("robot.toml"));
    anyhow::ensure!(
        robot_file.is_file() || args.config.is_none(),
        "--config {}: no such file",
        robot_file.display()
    );
    let dir = robot_file
        .parent()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("."));
    let mut cfg = load_agent_config_with(&dir, &robot_file)
        .with_context(|| format!("loading configuration from {}", dir.display()))?;
    let run_file = load_run_file(&robot_file)?;
    let limits = run_file.runtime.limits()?;
    let io: IoConfig = run_file.io;
    if let Some(d) = &args.datum {
        cfg.datum = Some(parse_datum(d)?);
    }
    let robot = RobotId::new(args.robot.clone()).map_err(|e| anyhow::anyhow!("--robot: {e}"))?;
    let tls = match &args.pki {
        Some(dir) => Some(secure::robot_files(dir, &robot)?),
        None => None,
    };
    let connect = if args.connect.is_empty() && args.zenoh.is_none() && tls.is_some() {
        vec![crate::bus::DEFAULT_STATION_ENDPOINT.replacen(
            "tcp/",
            &format!("{}/", common::security::SECURE_SCHEME),
            1,
        )]
    } else {
        args.connect.clone()
    };
    let station = ZenohSettings {
        file: args.zenoh.clone(),
        connect,
        tls: tls.clone(),
        ..ZenohSettings::default()
    };
    let mut bus = BusConfig::new(robot.clone());
    bus.uplink = run_file.bus.uplink(args.uplink_budget_kbps)?;
    if args.zenoh.is_some() || !args.connect.is_empty() || tls.is_some() {
        bus.zenoh = station.clone();
    }
    // Refused endpoints (plain off loopback, or not tls/ with --pki) are reported before any
    // source is opened.
    bus.zenoh.to_config()?;

    let record = args.record.options(&dir, &robot_file)?;
    if let Some(path) = &args.replay {
        return replay(&args, path, cfg, limits, &io, bus, record);
    }
    let mut lidar = spec("lidar", &args.lidar, &io.lidar)?;
    let depth = spec("depth", &args.depth, &io.depth)?;
    let odom = spec("odom", &args.odom, &io.odom)?;
    let imu = spec("imu", &args.imu, &io.imu)?;
    let gnss = spec("gnss", &args.gnss, &io.gnss)?;
    let heading = spec("heading", &args.heading, &io.heading)?;
    let mut cmd_vel = spec("cmd-vel", &args.cmd_vel, &io.cmd_vel)?;
    let mut nav_computer = spec("nav-computer", &args.nav_computer, &io.nav_computer)?;
    let lidar_input = lidar_msg(args.lidar_msg.as_deref().unwrap_or(&io.lidar_msg))?;
    if args.no_lidar {
        anyhow::ensure!(
            args.lidar.as_deref().is_none_or(|s| s.trim().is_empty()),
            "--no-lidar and --lidar: choose one"
        );
        if args.cmd_vel.is_some() || args.nav_computer.is_some() {
            tracing::warn!("--no-lidar: the base is never driven");
        }
        (lidar, cmd_vel, nav_computer) = (None, None, None);
    } else {
        anyhow::ensure!(
            lidar.is_some(),
            "no LiDAR source: give --lidar ros2:TOPIC or vlp16-udp:PORT (or set [io] lidar), \
             or --no-lidar to bring up the other sensors without one"
        );
    }

    let uses_ros2 = [&lidar, &depth, &odom, &imu, &gnss, &heading, &cmd_vel]
        .iter()
        .any(|s| matches!(s, Some(SourceSpec::Ros2 { .. })));
    let link = if uses_ros2 {
        let form: KeyForm = args
            .ros2_keys
            .as_deref()
            .unwrap_or(&io.ros2_keys)
            .parse()
            .map_err(|e: String| anyhow::anyhow!("--ros2-keys: {e}"))?;
        let graph = Ros2Graph {
            form,
            domain_id: args.ros2_domain_id.unwrap_or(io.ros2_domain_id),
            namespace: args
                .ros2_namespace
                .clone()
                .unwrap_or_else(|| io.ros2_namespace.clone()),
        };
        let connect = if args.ros2_connect.is_empty() {
            io.ros2_connect.clone()
        } else {
            args.ros2_connect.clone()
        };
        anyhow::ensure!(
            !(connect.is_empty() && tls.is_some()),
            "with --pki the station link is TLS under the robot's access rules, which carry no \
             ROS 2 topics: give the ROS 2 side its own endpoint (--ros2-connect, or [io] \
             ros2_connect), e.g. tcp/127.0.0.1:7447 for a bridge on the robot"
        );
        let zenoh = if connect.is_empty() {
            bus.zenoh.clone()
        } else {
            ZenohSettings {
                connect,
                ..ZenohSettings::default()
            }
        };
        let node = format!("terranav_{}", robot.as_str().replace('-', "_"));
        Some(Ros2Link::open(&zenoh, graph, &node).context("joining the robot's ROS 2 graph")?)
    } else {
        None
    };

    let lidar_mount = cfg.profile.lidar.isometry();
    let depth_mount = cfg.profile.depth_camera.isometry();
    let mut sources: Vec<SourceStart> = Vec::new();
    let mut inputs: Vec<Topic> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    let ros = |what: Ros2Input, topic: &str, mount| -> anyhow::Result<SourceStart> {
        link.as_ref()
            .expect("ROS 2 link opened")
            .source(what, topic, mount)
    };
    let only_ros2 = |name: &str, s: &SourceSpec| {
        anyhow::anyhow!("--{name} {s}: only ros2:TOPIC is supported for this input")
    };
    if let Some(s) = &lidar {
        sources.push(match s {
            SourceSpec::Ros2 { topic } => ros(lidar_input, topic, lidar_mount)?,
            SourceSpec::Vlp16Udp { port } => {
                crate::run::robot::vlp16_udp(*port, Default::default())
            }
            other => anyhow::bail!("--lidar {other}: use ros2:TOPIC or vlp16-udp:PORT"),
        });
        inputs.push(Topic::Lidar);
        names.push(format!("lidar={s}"));
    }
    for (name, what, spec, mount, topic_kind) in [
        ("depth", Ros2Input::Depth, &depth, depth_mount, Topic::Depth),
        ("odom", Ros2Input::Odom, &odom, lidar_mount, Topic::Odom),
        ("imu", Ros2Input::Imu, &imu, lidar_mount, Topic::Imu),
        (
            "heading",
            Ros2Input::Heading,
            &heading,
            lidar_mount,
            Topic::Heading,
        ),
    ] {
        if let Some(s) = spec {
            sources.push(match s {
                SourceSpec::Ros2 { topic } => ros(what, topic, mount)?,
                other => return Err(only_ros2(name, other)),
            });
            inputs.push(topic_kind);
            names.push(format!("{name}={s}"));
        }
    }
    if let Some(s) = &gnss {
        sources.push(match s {
            SourceSpec::Ros2 { topic } => ros(Ros2Input::Fix, topic, lidar_mount)?,
            other => crate::run::gnss_sources::source(other)
                .with_context(|| format!("--gnss {other}: not a GNSS source"))?,
        });
        inputs.push(Topic::Gnss);
        names.push(format!("gnss={s}"));
    }
    let manual: Box<dyn Base> = match &cmd_vel {
        Some(SourceSpec::Ros2 { topic }) => {
            link.as_ref().expect("ROS 2 link opened").base(topic)?
        }
        Some(other) => anyhow::bail!("--cmd-vel {other}: use ros2:TOPIC (or \"\" to never drive)"),
        None => {
            if nav_computer.is_none() {
                tracing::warn!("no --cmd-vel: the base is never driven");
            }
            Box::new(NoBase)
        }
    };
    let base: Box<dyn Base> = match &nav_computer {
        Some(SourceSpec::OrpheusUdp { host, port }) => {
            names.push(format!("nav-computer=orpheus-udp:{host}:{port}"));
            Box::new(NavComputerBase::connect(host, *port, manual)?)
        }
        Some(other) => anyhow::bail!("--nav-computer {other}: use orpheus-udp:HOST:PORT"),
        None => manual,
    };

    let stop = Arc::new(AtomicBool::new(false));
    stop_on_signals(stop.clone())?;
    if args.exit_with_parent {
        crate::cli::mission::watch_parent(stop.clone());
    }
    tracing::info!(
        "robot {robot} running: {}; station {}",
        names.join(", "),
        if bus.zenoh.connect.is_empty() {
            "default endpoint".to_string()
        } else {
            bus.zenoh.connect.join(",")
        }
    );
    let summary = run_robot(
        RobotRun {
            agent: cfg,
            limits,
            robot: robot.as_str().to_string(),
            bus,
            inputs,
            sources,
            base,
            source_name: names.join(" "),
            print_fixes: args.print_fixes,
            record,
        },
        stop,
    )?;
    drop(link);
    println!("{summary}");
    Ok(())
}

/// `run --replay`.
fn replay(
    args: &RunArgs,
    path: &std::path::Path,
    cfg: agent::AgentConfig,
    limits: crate::runtime::RuntimeLimits,
    io: &IoConfig,
    bus: BusConfig,
    record: Option<crate::record::RecordOptions>,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.speed.is_finite() && args.speed > 0.0,
        "--speed must be > 0"
    );
    // The bag topics the robot's specs name.
    let topic = |name: &str, cli: &Option<String>, file: &str| -> anyhow::Result<Option<String>> {
        Ok(match spec(name, cli, file)? {
            Some(SourceSpec::Ros2 { topic }) => Some(topic),
            _ => None,
        })
    };
    let topics = crate::record::rosbag::BagTopics {
        lidar: topic("lidar", &args.lidar, &io.lidar)?,
        depth: topic("depth", &args.depth, &io.depth)?,
        odom: topic("odom", &args.odom, &io.odom)?,
        imu: topic("imu", &args.imu, &io.imu)?,
        fix: topic("gnss", &args.gnss, &io.gnss)?,
        heading: topic("heading", &args.heading, &io.heading)?,
    };
    let stop = Arc::new(AtomicBool::new(false));
    stop_on_signals(stop.clone())?;
    let report = crate::record::replay::run_replay(
        crate::record::replay::ReplayOptions {
            path: path.to_path_buf(),
            speed: (!args.as_fast_as_possible).then_some(args.speed),
            config: (cfg, limits),
            override_config: args.config.is_some(),
            robot: args.robot.clone(),
            topics,
            bus: (args.zenoh.is_some() || !args.connect.is_empty()).then_some(bus),
            record,
        },
        stop,
    )?;
    if report.digest_match == Some(false) {
        tracing::warn!("the replay's digest differs from the recording's");
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

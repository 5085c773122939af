//! `robot-agent`: the terranav robot agent and its tools.

use clap::{Parser, Subcommand};
use robot_agent::cli;

/// terranav robot agent: sensing, SLAM, traversability mapping, planning, control and missions,
/// on a real robot or in the built-in simulated world.
#[derive(Debug, Parser)]
#[command(name = "robot-agent", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Benchmarks: the whole agent per sweep (`bench pipeline`).
    Bench(cli::bench::BenchArgs),
    /// GNSS tools: decode NMEA-0183 logs.
    Gnss(cli::gnss::GnssArgs),
    /// Geodesy: WGS-84 geodetic / ECEF / ENU conversions.
    Geo(cli::geo::GeoArgs),
    /// LiDAR tools: decode Velodyne VLP-16 packets (pcap, ROS 2 bag) into PCD scans.
    Lidar(cli::lidar::LidarArgs),
    /// Run the agent on a robot: ROS 2 over Zenoh or native drivers in, cmd_vel out, until SIGINT/SIGTERM.
    Run(Box<cli::run::RunArgs>),
    /// Run a simulated robot in the built-in world (live on the bus, or headless to a report).
    Sim(Box<cli::sim::SimArgs>),
    /// SLAM tools: evaluate ICP SLAM on a recorded sequence.
    Slam(cli::slam::SlamArgs),
    /// Traversability mapping tools: evaluate, replay and render maps.
    Map(cli::map::MapArgs),
    /// Planning tools: benchmark A* on Moving AI maps.
    Plan(cli::plan::PlanArgs),
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn")),
        )
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Bench(a) => cli::bench::run(a),
        Command::Gnss(a) => cli::gnss::run(a),
        Command::Geo(a) => cli::geo::run(a),
        Command::Lidar(a) => cli::lidar::run(a),
        Command::Run(a) => cli::run::run(*a),
        Command::Sim(a) => cli::sim::run(*a),
        Command::Slam(a) => cli::slam::run(a),
        Command::Map(a) => cli::map::run(a),
        Command::Plan(a) => cli::plan::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("robot-agent: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

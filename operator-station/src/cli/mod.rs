//! Command line: `serve`, `demo`, and scripted use (`robots`, `goal`, `stop`, `export`).
//! `robots`, `goal` and `stop` act directly over Zenoh (no station needed); exports read the
//! station's database. `bench` measures merge throughput and pose latency.

pub mod bench;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use common::command::{check_goal, CommandLimits, RobotContext};
use common::keys::{self, RobotId, Topic};
use common::msg::{self, GoalCmd, GoalTarget, Session, StopCmd};
use zenoh::query::ConsolidationMode;

use crate::api::{self, AppState};
use crate::station::{self, Station, StationOptions, DEFAULT_LISTEN_ENDPOINT};

/// `operator-station`.
#[derive(Debug, Parser)]
#[command(
    name = "operator-station",
    version,
    about = "terranav operator station"
)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub cmd: Cmd,
}

/// Zenoh options shared by the subcommands.
#[derive(Debug, Clone, clap::Args)]
pub struct ZenohArgs {
    /// Zenoh json5 config file (e.g. config/zenoh/station.json5).
    #[arg(long)]
    pub zenoh: Option<PathBuf>,
    /// Zenoh endpoint to listen on (serve/demo) [default: tcp/127.0.0.1:7447].
    #[arg(long = "zenoh-listen")]
    pub zenoh_listen: Option<String>,
    /// Zenoh endpoint to connect to (e.g. a router, or for CLI commands the station).
    #[arg(long)]
    pub connect: Option<String>,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Run the station: Zenoh, merged map, database, HTTP API and UI.
    Serve(ServeArgs),
    /// Station plus N simulated robots (child processes), all on loopback.
    Demo(DemoArgs),
    /// List robots seen on the bus (liveliness + sessions), as JSON lines.
    Robots(ClientArgs),
    /// Send a goal to a robot.
    Goal(GoalArgs),
    /// Stop a robot.
    Stop(StopArgs),
    /// Export from the database.
    Export(ExportArgs),
    /// Benchmarks: merge throughput and pose latency on loopback, with same-run baselines.
    Bench(bench::BenchArgs),
}

/// `serve` options.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Zenoh options.
    #[command(flatten)]
    pub z: ZenohArgs,
    /// HTTP listen address (127.0.0.1 by default; anything else requires --token).
    #[arg(long)]
    pub listen: Option<SocketAddr>,
    /// HTTP port on 127.0.0.1 (when --listen is not given).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Database file.
    #[arg(long, default_value = "terranav-station.sqlite")]
    pub db: PathBuf,
    /// Bearer token required on every API request.
    #[arg(long)]
    pub token: Option<String>,
    /// Directory of the web UI (default: found next to the binary or in the working directory).
    #[arg(long)]
    pub web: Option<PathBuf>,
    /// Operator options shared with `demo`.
    #[command(flatten)]
    pub ops: OpsArgs,
}

/// Options of the operator's day, shared by `serve` and `demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct OpsArgs {
    /// Background map drawn under the traversability map: a folder of {z}/{x}/{y}.png|jpg
    /// tiles (XYZ; TMS with gdal2tiles' tilemapresource.xml) or an MBTiles file. Served
    /// locally; nothing is fetched from the network.
    #[arg(long, value_name = "PATH")]
    pub basemap: Option<PathBuf>,
    /// A robot on a mission that has not come 0.5 m closer to its goal for this long raises a
    /// "stuck" alert, seconds.
    #[arg(long, default_value_t = 30.0)]
    pub stuck_after_s: f64,
}

impl OpsArgs {
    fn alerts(&self) -> anyhow::Result<crate::alerts::AlertConfig> {
        if !(self.stuck_after_s.is_finite() && self.stuck_after_s > 0.0) {
            bail!("--stuck-after-s must be a positive number of seconds");
        }
        Ok(crate::alerts::AlertConfig {
            stuck_after_s: self.stuck_after_s,
            ..crate::alerts::AlertConfig::default()
        })
    }

    fn basemap(&self) -> anyhow::Result<Option<std::sync::Arc<crate::basemap::Basemap>>> {
        self.basemap
            .as_deref()
            .map(|p| {
                let b = crate::basemap::Basemap::open(p)?;
                let i = b.info();
                eprintln!(
                    "basemap {}: {} tiles, zoom {}-{} ({})",
                    p.display(),
                    i.format,
                    i.min_zoom,
                    i.max_zoom,
                    i.scheme
                );
                Ok(std::sync::Arc::new(b))
            })
            .transpose()
    }
}

/// `demo` options.
#[derive(Debug, Clone, clap::Args)]
pub struct DemoArgs {
    /// Number of simulated robots.
    #[arg(long, default_value_t = 2)]
    pub robots: u32,
    /// Scenario file for the simulated world.
    #[arg(long, default_value = "config/scenarios/park.toml")]
    pub scenario: PathBuf,
    /// HTTP port.
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Zenoh port on 127.0.0.1 [default: 7447, the port `robots`, `goal` and `stop` connect
    /// to, or a free one when 7447 is taken (the demo prints it)].
    #[arg(long)]
    pub zenoh_port: Option<u16>,
    /// Database file (default: a fresh temporary one, removed when the demo ends).
    #[arg(long)]
    pub db: Option<PathBuf>,
    /// Operator options shared with `serve`.
    #[command(flatten)]
    pub ops: OpsArgs,
}

/// Options of commands that talk to robots directly.
#[derive(Debug, Clone, clap::Args)]
pub struct ClientArgs {
    /// Zenoh options.
    #[command(flatten)]
    pub z: ZenohArgs,
    /// How long to listen for robots, seconds.
    #[arg(long, default_value_t = 1.5)]
    pub wait_s: f64,
}

/// `goal` options.
#[derive(Debug, Clone, clap::Args)]
pub struct GoalArgs {
    /// Robot id.
    #[arg(long)]
    pub robot: String,
    /// Map goal `X,Y` in metres.
    #[arg(long, conflicts_with = "gnss", allow_hyphen_values = true)]
    pub xy: Option<String>,
    /// GNSS goal `LAT,LON` in degrees.
    #[arg(long, allow_hyphen_values = true)]
    pub gnss: Option<String>,
    /// Zenoh options.
    #[command(flatten)]
    pub client: ClientArgs,
}

/// `stop` options.
#[derive(Debug, Clone, clap::Args)]
pub struct StopArgs {
    /// Robot id.
    #[arg(long)]
    pub robot: String,
    /// Zenoh options.
    #[command(flatten)]
    pub client: ClientArgs,
}

/// `export` options.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportArgs {
    /// What to export.
    #[command(subcommand)]
    pub what: ExportWhat,
}

/// Export targets.
#[derive(Debug, Clone, Subcommand)]
pub enum ExportWhat {
    /// The merged map of a datum as PNG (north up).
    Map {
        /// Output PNG.
        #[arg(long)]
        png: PathBuf,
        /// Datum id (default: the one with most tiles).
        #[arg(long)]
        datum: Option<String>,
        /// Pixels per cell along each side (1 = one pixel per 0.2 m cell).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=8))]
        px_per_cell: u32,
        /// Database file.
        #[arg(long, default_value = "terranav-station.sqlite")]
        db: PathBuf,
    },
    /// A session's track as GPX.
    Track {
        /// Robot.
        #[arg(long)]
        robot: String,
        /// Session id.
        #[arg(long)]
        session: String,
        /// Output GPX.
        #[arg(long)]
        gpx: PathBuf,
        /// Database file.
        #[arg(long, default_value = "terranav-station.sqlite")]
        db: PathBuf,
    },
}

/// Entry point of the binary.
pub fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        match cli.cmd {
            Cmd::Serve(a) => serve(a).await,
            Cmd::Demo(a) => demo(a).await,
            Cmd::Robots(a) => robots(a).await,
            Cmd::Goal(a) => goal(a).await,
            Cmd::Stop(a) => stop(a).await,
            Cmd::Export(a) => export(a),
            Cmd::Bench(a) => bench::run(a).await,
        }
    })
}

/// The HTTP address: `--listen` (non-loopback requires a token) or 127.0.0.1:port.
pub fn http_addr(
    listen: Option<SocketAddr>,
    port: u16,
    token: Option<&str>,
) -> anyhow::Result<SocketAddr> {
    let addr = listen.unwrap_or_else(|| SocketAddr::from(([127, 0, 0, 1], port)));
    if !addr.ip().is_loopback() && token.map(|t| t.is_empty()).unwrap_or(true) {
        bail!(
            "refusing to listen on {addr} without --token: anyone on the network could drive the robots. \
             Give --token T (the UI is then opened as http://HOST:PORT/?token=T), or listen on 127.0.0.1"
        );
    }
    Ok(addr)
}

fn zenoh_config(z: &ZenohArgs, listen_default: Option<&str>) -> anyhow::Result<zenoh::Config> {
    let listen: Vec<String> = match (&z.zenoh_listen, listen_default, &z.zenoh) {
        (Some(l), _, _) => vec![l.clone()],
        (None, Some(d), None) => vec![d.to_string()],
        _ => vec![],
    };
    let connect: Vec<String> = z.connect.iter().cloned().collect();
    Ok(station::zenoh_config(
        z.zenoh.as_deref(),
        None,
        &listen,
        &connect,
    )?)
}

/// Runs the station until Ctrl-C.
pub async fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let addr = http_addr(a.listen, a.port, a.token.as_deref())?;
    let zc = zenoh_config(&a.z, Some(DEFAULT_LISTEN_ENDPOINT))?;
    let web = a.web.clone().or_else(api::find_web_dir);
    let running = start_station(zc, &a.db, addr, a.token.clone(), web, &a.ops).await?;
    println!(
        "operator station: http://{addr}/  (database {})",
        a.db.display()
    );
    tokio::signal::ctrl_c().await.ok();
    running.stop().await;
    Ok(())
}

/// A station with its HTTP server.
pub struct Running {
    /// The station.
    pub station: Station,
    server: tokio::task::JoinHandle<()>,
}

impl Running {
    /// Stops the HTTP server and the station (draining the store).
    pub async fn stop(self) {
        self.server.abort();
        self.station.stop().await;
    }
}

/// Starts the station and its HTTP server.
pub async fn start_station(
    zc: zenoh::Config,
    db: &Path,
    addr: SocketAddr,
    token: Option<String>,
    web: Option<PathBuf>,
    ops: &OpsArgs,
) -> anyhow::Result<Running> {
    let alerts = ops.alerts()?;
    let basemap = ops.basemap()?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("bind HTTP {addr}"))?;
    let station = Station::start(StationOptions {
        zenoh: zc,
        db: db.to_path_buf(),
        alerts,
    })
    .await
    .context("start the station")?;
    if web.is_none() {
        tracing::warn!("web UI directory not found: serving the API only");
    }
    let app = api::router(
        AppState {
            inner: station.inner.clone(),
            token,
            basemap,
        },
        web,
    );
    let server = tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, app).await {
            tracing::error!("http server: {e}");
        }
    });
    Ok(Running { station, server })
}

/// Installs the UI's npm dependencies when missing (first run); returns a note when it could not.
fn ensure_web_deps(web: &Path) -> Option<String> {
    if web.join("node_modules/leaflet").is_dir() {
        return None;
    }
    let npm_ok = Command::new("npm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !npm_ok {
        return Some("npm not found: the UI is served without the map library (install Node.js/npm, then `npm ci --prefix web`)".into());
    }
    eprintln!(
        "first run: installing the web UI's dependencies (npm ci --prefix {}) ...",
        web.display()
    );
    let ok = Command::new("npm")
        .args(["ci", "--no-audit", "--no-fund", "--prefix"])
        .arg(web)
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if ok {
        None
    } else {
        Some("npm ci failed: the UI is served without the map library".into())
    }
}

/// The robot-agent binary: next to this executable, else on PATH.
pub fn robot_agent_bin() -> PathBuf {
    if let Ok(exe) = std::env::current_exe() {
        if let Some(dir) = exe.parent() {
            let p = dir.join(format!("robot-agent{}", std::env::consts::EXE_SUFFIX));
            if p.is_file() {
                return p;
            }
        }
    }
    PathBuf::from("robot-agent")
}

/// The demo's robot processes, each with what it is (`husky-1 world`).
struct Children(Vec<(String, Child)>);

impl Drop for Children {
    fn drop(&mut self) {
        for (_, c) in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Resolves on Ctrl-C, and on Unix on SIGTERM or SIGHUP too (a `kill`, a closed terminal), so
/// the demo stops its robots the same way for each.
async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let (Ok(mut term), Ok(mut hup)) = (
            signal(SignalKind::terminate()),
            signal(SignalKind::hangup()),
        ) else {
            let _ = tokio::signal::ctrl_c().await;
            return;
        };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
            _ = hup.recv() => {}
        }
    }
    #[cfg(not(unix))]
    let _ = tokio::signal::ctrl_c().await;
}

/// One demo robot the way a real one runs: the simulated world serving its sensors as ROS 2
/// topics on its own Zenoh endpoint (`robot-agent sim --serve-ros2`, the robot's "hardware"),
/// and `robot-agent run` on those topics, connected to the station. The agent takes the world's
/// datum so every robot maps in one frame, as robots sharing a site datum do.
fn start_robot(
    agent: &Path,
    scenario: &Path,
    robot: &str,
    seed: u32,
    start: &str,
    station_endpoint: &str,
    children: &mut Children,
) -> anyhow::Result<()> {
    use std::io::BufRead;
    let hw_port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let hw_endpoint = format!("tcp/127.0.0.1:{hw_port}");
    let spawn_err = || {
        format!(
            "start {} (build it with cargo build --release --bins)",
            agent.display()
        )
    };
    let mut world = Command::new(agent)
        .arg("sim")
        .arg("--scenario")
        .arg(scenario)
        .args([
            "--serve-ros2",
            "--listen",
            &hw_endpoint,
            "--seed",
            &seed.to_string(),
        ])
        .arg(format!("--start={start}"))
        // A station killed outright (SIGKILL, out of memory) never runs `Children`'s drop;
        // its robots would go on simulating and publishing with nobody to stop them.
        .arg("--exit-with-parent")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .with_context(spawn_err)?;
    // The world's first line names its datum; the rest (its truth, for tests) is drained.
    let out = world.stdout.take().context("world stdout")?;
    children.0.push((format!("{robot} world"), world));
    let mut lines = std::io::BufReader::new(out).lines();
    let first = lines
        .next()
        .context("the simulated world exited before it started")??;
    std::thread::spawn(move || for _ in lines.map_while(Result::ok) {});
    let datum = serde_json::from_str::<serde_json::Value>(&first)
        .ok()
        .and_then(|v| v["datum"].as_str().map(str::to_owned))
        .with_context(|| format!("the world's first line names no datum: {first}"))?;
    let run = Command::new(agent)
        .args(["run", "--robot", robot, "--connect", station_endpoint])
        .args(["--ros2-connect", &hw_endpoint, "--heading", "ros2:heading"])
        .args(["--datum", &datum, "--exit-with-parent"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .with_context(spawn_err)?;
    children.0.push((format!("{robot} agent"), run));
    Ok(())
}

/// Station plus simulated robots until Ctrl-C (or SIGTERM / SIGHUP).
pub async fn demo(a: DemoArgs) -> anyhow::Result<()> {
    let addr = http_addr(None, a.port, None)?;
    let mut zport = demo_zenoh_port(a.zenoh_port)?;
    // The temporary folder (only when no --db is given) goes when the demo ends, however it
    // ends short of SIGKILL.
    let tmp = match &a.db {
        Some(_) => None,
        None => Some(TempDir(tempfile_dir()?)),
    };
    let db = match (&a.db, &tmp) {
        (Some(d), _) => d.clone(),
        (None, Some(t)) => t.0.join("demo.sqlite"),
        (None, None) => unreachable!("a temporary folder when no --db"),
    };
    let web = api::find_web_dir();
    if let Some(w) = &web {
        if let Some(note) = ensure_web_deps(w) {
            eprintln!("{note}");
        }
    }
    let zc = |port: u16| station::zenoh_config(None, None, &[format!("tcp/127.0.0.1:{port}")], &[]);
    let running = match start_station(zc(zport)?, &db, addr, None, web.clone(), &a.ops).await {
        Ok(r) => r,
        // Another program took 7447 between the check and the bind: any free port will do.
        Err(e) if a.zenoh_port.is_none() && zport == DEFAULT_ZENOH_PORT => {
            tracing::warn!("zenoh on port {zport}: {e:#}; trying a free port");
            zport = demo_zenoh_port(Some(0))?;
            start_station(zc(zport)?, &db, addr, None, web, &a.ops).await?
        }
        Err(e) => return Err(e),
    };
    let endpoint = format!("tcp/127.0.0.1:{zport}");
    let agent = robot_agent_bin();
    let scenario = if a.scenario.is_file() {
        a.scenario.clone()
    } else {
        // Relative to the workspace when run from elsewhere.
        let alt = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(&a.scenario);
        if alt.is_file() {
            alt
        } else {
            a.scenario.clone()
        }
    };
    let mut children = Children(Vec::new());
    for i in 1..=a.robots {
        let robot = format!("husky-{i}");
        // Distinct start poses: a row 4 m apart, all facing east.
        let start = format!("{},{},0", 0.0, (i as f64 - 1.0) * 4.0);
        start_robot(
            &agent,
            &scenario,
            &robot,
            i,
            &start,
            &endpoint,
            &mut children,
        )?;
    }
    println!(
        "terranav demo: open http://{addr}/  ({} simulated robots; Ctrl-C to stop)",
        a.robots
    );
    println!("  zenoh    {endpoint}");
    if zport == DEFAULT_ZENOH_PORT {
        println!("  CLI      operator-station robots | goal --robot husky-1 --xy X,Y | stop --robot husky-1");
    } else {
        println!("  CLI      (port 7447 was taken) operator-station robots --connect {endpoint}");
    }
    println!(
        "  database {}{}",
        db.display(),
        if tmp.is_some() {
            " (temporary: removed when the demo ends; give --db FILE to keep it)"
        } else {
            ""
        }
    );
    let mut tick = tokio::time::interval(Duration::from_millis(500));
    let stop = stop_signal();
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => break,
            _ = tick.tick() => {
                children.0.retain_mut(|(name, c)| match c.try_wait() {
                    Ok(Some(status)) => {
                        eprintln!("robot {name} exited with {status}");
                        false
                    }
                    _ => true,
                });
            }
        }
    }
    drop(children);
    running.stop().await;
    drop(tmp);
    Ok(())
}

/// The Zenoh port `robots`, `goal` and `stop` connect to by default.
pub const DEFAULT_ZENOH_PORT: u16 = 7447;

/// The demo's Zenoh port: the one asked for, else 7447 when free (so the CLI commands find the
/// robots without options), else any free one.
fn demo_zenoh_port(asked: Option<u16>) -> anyhow::Result<u16> {
    if let Some(p) = asked.filter(|p| *p != 0) {
        return Ok(p);
    }
    if asked.is_none() && std::net::TcpListener::bind(("127.0.0.1", DEFAULT_ZENOH_PORT)).is_ok() {
        return Ok(DEFAULT_ZENOH_PORT);
    }
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// A folder removed when dropped.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Err(e) = std::fs::remove_dir_all(&self.0) {
            eprintln!("could not remove {}: {e}", self.0.display());
        }
    }
}

fn tempfile_dir() -> anyhow::Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("terranav-demo-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}

/// A short-lived Zenoh session for CLI commands (connects to the station's endpoint by default).
async fn client_session(z: &ZenohArgs) -> anyhow::Result<zenoh::Session> {
    let mut z = z.clone();
    if z.zenoh.is_none() && z.connect.is_none() {
        z.connect = Some(DEFAULT_LISTEN_ENDPOINT.to_string());
    }
    let zc = zenoh_config(&z, None)?;
    zenoh::open(zc)
        .await
        .map_err(|e| anyhow::anyhow!("zenoh: {e}"))
}

async fn alive_robots(s: &zenoh::Session, wait: Duration) -> anyhow::Result<Vec<String>> {
    let replies = s
        .liveliness()
        .get(keys::all_alive())
        .timeout(wait)
        .await
        .map_err(|e| anyhow::anyhow!("liveliness query: {e}"))?;
    let mut out = Vec::new();
    while let Ok(r) = replies.recv_async().await {
        if let Ok(sample) = r.result() {
            if let Ok((id, Topic::Alive)) = keys::parse(sample.key_expr().as_str()) {
                out.push(id.to_string());
            }
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}

async fn robots(a: ClientArgs) -> anyhow::Result<()> {
    let s = client_session(&a.z).await?;
    // Give the session time to connect and learn the routes.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let wait = Duration::from_secs_f64(a.wait_s.max(0.2));
    let alive = alive_robots(&s, wait).await?;
    if alive.is_empty() {
        eprintln!(
            "no robots answered on {} within {:.1} s (a demo on another Zenoh port? `operator-station demo` prints it; give --connect tcp/127.0.0.1:PORT)",
            a.z.connect.as_deref().unwrap_or(DEFAULT_LISTEN_ENDPOINT),
            wait.as_secs_f64()
        );
    }
    for id in alive {
        let rid = RobotId::new(id.clone())?;
        let mut session: Option<Session> = None;
        if let Ok(replies) = s
            .get(keys::key(&rid, Topic::Session))
            .consolidation(ConsolidationMode::None)
            .timeout(wait)
            .await
        {
            while let Ok(r) = replies.recv_async().await {
                if let Ok(sample) = r.result() {
                    session = msg::decode(&sample.payload().to_bytes()).ok();
                }
            }
        }
        println!(
            "{}",
            serde_json::json!({"robot": id, "online": true, "session": session})
        );
    }
    let _ = s.close().await;
    Ok(())
}

fn parse_pair(s: &str) -> anyhow::Result<(f64, f64)> {
    let (a, b) = s.split_once(',').context("expected two numbers A,B")?;
    let a: f64 = a.trim().parse().context("first number")?;
    let b: f64 = b.trim().parse().context("second number")?;
    if !(a.is_finite() && b.is_finite()) {
        bail!("numbers must be finite");
    }
    Ok((a, b))
}

/// A session that has seen `robot` online.
async fn robot_session(c: &ClientArgs, robot: &str) -> anyhow::Result<zenoh::Session> {
    let s = client_session(&c.z).await?;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let alive = alive_robots(&s, Duration::from_secs_f64(c.wait_s.max(0.2))).await?;
    if !alive.iter().any(|r| r == robot) {
        let _ = s.close().await;
        bail!(
            "robot {robot} is not online on {} (seen: {alive:?}; a demo on another Zenoh port? give --connect tcp/127.0.0.1:PORT)",
            c.z.connect.as_deref().unwrap_or(DEFAULT_LISTEN_ENDPOINT)
        );
    }
    Ok(s)
}

/// Sends one command and closes the session.
async fn put_and_close(
    s: zenoh::Session,
    rid: &RobotId,
    topic: Topic,
    payload: Vec<u8>,
) -> anyhow::Result<()> {
    let r = s
        .put(keys::key(rid, topic), payload)
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .await
        .map_err(|e| anyhow::anyhow!("zenoh put: {e}"));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let _ = s.close().await;
    r
}

async fn send_to_robot(
    c: &ClientArgs,
    robot: &str,
    topic: Topic,
    payload: Vec<u8>,
) -> anyhow::Result<()> {
    let rid = RobotId::new(robot)?;
    let s = robot_session(c, robot).await?;
    put_and_close(s, &rid, topic, payload).await
}

/// The robot's position from one of its poses (it publishes them at 10 Hz), for the goal
/// contract; empty when none comes within a second.
async fn robot_context(s: &zenoh::Session, rid: &RobotId) -> RobotContext {
    let Ok(sub) = s.declare_subscriber(keys::key(rid, Topic::Pose)).await else {
        return RobotContext::default();
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs(1);
    while let Ok(Ok(sample)) = tokio::time::timeout_at(deadline, sub.recv_async()).await {
        if let Ok(p) = msg::decode::<msg::Pose>(&sample.payload().to_bytes()) {
            return RobotContext {
                position_m: Some((p.x_m, p.y_m)),
                lat_lon_deg: p.lat_lon_deg,
                mapped: None,
            };
        }
    }
    RobotContext::default()
}

async fn goal(a: GoalArgs) -> anyhow::Result<()> {
    let target = match (&a.xy, &a.gnss) {
        (Some(xy), None) => {
            let (x, y) = parse_pair(xy)?;
            GoalTarget::Map { x_m: x, y_m: y }
        }
        (None, Some(g)) => {
            let (lat, lon) = parse_pair(g)?;
            if !(-90.0..=90.0).contains(&lat) || !(-180.0..=180.0).contains(&lon) {
                bail!("latitude/longitude out of range");
            }
            GoalTarget::Gnss {
                lat_deg: lat,
                lon_deg: lon,
                h_m: None,
            }
        }
        _ => bail!("give --xy X,Y or --gnss LAT,LON"),
    };
    let cmd = GoalCmd {
        goal_id: (station::now_unix_ms() / 1000) as u32,
        target,
        tolerance_m: 0.0,
    };
    let rid = RobotId::new(&a.robot)?;
    let s = robot_session(&a.client, &a.robot).await?;
    // The same contract the robot and the HTTP API apply: refused here, nothing is sent.
    let ctx = robot_context(&s, &rid).await;
    if let Err(r) = check_goal(&cmd, &CommandLimits::default(), &ctx) {
        let _ = s.close().await;
        bail!("goal refused: {} [{}]", r.message, r.code.as_str());
    }
    put_and_close(s, &rid, Topic::CmdGoal, msg::encode(&cmd)).await?;
    println!(
        "{}",
        serde_json::json!({"ok": true, "robot": a.robot, "sent": cmd})
    );
    Ok(())
}

async fn stop(a: StopArgs) -> anyhow::Result<()> {
    let cmd = StopCmd {
        reason: "operator-station stop".into(),
    };
    send_to_robot(&a.client, &a.robot, Topic::CmdStop, msg::encode(&cmd)).await?;
    println!(
        "{}",
        serde_json::json!({"ok": true, "robot": a.robot, "sent": cmd})
    );
    Ok(())
}

fn export(a: ExportArgs) -> anyhow::Result<()> {
    match a.what {
        ExportWhat::Map {
            png,
            datum,
            px_per_cell,
            db,
        } => {
            let c = open_existing(&db)?;
            let datums = crate::store::datums(&c)?;
            let mut map = crate::merge::MergedMap::default();
            for (d, _, _, v, data) in crate::store::tiles(&c, datum.as_deref())? {
                let mut t = common::grid::decode_tile(&data)
                    .with_context(|| format!("stored tile of {d}"))?;
                t.version = v;
                map.restore(&d, t);
            }
            let pick = match datum {
                Some(d) => d,
                None => map
                    .datums
                    .iter()
                    .max_by_key(|(_, m)| m.tiles.len())
                    .map(|(k, _)| k.clone())
                    .context("the database has no tiles")?,
            };
            let dm = map.datums.get(&pick).with_context(|| {
                format!(
                    "no tiles for datum {pick} (datums: {:?})",
                    datums.iter().map(|d| &d.datum_id).collect::<Vec<_>>()
                )
            })?;
            let bytes = crate::merge::datum_png_scaled(dm, px_per_cell).context("empty map")?;
            std::fs::write(&png, bytes).with_context(|| format!("write {}", png.display()))?;
            println!(
                "{}",
                serde_json::json!({"datum_id": pick, "tiles": dm.tiles.len(), "bounds_m": dm.bounds_m(), "png": png})
            );
        }
        ExportWhat::Track {
            robot,
            session,
            gpx,
            db,
        } => {
            let c = open_existing(&db)?;
            let row = crate::store::session(&c, &session)?
                .with_context(|| format!("unknown session {session}"))?;
            if row.robot != robot {
                bail!("session {session} belongs to {}, not {robot}", row.robot);
            }
            let datum = crate::store::datums(&c)?
                .into_iter()
                .find(|d| d.datum_id == row.datum_id)
                .and_then(|d| Some(msg::Datum { lat_deg: d.lat_deg?, lon_deg: d.lon_deg?, h_m: d.h_m.unwrap_or(0.0) }))
                .with_context(|| format!("session {session} has no GNSS datum: a track without lat/lon cannot be GPX"))?;
            let pts = crate::store::track(&c, &session)?;
            let mut out = String::from(
                "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<gpx version=\"1.1\" creator=\"terranav\" xmlns=\"http://www.topografix.com/GPX/1/1\">\n<trk>",
            );
            out.push_str(&format!(
                "<name>{}</name><trkseg>\n",
                api::xml_escape(&format!("{robot} {session}"))
            ));
            for (t, x, y, _) in &pts {
                let g = common::geo::enu_to_lla(&datum, &nalgebra::Vector3::new(*x, *y, 0.0));
                out.push_str(&format!(
                    "<trkpt lat=\"{:.9}\" lon=\"{:.9}\"><ele>{:.3}</ele><time>{}</time></trkpt>\n",
                    g.lat_deg,
                    g.lon_deg,
                    g.h_m,
                    rfc3339(*t)
                ));
            }
            out.push_str("</trkseg></trk>\n</gpx>\n");
            std::fs::write(&gpx, out).with_context(|| format!("write {}", gpx.display()))?;
            println!(
                "{}",
                serde_json::json!({"session_id": session, "points": pts.len(), "gpx": gpx})
            );
        }
    }
    Ok(())
}

fn open_existing(db: &Path) -> anyhow::Result<rusqlite::Connection> {
    if !db.is_file() {
        bail!("database {} not found (give --db)", db.display());
    }
    Ok(crate::store::open(db)?)
}

/// Unix ms as RFC 3339 UTC.
pub fn rfc3339(t_ms: u64) -> String {
    let secs = (t_ms / 1000) as i64;
    let ms = t_ms % 1000;
    let days = secs.div_euclid(86_400);
    let sod = secs.rem_euclid(86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{ms:03}Z",
        sod / 3600,
        (sod % 3600) / 60,
        sod % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_loopback_listen_needs_a_token() {
        let any: SocketAddr = "0.0.0.0:8080".parse().unwrap();
        assert!(http_addr(Some(any), 0, None).is_err());
        assert!(http_addr(Some(any), 0, Some("")).is_err());
        assert_eq!(http_addr(Some(any), 0, Some("t")).unwrap(), any);
        assert_eq!(
            http_addr(None, 9000, None).unwrap(),
            "127.0.0.1:9000".parse().unwrap()
        );
    }

    #[test]
    fn rfc3339_is_right() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(1_700_000_000_123), "2023-11-14T22:13:20.123Z");
    }
}

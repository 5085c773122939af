//! Command line: `serve`, `demo`, and scripted use (`robots`, `goal`, `stop`, `export`).
//! `robots`, `goal` and `stop` act directly over Zenoh (no station needed); exports read the
//! station's database. `bench` measures merge throughput and pose latency (and both again over
//! TLS against plain TCP). `pki` makes the fleet's certificates; with `--pki` every Zenoh link is
//! TLS with mutual authentication, and without it anything off loopback is refused at start.

pub mod bench;
pub mod net;
pub mod pki;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use common::command::{check_goal, CommandLimits};
use common::keys::{RobotId, Topic};
use common::msg::{self, GoalCmd, GoalTarget, Session, Status, StopCmd};

use crate::api::{self, AppState};
use crate::bus::client::{self, alive_robots, robot_context, send_confirmed};
use crate::bus::confirm::{Expect, Outcome, Policy};
use crate::security::{self, RegisterWatch};
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
    /// The fleet's PKI folder (`pki init`): Zenoh over QUIC with mutual TLS authentication as
    /// the station, under the station's access rules; endpoints are then quic/ (default
    /// quic/127.0.0.1:7447; tls/ is accepted too). Without it, endpoints off loopback are refused.
    #[arg(long, value_name = "DIR", id = "pki")]
    pub pki: Option<PathBuf>,
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
    /// The fleet's certificates: init (CA and station), issue (a robot), revoke (a robot).
    Pki(pki::PkiArgs),
    /// A Zenoh router for robots and stations on other networks (no zenohd needed).
    Router(net::RouterArgs),
    /// Every tile a robot serves, written to a folder (to check a station's map against it).
    RobotTiles(net::RobotTilesArgs),
}

/// `serve` options.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Zenoh options.
    #[command(flatten)]
    pub z: ZenohArgs,
    /// HTTP listen address (127.0.0.1 by default; anything else requires --token and TLS).
    #[arg(long)]
    pub listen: Option<SocketAddr>,
    /// Serve the API and UI over TLS with this PEM certificate (chain); needs --tls-key. Off
    /// loopback without it, the fleet's station certificate (--pki) is used.
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
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
    /// Run as the read-only monitor NAME (`pki add-monitor --name NAME`): with --pki holding its
    /// certificate (its copied folder, or the fleet folder) it is a Zenoh client of the station or
    /// router given by --connect, watches everything and commands nothing (its API refuses
    /// command routes with code `monitor_read_only`; the station's and router's rules drop its
    /// puts; robots admit it to nothing).
    #[arg(long, value_name = "NAME", requires = "pki")]
    pub monitor: Option<String>,
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
    /// History period of the merged map, seconds: every tile keeps its last version of each
    /// period, so a past session can be scrubbed with the map as it was (0: keep none).
    #[arg(long, default_value_t = 60)]
    pub map_history_s: u32,
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
    /// Run it secure: the fleet's PKI folder (created with the robots' certificates when it has
    /// none), Zenoh over TLS with mutual authentication and access rules, still on loopback.
    #[arg(long, value_name = "DIR")]
    pub pki: Option<PathBuf>,
    /// Operator options shared with `serve`.
    #[command(flatten)]
    pub ops: OpsArgs,
    /// Record each robot's session to MCAP in this folder (`husky-N.mcap`).
    #[arg(long, value_name = "DIR")]
    pub record_mcap: Option<PathBuf>,
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
    /// Sending until the robot shows the goal.
    #[command(flatten)]
    pub delivery: DeliveryArgs,
}

/// How `goal` and `stop` make sure the robot took the command: it is sent again until the
/// robot's status shows it (its goal id; halted), the robot refuses it, or the sends run out.
#[derive(Debug, Clone, clap::Args)]
pub struct DeliveryArgs {
    /// Sends at most, the first included.
    #[arg(long, default_value_t = Policy::default().attempts)]
    pub attempts: u32,
    /// How long to wait for a status showing the command before sending it again, seconds.
    #[arg(long, default_value_t = Policy::default().confirm_s)]
    pub confirm_s: f64,
}

impl DeliveryArgs {
    fn policy(&self) -> Policy {
        Policy {
            attempts: self.attempts,
            confirm_s: self.confirm_s,
        }
    }
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
    /// Sending until the robot shows itself halted.
    #[command(flatten)]
    pub delivery: DeliveryArgs,
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
    /// The merged map of a datum as PNG (north up) and/or GeoTIFF (height, class and cost bands,
    /// georeferenced; needs a GNSS datum).
    Map {
        /// Output PNG.
        #[arg(long, required_unless_present = "geotiff")]
        png: Option<PathBuf>,
        /// Output GeoTIFF.
        #[arg(long)]
        geotiff: Option<PathBuf>,
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
    /// A session as MCAP (Foxglove, Lichtblick): poses, track, paths, goals, routes, and the
    /// merged map of its datum as a grid and as tiles.
    Session {
        /// Session id.
        #[arg(long)]
        session: String,
        /// Output MCAP.
        #[arg(long)]
        mcap: PathBuf,
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
            Cmd::Pki(a) => pki::run(a),
            Cmd::Router(a) => net::router(a).await,
            Cmd::RobotTiles(a) => net::robot_tiles(a).await,
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

/// The certificate and key of the HTTP server when it is to speak TLS: `--tls-cert/--tls-key`
/// when given; off loopback, else the fleet's station certificate (`--pki`); off loopback without
/// either, refused (the token would cross the network in the clear).
pub fn http_tls(
    addr: SocketAddr,
    cert: Option<&Path>,
    key: Option<&Path>,
    pki: Option<&Path>,
) -> anyhow::Result<Option<(PathBuf, PathBuf)>> {
    if let (Some(c), Some(k)) = (cert, key) {
        return Ok(Some((c.to_path_buf(), k.to_path_buf())));
    }
    if addr.ip().is_loopback() {
        return Ok(None);
    }
    match pki {
        Some(dir) => {
            let s = common::security::FleetDir::new(dir).station();
            Ok(Some((s.cert, s.key)))
        }
        None => bail!(
            "refusing to serve HTTP on {addr} without TLS: the token and every command would \
             cross the network in the clear. Give --pki DIR (the fleet's station certificate, \
             `operator-station pki init --dir DIR --host NAME`) or --tls-cert FILE --tls-key FILE"
        ),
    }
}

/// What a Zenoh session of this process does: the station listens, a CLI call connects, a
/// monitor (named) is a client of a station or router under its own certificate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role<'a> {
    Station,
    Client,
    Monitor(&'a str),
}

/// The Zenoh config of `z` for `role`: default endpoints on loopback (`quic/` with `--pki`), TLS
/// and access rules with `--pki`, and the refusal of plain endpoints off loopback.
fn zenoh_config(z: &ZenohArgs, role: Role) -> anyhow::Result<zenoh::Config> {
    let secure = z.pki.is_some();
    if let Role::Monitor(name) = role {
        let Some(dir) = &z.pki else {
            bail!("--monitor needs --pki (the monitor's certificate folder)");
        };
        if z.zenoh_listen.is_some() {
            bail!(
                "--monitor takes no --zenoh-listen: a monitor is a Zenoh client of the station or \
                 router it connects to (--connect {}/STATION:7447)",
                common::security::SECURE_SCHEME
            );
        }
        if z.connect.is_none() && z.zenoh.is_none() {
            bail!(
                "--monitor needs --connect {}/HOST:PORT: the station or router (operator-station \
                 router --pki) it watches the fleet through",
                common::security::SECURE_SCHEME
            );
        }
        let connect: Vec<String> = z.connect.iter().cloned().collect();
        let mut c = station::zenoh_config(z.zenoh.as_deref(), None, &[], &connect)?;
        security::apply_monitor(&mut c, dir, name)?;
        security::check_endpoints(&c, true)?;
        return Ok(c);
    }
    let default_ep = if secure {
        DEFAULT_LISTEN_ENDPOINT.replacen(
            "tcp/",
            &format!("{}/", common::security::SECURE_SCHEME),
            1,
        )
    } else {
        DEFAULT_LISTEN_ENDPOINT.to_string()
    };
    let listen: Vec<String> = match (&z.zenoh_listen, role, &z.zenoh) {
        (Some(l), _, _) => vec![l.clone()],
        (None, Role::Station, None) => vec![default_ep.clone()],
        _ => vec![],
    };
    let connect: Vec<String> = match (&z.connect, role, &z.zenoh) {
        (Some(c), _, _) => vec![c.clone()],
        (None, Role::Client, None) => vec![default_ep],
        _ => vec![],
    };
    let mut c = station::zenoh_config(z.zenoh.as_deref(), None, &listen, &connect)?;
    if let Some(dir) = &z.pki {
        if listen.is_empty() && z.zenoh.is_none() {
            // A secure call that only connects needs no listener (and a plain loopback one
            // would be refused).
            c.insert_json5("listen/endpoints", "[]")
                .map_err(|e| anyhow::anyhow!("zenoh config: {e}"))?;
        }
        security::apply(&mut c, dir, role == Role::Client)?;
    }
    security::check_endpoints(&c, secure)?;
    Ok(c)
}

/// Runs the station until Ctrl-C. With `--pki` it re-reads the fleet register every second and,
/// when it changed (a robot issued or revoked), re-opens its Zenoh session with the new rules.
pub async fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let addr = http_addr(a.listen, a.port, a.token.as_deref())?;
    let role = match a.monitor.as_deref() {
        Some(name) => Role::Monitor(name),
        None => Role::Station,
    };
    // A monitor's folder holds no station certificate for HTTPS: off loopback it takes
    // --tls-cert/--tls-key.
    let http_pki = match role {
        Role::Monitor(_) => None,
        _ => a.z.pki.as_deref(),
    };
    let tls = http_tls(addr, a.tls_cert.as_deref(), a.tls_key.as_deref(), http_pki)?;
    let zc = zenoh_config(&a.z, role)?;
    let web = a.web.clone().or_else(api::find_web_dir);
    let mut running = start_station(
        zc,
        &a.db,
        addr,
        a.token.clone(),
        web,
        tls.as_ref(),
        &a.ops,
        a.monitor.clone(),
    )
    .await?;
    println!(
        "operator station{}: {}://{addr}/  (database {})",
        a.monitor
            .as_deref()
            .map(|m| format!(" (monitor {m}, read-only)"))
            .unwrap_or_default(),
        if tls.is_some() { "https" } else { "http" },
        a.db.display()
    );
    // A monitor's own access is decided by the station or router it connects to (which re-reads
    // the register); it has no rules of its own to re-read.
    let mut watch = match role {
        Role::Monitor(_) => None,
        _ => a.z.pki.as_deref().map(RegisterWatch::new),
    };
    run_until_stopped(&mut running, &a.z, &mut watch, || false).await;
    running.stop().await;
    Ok(())
}

/// Waits for Ctrl-C (or SIGTERM / SIGHUP), re-opening the station's session when the register
/// watched by `watch` changes, and calling `tick` twice a second (true: stop).
async fn run_until_stopped(
    running: &mut Running,
    z: &ZenohArgs,
    watch: &mut Option<RegisterWatch>,
    tick: impl FnMut() -> bool,
) {
    let reopen = async || {
        let zc = zenoh_config(z, Role::Station)?;
        running
            .station
            .reopen(zc)
            .await
            .map_err(anyhow::Error::from)
    };
    until_stopped(Duration::from_millis(500), "Zenoh", watch, tick, reopen).await;
}

/// Waits for Ctrl-C (or SIGTERM / SIGHUP), calling `tick` every `period` (true: stop) and
/// `reopen` when the register watched by `watch` changed; a re-open that failed (the port not
/// yet free) is tried again on the next tick. `what` names the session in the log.
pub(crate) async fn until_stopped(
    period: Duration,
    what: &str,
    watch: &mut Option<RegisterWatch>,
    mut tick: impl FnMut() -> bool,
    mut reopen: impl AsyncFnMut() -> anyhow::Result<()>,
) {
    let mut interval = tokio::time::interval(period);
    let stop = stop_signal();
    tokio::pin!(stop);
    let mut reload = false;
    loop {
        tokio::select! {
            _ = &mut stop => break,
            _ = interval.tick() => {
                if tick() {
                    break;
                }
                if let Some(w) = watch.as_mut() {
                    reload |= w.changed();
                }
                if reload {
                    tracing::info!("fleet register changed: re-opening {what} with the new access rules");
                    match reopen().await {
                        Ok(()) => reload = false,
                        Err(e) => tracing::error!("re-opening {what}: {e:#}"),
                    }
                }
            }
        }
    }
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

/// Starts the station and its HTTP server (HTTPS with `tls`: certificate and key PEM files);
/// `monitor` names the read-only monitor this station runs as, if it is one.
#[allow(clippy::too_many_arguments)] // one call per way of starting (serve, demo), each a flag
pub async fn start_station(
    zc: zenoh::Config,
    db: &Path,
    addr: SocketAddr,
    token: Option<String>,
    web: Option<PathBuf>,
    tls: Option<&(PathBuf, PathBuf)>,
    ops: &OpsArgs,
    monitor: Option<String>,
) -> anyhow::Result<Running> {
    let alerts = ops.alerts()?;
    let basemap = ops.basemap()?;
    enum Http {
        Plain(tokio::net::TcpListener),
        Tls(api::tls::TlsListener),
    }
    let http = match tls {
        Some((cert, key)) => {
            let cfg = api::tls::server_config(cert, key)?;
            Http::Tls(api::tls::TlsListener::bind(addr, cfg).await?)
        }
        None => Http::Plain(
            tokio::net::TcpListener::bind(addr)
                .await
                .with_context(|| format!("bind HTTP {addr}"))?,
        ),
    };
    let station = Station::start(StationOptions {
        zenoh: zc,
        db: db.to_path_buf(),
        alerts,
        map_history_s: ops.map_history_s,
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
            role: api::Role::new(monitor),
        },
        web,
    );
    let server = tokio::spawn(async move {
        let r = match http {
            Http::Plain(l) => axum::serve(l, app).await,
            Http::Tls(l) => axum::serve(l, app).await,
        };
        if let Err(e) = r {
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

/// The demo's robot processes, each with what it is (`husky-1 world`), and whether the robots
/// record (then they are asked to stop first, so that their recordings close).
struct Children(Vec<(String, Child)>, bool);

impl Drop for Children {
    fn drop(&mut self) {
        if self.1 {
            // Recording agents are asked to stop (SIGTERM) so that they close their files with
            // summaries; those that do not within 5 s are killed (their files still read up to
            // the last closed chunk).
            for (_, c) in self.0.iter().filter(|(what, _)| what.ends_with(" agent")) {
                let _ = Command::new("kill")
                    .args(["-TERM", &c.id().to_string()])
                    .status();
            }
            let until = std::time::Instant::now() + Duration::from_secs(5);
            while std::time::Instant::now() < until
                && self
                    .0
                    .iter_mut()
                    .any(|(what, c)| what.ends_with(" agent") && matches!(c.try_wait(), Ok(None)))
            {
                std::thread::sleep(Duration::from_millis(50));
            }
        }
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
#[allow(clippy::too_many_arguments)] // one robot's launch line, each argument a flag of it
fn start_robot(
    agent: &Path,
    scenario: &Path,
    robot: &str,
    seed: u32,
    start: &str,
    (station_endpoint, pki): (&str, Option<&Path>),
    mcap: Option<PathBuf>,
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
    let mut run = Command::new(agent);
    run.args(["run", "--robot", robot, "--connect", station_endpoint]);
    if let Some(dir) = pki {
        // The robot's certificate and rules on its link to the station; its "hardware" link
        // stays plain on loopback.
        run.arg("--pki").arg(dir);
    }
    if let Some(path) = &mcap {
        run.arg("--mcap").arg(path);
    }
    let run = run
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
    let secure = a.pki.is_some();
    let scheme = if secure { "tls" } else { "tcp" };
    let robot_ids: Vec<RobotId> = (1..=a.robots)
        .map(|i| RobotId::new(format!("husky-{i}")))
        .collect::<Result<_, _>>()?;
    if let Some(dir) = &a.pki {
        crate::pki::ensure_demo_fleet(dir, &robot_ids)?;
    }
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
    let z_for = |port: u16| ZenohArgs {
        zenoh: None,
        zenoh_listen: Some(format!("{scheme}/127.0.0.1:{port}")),
        connect: None,
        pki: a.pki.clone(),
    };
    let mut z = z_for(zport);
    let started = start_station(
        zenoh_config(&z, Role::Station)?,
        &db,
        addr,
        None,
        web.clone(),
        None,
        &a.ops,
        None,
    )
    .await;
    let mut running = match started {
        Ok(r) => r,
        // Another program took 7447 between the check and the bind: any free port will do.
        Err(e) if a.zenoh_port.is_none() && zport == DEFAULT_ZENOH_PORT => {
            tracing::warn!("zenoh on port {zport}: {e:#}; trying a free port");
            zport = demo_zenoh_port(Some(0))?;
            z = z_for(zport);
            let zc = zenoh_config(&z, Role::Station)?;
            start_station(zc, &db, addr, None, web, None, &a.ops, None).await?
        }
        Err(e) => return Err(e),
    };
    let endpoint = format!("{scheme}/127.0.0.1:{zport}");
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
    let mut children = Children(Vec::new(), a.record_mcap.is_some());
    if let Some(dir) = &a.record_mcap {
        std::fs::create_dir_all(dir).with_context(|| format!("--record-mcap {}", dir.display()))?;
    }
    for (k, id) in robot_ids.iter().enumerate() {
        let (i, robot) = (k + 1, id.to_string());
        // Distinct start poses: a row 4 m apart, all facing east.
        let start = format!("{},{},0", 0.0, (i as f64 - 1.0) * 4.0);
        start_robot(
            &agent,
            &scenario,
            &robot,
            i as u32,
            &start,
            (&endpoint, a.pki.as_deref()),
            a.record_mcap
                .as_ref()
                .map(|d| d.join(format!("{robot}.mcap"))),
            &mut children,
        )?;
    }
    println!(
        "terranav demo: open http://{addr}/  ({} simulated robots; Ctrl-C to stop)",
        a.robots
    );
    println!(
        "  zenoh    {endpoint}{}",
        if secure {
            " (TLS with mutual authentication)"
        } else {
            ""
        }
    );
    let pki_arg = a
        .pki
        .as_ref()
        .map(|d| format!(" --pki {}", d.display()))
        .unwrap_or_default();
    if zport == DEFAULT_ZENOH_PORT && !secure {
        println!("  CLI      operator-station robots | goal --robot husky-1 --xy X,Y | stop --robot husky-1");
    } else {
        println!("  CLI      operator-station robots --connect {endpoint}{pki_arg}");
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
    let mut watch = a.pki.as_deref().map(RegisterWatch::new);
    run_until_stopped(&mut running, &z, &mut watch, || {
        children.0.retain_mut(|(name, c)| match c.try_wait() {
            Ok(Some(status)) => {
                eprintln!("robot {name} exited with {status}");
                false
            }
            _ => true,
        });
        false
    })
    .await;
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
    client::open(zenoh_config(z, Role::Client)?).await
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
        let session: Option<Session> = client::robot_session_msg(&s, &rid, wait).await;
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

/// Prints how a command ended (one JSON line on stdout) and turns a refusal or an unconfirmed
/// send into an error (so scripts see a non-zero exit status).
fn report_sent<T: serde::Serialize>(
    robot: &str,
    cmd: &T,
    outcome: Outcome,
    last: Option<Status>,
    shows: &str,
) -> anyhow::Result<()> {
    let last = last.unwrap_or_default();
    match outcome {
        Outcome::Taken { attempts } => {
            println!(
                "{}",
                serde_json::json!({
                    "ok": true, "robot": robot, "sent": cmd, "confirmed": true,
                    "attempts": attempts, "mode": last.mode, "mission": last.mission,
                    "reason": last.reason,
                })
            );
            Ok(())
        }
        Outcome::Refused { reason, attempts } => {
            bail!("refused by robot {robot} (after {attempts} send(s)): {reason}")
        }
        Outcome::Superseded { goal_id, attempts } => bail!(
            "robot {robot} took goal {goal_id} from another sender before any status showed this command (sent {attempts} time(s)); not sent again"
        ),
        Outcome::Unconfirmed {
            attempts,
            statuses: 0,
        } => bail!(
            "sent {attempts} time(s), but no status came from robot {robot} (is its status reaching this session?); it may or may not have taken it"
        ),
        Outcome::Unconfirmed { attempts, statuses } => {
            bail!(
                "sent {attempts} time(s); none of the robot's {statuses} status(es) since showed {shows} (last: mode {:?}, mission {:?}, goal id {}, \"{}\")",
                last.mode,
                last.mission,
                last.goal_id,
                last.reason
            )
        }
    }
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
    let wait = Duration::from_secs_f64(a.client.wait_s.max(0.2));
    let (cmd, outcome, last) = send_confirmed(
        s,
        &rid,
        Topic::CmdGoal,
        |before| {
            // An id the robot is not showing already, or its status could not tell this goal.
            let mut cmd = cmd;
            if before.is_some_and(|b| b.goal_id == cmd.goal_id) {
                cmd.goal_id = cmd.goal_id.wrapping_add(1);
            }
            let expect = Expect::Goal {
                goal_id: cmd.goal_id,
            };
            (cmd, expect)
        },
        a.delivery.policy(),
        wait,
    )
    .await?;
    report_sent(&a.robot, &cmd, outcome, last, "this goal's id")
}

async fn stop(a: StopArgs) -> anyhow::Result<()> {
    let cmd = StopCmd {
        reason: "operator-station stop".into(),
    };
    let rid = RobotId::new(&a.robot)?;
    let s = robot_session(&a.client, &a.robot).await?;
    let wait = Duration::from_secs_f64(a.client.wait_s.max(0.2));
    let (cmd, outcome, last) = send_confirmed(
        s,
        &rid,
        Topic::CmdStop,
        |_| (cmd, Expect::Halted),
        a.delivery.policy(),
        wait,
    )
    .await?;
    report_sent(&a.robot, &cmd, outcome, last, "it halted")
}

fn export(a: ExportArgs) -> anyhow::Result<()> {
    match a.what {
        ExportWhat::Session { session, mcap, db } => {
            let c = open_existing(&db)?;
            let e = crate::export::mcap::export_session(&c, &session, &mcap)?;
            println!("{}", serde_json::to_string(&e)?);
        }
        ExportWhat::Map {
            png,
            geotiff,
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
            if let Some(png) = &png {
                let bytes = crate::merge::datum_png_scaled(dm, px_per_cell).context("empty map")?;
                std::fs::write(png, bytes).with_context(|| format!("write {}", png.display()))?;
            }
            let mut geo = None;
            if let Some(out) = &geotiff {
                let row = datums
                    .iter()
                    .find(|d| d.datum_id == pick)
                    .with_context(|| format!("datum {pick} is not in the database"))?;
                let (Some(lat_deg), Some(lon_deg)) = (row.lat_deg, row.lon_deg) else {
                    bail!(
                        "datum {pick} is a local (SLAM-only) frame: a GeoTIFF needs a GNSS datum"
                    );
                };
                let d = msg::Datum {
                    lat_deg,
                    lon_deg,
                    h_m: row.h_m.unwrap_or(0.0),
                };
                let f = std::fs::File::create(out)
                    .with_context(|| format!("create {}", out.display()))?;
                let info = crate::export::geotiff::write(dm, &d, &pick, std::io::BufWriter::new(f))
                    .with_context(|| format!("write {}", out.display()))?;
                geo = Some(info);
            }
            println!(
                "{}",
                serde_json::json!({"datum_id": pick, "tiles": dm.tiles.len(), "bounds_m": dm.bounds_m(), "png": png, "geotiff": geotiff, "raster": geo})
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
    fn http_off_loopback_needs_tls() {
        let any: SocketAddr = "0.0.0.0:8443".parse().unwrap();
        let lo: SocketAddr = "127.0.0.1:8080".parse().unwrap();
        let e = http_tls(any, None, None, None).unwrap_err().to_string();
        assert!(e.contains("--tls-cert") && e.contains("--pki"), "{e}");
        assert_eq!(http_tls(lo, None, None, None).unwrap(), None);
        let (c, k) = http_tls(any, None, None, Some(Path::new("pki")))
            .unwrap()
            .unwrap();
        assert!(c.ends_with("station/station.crt") && k.ends_with("station/station.key"));
        let own = http_tls(lo, Some(Path::new("a.crt")), Some(Path::new("a.key")), None).unwrap();
        assert_eq!(own, Some((PathBuf::from("a.crt"), PathBuf::from("a.key"))));
    }

    #[test]
    fn zenoh_off_loopback_without_pki_is_refused() {
        let z = |listen: Option<&str>, connect: Option<&str>| ZenohArgs {
            zenoh: None,
            zenoh_listen: listen.map(String::from),
            connect: connect.map(String::from),
            pki: None,
        };
        let e = zenoh_config(&z(Some("tcp/0.0.0.0:7447"), None), Role::Station)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pki init") && e.contains("quic/0.0.0.0:7447"),
            "{e}"
        );
        assert!(zenoh_config(&z(None, Some("tcp/192.0.2.1:7447")), Role::Client).is_err());
        assert!(zenoh_config(&z(None, None), Role::Station).is_ok());
        assert!(zenoh_config(&z(None, None), Role::Client).is_ok());
        // The shipped station file listens on loopback.
        let file = ZenohArgs {
            zenoh: Some(
                PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/zenoh/station.json5"),
            ),
            ..z(None, None)
        };
        assert!(zenoh_config(&file, Role::Station).is_ok());
    }

    #[test]
    fn a_monitor_is_a_tls_client_with_its_own_certificate() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("pki");
        crate::pki::init(&dir, &[]).unwrap();
        crate::pki::add_monitor(&dir, "m1", 30).unwrap();
        let z = |listen: Option<&str>, connect: Option<&str>, pki: &Path| ZenohArgs {
            zenoh: None,
            zenoh_listen: listen.map(String::from),
            connect: connect.map(String::from),
            pki: Some(pki.to_path_buf()),
        };
        let ok = zenoh_config(
            &z(None, Some("quic/127.0.0.1:7447"), &dir),
            Role::Monitor("m1"),
        )
        .unwrap();
        assert_eq!(ok.get_json("mode").unwrap(), "\"client\"");
        assert_eq!(ok.get_json("listen/endpoints").unwrap(), "[]");
        let cert = ok
            .get_json("transport/link/tls/connect_certificate")
            .unwrap();
        assert!(cert.contains("monitors/m1/monitor.crt"), "{cert}");
        // It sets no rules of its own (the station's and router's decide).
        assert!(!ok
            .get_json("access_control/enabled")
            .unwrap()
            .contains("true"));
        // The copied folder works as well as the fleet folder.
        let copied = common::security::FleetDir::new(&dir).monitor_dir("m1");
        assert!(zenoh_config(
            &z(None, Some("quic/127.0.0.1:7447"), &copied),
            Role::Monitor("m1")
        )
        .is_ok());
        let err = |z: ZenohArgs, name| {
            zenoh_config(&z, Role::Monitor(name))
                .unwrap_err()
                .to_string()
        };
        assert!(err(z(None, None, &dir), "m1").contains("--connect"));
        assert!(err(
            z(Some("quic/127.0.0.1:1"), Some("quic/127.0.0.1:7447"), &dir),
            "m1"
        )
        .contains("--zenoh-listen"));
        assert!(err(z(None, Some("tcp/127.0.0.1:7447"), &dir), "m1").contains("quic/"));
        assert!(err(z(None, Some("quic/127.0.0.1:7447"), &dir), "m2").contains("add-monitor"));
    }

    #[test]
    fn rfc3339_is_right() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(1_700_000_000_123), "2023-11-14T22:13:20.123Z");
    }
}

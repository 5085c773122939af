//! The only place that touches Zenoh: publishes session, pose, tiles, path, status and routes;
//! answers queries for the session, every current tile and the recorded routes; receives and
//! validates commands.
//!
//! Two faces: [`RobotBus`] is async (tokio), [`BusHandle`] is the blocking-friendly face for the
//! synchronous simulation loop (its `publish_*` calls never block: they hand the message to the
//! bus task). Commands arrive validated as [`Command`]; refused ones arrive as
//! [`Command::Refused`] with the reason, so the agent can put it in its status. Every command's
//! header (sender, sequence, time) goes through a [`ReplayGuard`] first: a replayed command is
//! refused and counted apart.
//!
//! With certificates ([`ZenohSettings::tls`]) the session speaks only TLS with mutual
//! authentication and enforces the robot's access rules ([`secure`]); without, it refuses every
//! endpoint off loopback.

pub mod orpheus;
pub mod secure;
pub mod tiles;
pub mod translate;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::command::{self, Refusal, RefusalCode, ReplayGuard, ReplayWindow, RobotContext};
use common::grid::TileIndex;
use common::keys::{self, RobotId, Topic};
use common::msg::{
    self, CmdHeader, DriveCmd, GoalCmd, Path, Pose, Route, RouteCmd, Session, SpeedCmd, Status,
    StopCmd, ZoneSet,
};
use common::security::CertFiles;
use tokio::sync::mpsc;
use zenoh::qos::CongestionControl;

/// Teleop silence after which the robot must stop.
pub const DEADMAN: Duration = Duration::from_millis(300);

/// Default endpoint of the operator station (agents connect, the station listens).
pub const DEFAULT_STATION_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// Why the bus could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BusError {
    /// The Zenoh configuration could not be read or is invalid.
    #[error("zenoh config: {0}")]
    Config(String),
    /// The Zenoh session or one of its declarations failed.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// The background runtime could not be started.
    #[error("runtime: {0}")]
    Runtime(String),
    /// An endpoint this robot must not use (a plain link off loopback), with what to do instead.
    #[error("{0}")]
    Refused(String),
}

fn zerr(e: impl std::fmt::Display) -> BusError {
    BusError::Zenoh(e.to_string())
}

/// Zenoh mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ZenohMode {
    /// Peer (default): connects to the given endpoints, others may connect to it.
    #[default]
    Peer,
    /// Client of a router (or of a peer that listens).
    Client,
}

/// Where the Zenoh session connects and listens.
#[derive(Clone, Debug, Default)]
pub struct ZenohSettings {
    /// A json5 Zenoh config file (`config/zenoh/*.json5`); the fields below override it.
    pub file: Option<PathBuf>,
    /// Mode when no file is given (a file's own `mode` wins).
    pub mode: Option<ZenohMode>,
    /// Endpoints to connect to, e.g. `tcp/127.0.0.1:7447`.
    pub connect: Vec<String>,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// The robot's certificates: TLS with mutual authentication and the robot's access rules
    /// (every endpoint must then be `tls/`). None: plain links, loopback only.
    pub tls: Option<CertFiles>,
}

impl ZenohSettings {
    /// Settings that connect to one endpoint (the station's listen endpoint).
    pub fn connect_to(endpoint: impl Into<String>) -> Self {
        Self {
            connect: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// Settings that listen on one endpoint (what the station does).
    pub fn listen_on(endpoint: impl Into<String>) -> Self {
        Self {
            listen: vec![endpoint.into()],
            ..Self::default()
        }
    }

    /// Builds the Zenoh config: the file (or terranav defaults), multicast scouting off, short
    /// lease so a vanished peer is declared gone within 2 s, fast reconnect, then the overrides,
    /// then TLS when certificates are given. Refuses plain endpoints off loopback (and, with
    /// certificates, anything but `tls/`).
    pub fn to_config(&self) -> Result<zenoh::Config, BusError> {
        let c = self.build_config()?;
        secure::check_endpoints(&c, self.tls.is_some())?;
        Ok(c)
    }

    fn build_config(&self) -> Result<zenoh::Config, BusError> {
        let mut c = match &self.file {
            Some(f) => zenoh::Config::from_file(f)
                .map_err(|e| BusError::Config(format!("{}: {e}", f.display())))?,
            None => {
                let mut c = zenoh::Config::default();
                apply_terranav_defaults(&mut c)?;
                c
            }
        };
        let set = |c: &mut zenoh::Config, k: &str, v: &str| {
            c.insert_json5(k, v)
                .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))
        };
        if self.file.is_none() {
            let mode = match self.mode.unwrap_or_default() {
                ZenohMode::Peer => "\"peer\"",
                ZenohMode::Client => "\"client\"",
            };
            set(&mut c, "mode", mode)?;
        }
        // Whatever the file says, never scout by multicast: a fresh machine needs no network set-up
        // and tests on one host must not find each other.
        set(&mut c, "scouting/multicast/enabled", "false")?;
        if !self.connect.is_empty() {
            let v = serde_json::to_string(&self.connect)
                .map_err(|e| BusError::Config(e.to_string()))?;
            set(&mut c, "connect/endpoints", &v)?;
        }
        if !self.listen.is_empty() {
            let v =
                serde_json::to_string(&self.listen).map_err(|e| BusError::Config(e.to_string()))?;
            set(&mut c, "listen/endpoints", &v)?;
        } else if self.file.is_none() && self.tls.is_some() {
            // A secure robot connects to the station and needs no listener; `--listen tls/...`
            // lets stations link to it directly.
            set(&mut c, "listen/endpoints", "[]")?;
        } else if self.file.is_none() {
            // Zenoh's peer default listens on every interface (`tcp/[::]:0`); the robot connects
            // to the station, so it only needs a loopback port for peers on its own machine.
            set(&mut c, "listen/endpoints", "[\"tcp/127.0.0.1:0\"]")?;
        }
        if let Some(files) = &self.tls {
            secure::apply_tls(&mut c, files)?;
        }
        Ok(c)
    }
}

/// Link lease (ms): a peer silent for this long is dropped and its liveliness tokens vanish.
/// Four keep-alives per lease; 1.5 s keeps detection of a frozen or unplugged robot under 2 s
/// (a killed process closes its TCP socket and is detected at once).
pub const LEASE_MS: u64 = 1500;

/// The terranav defaults that `config/zenoh/*.json5` also spell out.
pub fn apply_terranav_defaults(c: &mut zenoh::Config) -> Result<(), BusError> {
    let kv = [
        ("scouting/multicast/enabled", "false".to_string()),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
        ("transport/link/tx/keep_alive", "4".to_string()),
        // Retry a lost endpoint every 0.5-1 s so a restarted station is rejoined quickly.
        (
            "connect/retry",
            "{period_init_ms: 500, period_max_ms: 1000, period_increase_factor: 1.5}".to_string(),
        ),
    ];
    for (k, v) in kv {
        c.insert_json5(k, &v)
            .map_err(|e| BusError::Config(format!("{k} = {v}: {e}")))?;
    }
    Ok(())
}

pub use common::command::CommandLimits;

/// Everything [`RobotBus::open`] needs.
#[derive(Clone, Debug)]
pub struct BusConfig {
    /// This robot.
    pub robot: RobotId,
    /// Zenoh endpoints.
    pub zenoh: ZenohSettings,
    /// Command validation limits.
    pub limits: CommandLimits,
    /// How fresh a command must be (replays are refused).
    pub replay: ReplayWindow,
}

impl BusConfig {
    /// A robot connecting to the station's default endpoint.
    pub fn new(robot: RobotId) -> Self {
        Self {
            robot,
            zenoh: ZenohSettings::connect_to(DEFAULT_STATION_ENDPOINT),
            limits: CommandLimits::default(),
            replay: ReplayWindow::default(),
        }
    }
}

/// A validated command, or the reason one was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Go to a goal.
    Goal(GoalCmd),
    /// Route teach / repeat.
    Route(RouteCmd),
    /// Teleop.
    Drive(DriveCmd),
    /// Stop now.
    Stop(StopCmd),
    /// Speed limit.
    Speed(SpeedCmd),
    /// The zones to obey (from the station).
    Zones(ZoneSet),
    /// A command that was refused (already counted by the bus); show it in the status.
    Refused(Refusal),
}

/// Counters of the bus, for the status message.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Commands refused since start.
    pub commands_refused: u32,
    /// Payloads on command keys that failed to decode since start.
    pub decode_errors: u32,
    /// Commands refused as replays since start (also counted in `commands_refused`).
    pub commands_replayed: u32,
}

/// What the robot currently serves to queries.
#[derive(Default)]
struct Served {
    session: Option<Vec<u8>>,
    tiles: BTreeMap<TileIndex, Vec<u8>>,
    routes: BTreeMap<String, Vec<u8>>,
}

struct Shared {
    robot: RobotId,
    limits: CommandLimits,
    /// What the robot knows about itself, for the goal checks (kept fresh by the loop).
    context: Mutex<RobotContext>,
    served: Mutex<Served>,
    refused: AtomicU32,
    decode_errors: AtomicU32,
    replayed: AtomicU32,
    replay_guard: Mutex<ReplayGuard>,
    last_drive: Mutex<Option<(Instant, u32)>>,
}

impl Shared {
    fn counters(&self) -> BusCounters {
        BusCounters {
            commands_refused: self.refused.load(Ordering::Relaxed),
            decode_errors: self.decode_errors.load(Ordering::Relaxed),
            commands_replayed: self.replayed.load(Ordering::Relaxed),
        }
    }

    fn lock_served(&self) -> std::sync::MutexGuard<'_, Served> {
        self.served.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// One robot's Zenoh session (async face).
pub struct RobotBus {
    session: zenoh::Session,
    shared: Arc<Shared>,
    _token: zenoh::liveliness::LivelinessToken,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

/// Checks a decoded command against the contract (`common::command`), with what the robot
/// knows about itself (`ctx`: its position and mapped area, for goals that are too far).
pub fn validate(cmd: &Command, limits: &CommandLimits, ctx: &RobotContext) -> Result<(), Refusal> {
    match cmd {
        Command::Goal(g) => command::check_goal(g, limits, ctx),
        Command::Drive(d) => command::check_drive(d, limits),
        Command::Speed(s) => command::check_speed(s),
        Command::Route(r) => command::check_route(r),
        Command::Zones(z) => command::check_zones(z),
        Command::Stop(_) | Command::Refused(_) => Ok(()),
    }
}

/// What became of one command payload.
#[derive(Clone, Debug, PartialEq)]
pub struct Parsed {
    /// The validated command, or [`Command::Refused`] with the reason.
    pub command: Command,
    /// The payload did not decode (counted apart from other refusals).
    pub undecodable: bool,
    /// Refused as a replay by the [`ReplayGuard`] (counted apart from other refusals).
    pub replayed: bool,
}

/// Decodes one command payload on `key`, checks its header against `guard` at `now_unix_ms` (the
/// robot's clock), then its content against the contract. `None` when the key is not a command of
/// this robot. Undecodable, replayed and invalid commands come back as `Refused`.
pub fn parse_command(
    robot: &RobotId,
    key: &str,
    payload: &[u8],
    limits: &CommandLimits,
    ctx: &RobotContext,
    guard: &mut ReplayGuard,
    now_unix_ms: u64,
) -> Option<Parsed> {
    let (rid, topic) = keys::parse(key).ok()?;
    if &rid != robot || !(topic.is_command() || topic == Topic::Zones) {
        return None;
    }
    let refused = |r: Refusal, undecodable: bool, replayed: bool| Parsed {
        command: Command::Refused(r),
        undecodable,
        replayed,
    };
    fn dec<T: serde::de::DeserializeOwned>(
        kind: &'static str,
        b: &[u8],
        f: fn(T) -> Command,
    ) -> Result<(&'static str, CmdHeader, Command), Refusal> {
        msg::decode_cmd::<T>(b)
            .map(|(h, c)| (kind, h, f(c)))
            .map_err(|e| Refusal::new(RefusalCode::Undecodable, format!("{kind}: {e}")))
    }
    let decoded = match topic {
        Topic::CmdGoal => dec("goal", payload, Command::Goal),
        Topic::CmdRoute => dec("route", payload, Command::Route),
        Topic::CmdDrive => dec("drive", payload, Command::Drive),
        Topic::CmdStop => dec("stop", payload, Command::Stop),
        Topic::CmdSpeed => dec("speed", payload, Command::Speed),
        Topic::Zones => {
            // A zone set is the station's state, not a command: it travels bare (pushed, or as
            // the answer to the robot's query, possibly long after it was drawn), only a station
            // may send it (the access rules), and its version orders it (the agent keeps the
            // newest), so it does not pass the replay guard.
            return Some(match msg::decode::<ZoneSet>(payload) {
                Err(e) => refused(
                    Refusal::new(RefusalCode::Undecodable, format!("zones: {e}")),
                    true,
                    false,
                ),
                Ok(set) => {
                    let cmd = Command::Zones(set);
                    match validate(&cmd, limits, ctx) {
                        Ok(()) => Parsed {
                            command: cmd,
                            undecodable: false,
                            replayed: false,
                        },
                        Err(r) => refused(r, false, false),
                    }
                }
            });
        }
        _ => return None,
    };
    Some(match decoded {
        Err(r) => refused(r, true, false),
        Ok((kind, header, cmd)) => match guard.check(kind, &header, now_unix_ms) {
            Err(r) => refused(r, false, true),
            Ok(()) => match validate(&cmd, limits, ctx) {
                Ok(()) => Parsed {
                    command: cmd,
                    undecodable: false,
                    replayed: false,
                },
                Err(r) => refused(r, false, false),
            },
        },
    })
}

fn now_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

impl RobotBus {
    /// Opens the session, declares the liveliness token, the queryables and the command
    /// subscriber. Commands go to `commands`.
    pub async fn open(
        config: BusConfig,
        commands: std::sync::mpsc::Sender<Command>,
    ) -> Result<Self, BusError> {
        let mut zc = config.zenoh.to_config()?;
        if config.zenoh.tls.is_some() {
            secure::apply_robot_acl(&mut zc, &config.robot)?;
        }
        let session = zenoh::open(zc).await.map_err(zerr)?;
        let robot = config.robot.clone();
        let shared = Arc::new(Shared {
            robot: robot.clone(),
            limits: config.limits,
            context: Mutex::new(RobotContext::default()),
            served: Mutex::new(Served::default()),
            refused: AtomicU32::new(0),
            decode_errors: AtomicU32::new(0),
            replayed: AtomicU32::new(0),
            replay_guard: Mutex::new(ReplayGuard::new(config.replay)),
            last_drive: Mutex::new(None),
        });
        let mut tasks = Vec::new();

        // Commands, and the station's zones (pushed, and asked for once at start: a robot that
        // starts after the zones were drawn must obey them too).
        let sub = session
            .declare_subscriber(keys::robot_commands(&robot))
            .await
            .map_err(zerr)?;
        let zones_sub = session
            .declare_subscriber(keys::key(&robot, Topic::Zones))
            .await
            .map_err(zerr)?;
        let (sample_tx, mut sample_rx) = mpsc::unbounded_channel::<(String, Vec<u8>)>();
        for sub in [sub, zones_sub] {
            let tx = sample_tx.clone();
            tasks.push(tokio::spawn(async move {
                while let Ok(sample) = sub.recv_async().await {
                    let key = sample.key_expr().as_str().to_string();
                    if tx
                        .send((key, sample.payload().to_bytes().to_vec()))
                        .is_err()
                    {
                        break;
                    }
                }
            }));
        }
        {
            let tx = sample_tx;
            let s2 = session.clone();
            let key = keys::key(&robot, Topic::Zones);
            tasks.push(tokio::spawn(async move {
                // Give the connection to the station a moment; a station that is not there yet
                // pushes the zones when it sees this robot's session.
                tokio::time::sleep(Duration::from_millis(500)).await;
                match s2.get(&key).timeout(Duration::from_secs(3)).await {
                    Ok(replies) => {
                        while let Ok(reply) = replies.recv_async().await {
                            if let Ok(sample) = reply.result() {
                                let k = sample.key_expr().as_str().to_string();
                                let _ = tx.send((k, sample.payload().to_bytes().to_vec()));
                            }
                        }
                    }
                    Err(e) => tracing::debug!("zones query: {e}"),
                }
            }));
        }
        {
            let shared = shared.clone();
            tasks.push(tokio::spawn(async move {
                while let Some((key, payload)) = sample_rx.recv().await {
                    let ctx = *shared.context.lock().unwrap_or_else(|p| p.into_inner());
                    let parsed = {
                        let mut guard = shared
                            .replay_guard
                            .lock()
                            .unwrap_or_else(|p| p.into_inner());
                        parse_command(
                            &shared.robot,
                            &key,
                            &payload,
                            &shared.limits,
                            &ctx,
                            &mut guard,
                            now_unix_ms(),
                        )
                    };
                    let Some(parsed) = parsed else {
                        continue;
                    };
                    let cmd = match parsed.command {
                        Command::Refused(r) => {
                            if parsed.undecodable {
                                shared.decode_errors.fetch_add(1, Ordering::Relaxed);
                            }
                            if parsed.replayed {
                                shared.replayed.fetch_add(1, Ordering::Relaxed);
                            }
                            shared.refused.fetch_add(1, Ordering::Relaxed);
                            tracing::warn!(key, %r, "command refused");
                            Command::Refused(r)
                        }
                        Command::Drive(d) => {
                            let now = Instant::now();
                            let mut last =
                                shared.last_drive.lock().unwrap_or_else(|p| p.into_inner());
                            // Older sequence numbers are stale duplicates, unless the deadman has
                            // expired (a restarted station counts from anew).
                            if let Some((t, seq)) = *last {
                                if d.seq <= seq && now.duration_since(t) < Duration::from_secs(1) {
                                    continue;
                                }
                            }
                            *last = Some((now, d.seq));
                            Command::Drive(d)
                        }
                        other => other,
                    };
                    if commands.send(cmd).is_err() {
                        break;
                    }
                }
            }));
        }

        // Session queryable.
        let q = session
            .declare_queryable(keys::key(&robot, Topic::Session))
            .await
            .map_err(zerr)?;
        {
            let shared = shared.clone();
            let key = keys::key(&robot, Topic::Session);
            tasks.push(tokio::spawn(async move {
                while let Ok(query) = q.recv_async().await {
                    let s = shared.lock_served().session.clone();
                    if let Some(s) = s {
                        if let Err(e) = query.reply(&key, s).await {
                            tracing::warn!("session reply failed: {e}");
                        }
                    }
                }
            }));
        }

        // Tiles queryable: answers every current tile matching the query.
        let q = session
            .declare_queryable(keys::robot_tiles(&robot))
            .await
            .map_err(zerr)?;
        {
            let shared = shared.clone();
            let robot = robot.clone();
            tasks.push(tokio::spawn(async move {
                while let Ok(query) = q.recv_async().await {
                    let tiles: Vec<(TileIndex, Vec<u8>)> = shared
                        .lock_served()
                        .tiles
                        .iter()
                        .map(|(k, v)| (*k, v.clone()))
                        .collect();
                    let qk = query.key_expr().clone();
                    for (t, bytes) in tiles {
                        let key = keys::key(&robot, Topic::Tile { tx: t.tx, ty: t.ty });
                        let Ok(ke) = zenoh::key_expr::KeyExpr::try_from(key.clone()) else {
                            continue;
                        };
                        if !qk.intersects(&ke) {
                            continue;
                        }
                        if let Err(e) = query.reply(ke, bytes).await {
                            tracing::warn!("tile reply {key} failed: {e}");
                        }
                    }
                }
            }));
        }

        // Routes queryable.
        let q = session
            .declare_queryable(keys::key(&robot, Topic::Route))
            .await
            .map_err(zerr)?;
        {
            let shared = shared.clone();
            let key = keys::key(&robot, Topic::Route);
            tasks.push(tokio::spawn(async move {
                while let Ok(query) = q.recv_async().await {
                    let routes: Vec<Vec<u8>> =
                        shared.lock_served().routes.values().cloned().collect();
                    for r in routes {
                        if let Err(e) = query.reply(&key, r).await {
                            tracing::warn!("route reply failed: {e}");
                        }
                    }
                }
            }));
        }

        let token = session
            .liveliness()
            .declare_token(keys::key(&robot, Topic::Alive))
            .await
            .map_err(zerr)?;
        Ok(Self {
            session,
            shared,
            _token: token,
            tasks,
        })
    }

    /// This robot.
    pub fn robot(&self) -> &RobotId {
        &self.shared.robot
    }

    async fn put(&self, topic: Topic, payload: Vec<u8>, reliable: bool) -> Result<(), BusError> {
        let key = keys::key(&self.shared.robot, topic);
        let cc = if reliable {
            CongestionControl::Block
        } else {
            CongestionControl::Drop
        };
        self.session
            .put(key, payload)
            .congestion_control(cc)
            .await
            .map_err(zerr)
    }

    /// Publishes (and from now on serves) the session.
    pub async fn publish_session(&self, s: &Session) -> Result<(), BusError> {
        let b = msg::encode(s);
        self.shared.lock_served().session = Some(b.clone());
        self.put(Topic::Session, b, true).await
    }

    /// Publishes a pose.
    pub async fn publish_pose(&self, p: &Pose) -> Result<(), BusError> {
        self.put(Topic::Pose, msg::encode(p), false).await
    }

    /// Publishes a changed tile, already encoded with `common::grid::encode_tile`, and keeps it
    /// for the tile queryable.
    pub async fn publish_tile(&self, index: TileIndex, encoded: Vec<u8>) -> Result<(), BusError> {
        self.shared
            .lock_served()
            .tiles
            .insert(index, encoded.clone());
        self.put(
            Topic::Tile {
                tx: index.tx,
                ty: index.ty,
            },
            encoded,
            true,
        )
        .await
    }

    /// Publishes the planned path.
    pub async fn publish_path(&self, p: &Path) -> Result<(), BusError> {
        self.put(Topic::Path, msg::encode(p), true).await
    }

    /// Publishes the status.
    pub async fn publish_status(&self, s: &Status) -> Result<(), BusError> {
        self.put(Topic::Status, msg::encode(s), true).await
    }

    /// Publishes (and from now on serves) a recorded route.
    pub async fn publish_route(&self, r: &Route) -> Result<(), BusError> {
        let b = msg::encode(r);
        self.shared
            .lock_served()
            .routes
            .insert(r.route_id.clone(), b.clone());
        self.put(Topic::Route, b, true).await
    }

    /// Forgets every served tile (a new session starts a new map).
    pub fn clear_tiles(&self) {
        self.shared.lock_served().tiles.clear();
    }

    /// Counters for the status.
    pub fn counters(&self) -> BusCounters {
        self.shared.counters()
    }

    /// When the last accepted drive command arrived.
    pub fn last_drive(&self) -> Option<Instant> {
        self.shared
            .last_drive
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .map(|(t, _)| t)
    }

    /// True when no drive command arrived within [`DEADMAN`] before `now` (or none ever).
    pub fn drive_is_stale(&self, now: Instant) -> bool {
        match self.last_drive() {
            Some(t) => now.saturating_duration_since(t) > DEADMAN,
            None => true,
        }
    }

    /// Closes the session (the liveliness token goes with it).
    pub async fn close(self) -> Result<(), BusError> {
        for t in &self.tasks {
            t.abort();
        }
        self.session.close().await.map_err(zerr)
    }
}

/// Messages from the synchronous loop to the bus task.
enum Out {
    Session(Session),
    Pose(Pose),
    Tile(TileIndex, Vec<u8>),
    Path(Path),
    Status(Status),
    Route(Route),
    ClearTiles,
}

/// Blocking-friendly face of the bus for a synchronous loop: owns a small tokio runtime on a
/// background thread; `publish_*` never block (they queue for the bus task).
pub struct BusHandle {
    tx: mpsc::UnboundedSender<Out>,
    commands: std::sync::mpsc::Receiver<Command>,
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
    _stop: Option<tokio::sync::oneshot::Sender<()>>,
}

impl BusHandle {
    /// Starts the runtime and opens the bus; returns when the session is open.
    pub fn start(config: BusConfig) -> Result<Self, BusError> {
        let (cmd_tx, cmd_rx) = std::sync::mpsc::channel();
        let (tx, mut rx) = mpsc::unbounded_channel::<Out>();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<Arc<Shared>, BusError>>();
        let (stop_tx, mut stop_rx) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("robot-bus".into())
            .spawn(move || {
                let rt = match tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(2)
                    .enable_all()
                    .build()
                {
                    Ok(rt) => rt,
                    Err(e) => {
                        let _ = ready_tx.send(Err(BusError::Runtime(e.to_string())));
                        return;
                    }
                };
                rt.block_on(async move {
                    let bus = match RobotBus::open(config, cmd_tx).await {
                        Ok(b) => b,
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                            return;
                        }
                    };
                    let _ = ready_tx.send(Ok(bus.shared.clone()));
                    loop {
                        let out = tokio::select! {
                            m = rx.recv() => match m { Some(m) => m, None => break },
                            _ = &mut stop_rx => break,
                        };
                        let r = match out {
                            Out::Session(s) => bus.publish_session(&s).await,
                            Out::Pose(p) => bus.publish_pose(&p).await,
                            Out::Tile(i, b) => bus.publish_tile(i, b).await,
                            Out::Path(p) => bus.publish_path(&p).await,
                            Out::Status(s) => bus.publish_status(&s).await,
                            Out::Route(r) => bus.publish_route(&r).await,
                            Out::ClearTiles => {
                                bus.clear_tiles();
                                Ok(())
                            }
                        };
                        if let Err(e) = r {
                            tracing::warn!("publish failed: {e}");
                        }
                    }
                    let _ = bus.close().await;
                });
            })
            .map_err(|e| BusError::Runtime(e.to_string()))?;
        let shared = ready_rx
            .recv()
            .map_err(|_| BusError::Runtime("bus thread ended before opening".into()))??;
        Ok(Self {
            tx,
            commands: cmd_rx,
            shared,
            thread: Some(thread),
            _stop: Some(stop_tx),
        })
    }

    fn send(&self, o: Out) {
        // The bus task only ends when the handle is dropped; a send error then is harmless.
        let _ = self.tx.send(o);
    }

    /// Publishes (and serves) the session.
    pub fn publish_session(&self, s: &Session) {
        self.send(Out::Session(s.clone()));
    }
    /// Publishes a pose.
    pub fn publish_pose(&self, p: &Pose) {
        self.send(Out::Pose(p.clone()));
    }
    /// Publishes (and serves) one tile encoded with `common::grid::encode_tile`.
    pub fn publish_tile(&self, index: TileIndex, encoded: Vec<u8>) {
        self.send(Out::Tile(index, encoded));
    }
    /// Publishes the path.
    pub fn publish_path(&self, p: &Path) {
        self.send(Out::Path(p.clone()));
    }
    /// Publishes the status.
    pub fn publish_status(&self, s: &Status) {
        self.send(Out::Status(s.clone()));
    }
    /// Publishes (and serves) a recorded route.
    pub fn publish_route(&self, r: &Route) {
        self.send(Out::Route(r.clone()));
    }
    /// Forgets every served tile.
    pub fn clear_tiles(&self) {
        self.send(Out::ClearTiles);
    }

    /// Tells the command checks where the robot is and what it has mapped.
    pub fn set_context(&self, ctx: RobotContext) {
        *self
            .shared
            .context
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = ctx;
    }

    /// The next command, if any (validated, or `Refused`).
    pub fn try_recv(&self) -> Option<Command> {
        self.commands.try_recv().ok()
    }

    /// Waits up to `timeout` for the next command.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Command> {
        self.commands.recv_timeout(timeout).ok()
    }

    /// Counters for the status.
    pub fn counters(&self) -> BusCounters {
        self.shared.counters()
    }

    /// True when no drive command arrived within [`DEADMAN`] before `now` (or none ever).
    pub fn drive_is_stale(&self, now: Instant) -> bool {
        match *self
            .shared
            .last_drive
            .lock()
            .unwrap_or_else(|p| p.into_inner())
        {
            Some((t, _)) => now.saturating_duration_since(t) > DEADMAN,
            None => true,
        }
    }

    /// Current Unix time in milliseconds (what every message's `t_unix_ms` should carry).
    pub fn now_unix_ms() -> u64 {
        now_unix_ms()
    }

    /// Flushes queued messages and closes the session.
    pub fn close(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        // Dropping the queue sender lets the task drain what is queued, then close.
        let (dead_tx, _) = mpsc::unbounded_channel();
        drop(std::mem::replace(&mut self.tx, dead_tx));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for BusHandle {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::msg::GoalTarget;

    fn rid() -> RobotId {
        RobotId::new("husky-1").unwrap()
    }

    const NOW: u64 = 1_790_000_000_000;

    /// A command in its envelope, fresh at [`NOW`].
    fn env<T: serde::Serialize>(c: &T) -> Vec<u8> {
        let h = CmdHeader {
            sender: 1,
            seq: 1,
            t_unix_ms: NOW,
        };
        msg::encode_cmd(h, c)
    }

    fn parse(key: &str, b: &[u8]) -> Option<(Command, bool)> {
        let p = parse_command(
            &rid(),
            key,
            b,
            &CommandLimits::default(),
            &RobotContext::default(),
            &mut ReplayGuard::default(),
            NOW,
        )?;
        Some((p.command, p.undecodable))
    }

    #[test]
    fn valid_commands_pass() {
        let g = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Map {
                x_m: 3.0,
                y_m: -2.0,
            },
            tolerance_m: 0.5,
        };
        let (c, de) = parse("terranav/husky-1/cmd/goal", &env(&g)).unwrap();
        assert_eq!(c, Command::Goal(g));
        assert!(!de);
        let s = SpeedCmd { limit_mps: 0.7 };
        let (c, _) = parse("terranav/husky-1/cmd/speed", &env(&s)).unwrap();
        assert_eq!(c, Command::Speed(s));
    }

    #[test]
    fn bad_commands_are_refused_with_reasons() {
        let g = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Gnss {
                lat_deg: 91.0,
                lon_deg: 0.0,
                h_m: None,
            },
            tolerance_m: 0.5,
        };
        let (c, de) = parse("terranav/husky-1/cmd/goal", &env(&g)).unwrap();
        assert!(
            matches!(c, Command::Refused(ref r) if r.code == RefusalCode::LatitudeOutOfRange),
            "{c:?}"
        );
        assert!(!de);
        let d = DriveCmd {
            seq: 1,
            v_mps: f32::NAN,
            omega_rps: 0.0,
            deadman: true,
        };
        let (c, _) = parse("terranav/husky-1/cmd/drive", &env(&d)).unwrap();
        assert!(matches!(c, Command::Refused(_)));
        let d = DriveCmd {
            seq: 1,
            v_mps: 5.0,
            omega_rps: 0.0,
            deadman: true,
        };
        let (c, _) = parse("terranav/husky-1/cmd/drive", &env(&d)).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.message.contains("speed")));
        // Schema 1, then a string that claims 9 bytes and has one invalid one.
        let (c, de) = parse("terranav/husky-1/cmd/stop", &[1, 9, 0xff]).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.code == RefusalCode::Undecodable));
        assert!(de);
        // Another schema version.
        let mut b = msg::encode(&StopCmd::default());
        b[0] = 7;
        let (c, de) = parse("terranav/husky-1/cmd/stop", &b).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.message.contains("schema")));
        assert!(de);
        // Another robot's or a non-command key is not ours.
        assert!(parse(
            "terranav/husky-2/cmd/stop",
            &msg::encode(&StopCmd::default())
        )
        .is_none());
        assert!(parse("terranav/husky-1/pose", &[]).is_none());
    }

    #[test]
    fn a_command_sent_twice_is_refused_as_a_replay() {
        let mut guard = ReplayGuard::default();
        let b = env(&StopCmd::default());
        let mut go = |b: &[u8], now| {
            parse_command(
                &rid(),
                "terranav/husky-1/cmd/stop",
                b,
                &CommandLimits::default(),
                &RobotContext::default(),
                &mut guard,
                now,
            )
            .unwrap()
        };
        let first = go(&b, NOW + 3);
        assert!(matches!(first.command, Command::Stop(_)) && !first.replayed);
        let again = go(&b, NOW + 900);
        assert!(
            matches!(again.command, Command::Refused(ref r) if r.code == RefusalCode::Replayed),
            "{again:?}"
        );
        assert!(again.replayed && !again.undecodable);
        // A bare command without its envelope does not decode.
        let bare = go(&msg::encode(&StopCmd::default()), NOW + 901);
        assert!(bare.undecodable && !bare.replayed);
    }

    #[test]
    fn plain_endpoints_off_loopback_are_refused() {
        let e = ZenohSettings::connect_to("tcp/192.0.2.7:7447")
            .to_config()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("without --pki") && e.contains("pki issue"),
            "{e}"
        );
        let e = ZenohSettings::listen_on("tcp/0.0.0.0:7447")
            .to_config()
            .unwrap_err()
            .to_string();
        assert!(e.contains("listen on tcp/0.0.0.0:7447"), "{e}");
        // A secure robot needs tls/ everywhere; its default is to listen nowhere.
        let files = CertFiles::robot(std::path::Path::new("/nonexistent"));
        let secure = ZenohSettings {
            tls: Some(files.clone()),
            ..ZenohSettings::connect_to("tls/192.0.2.7:7447")
        };
        let c = secure.to_config().unwrap();
        assert_eq!(c.get_json("listen/endpoints").unwrap(), "[]");
        assert_eq!(
            c.get_json("transport/link/tls/enable_mtls").unwrap(),
            "true"
        );
        let plain_with_pki = ZenohSettings {
            tls: Some(files),
            ..ZenohSettings::connect_to("tcp/127.0.0.1:7447")
        };
        assert!(plain_with_pki.to_config().is_err());
    }

    #[test]
    fn config_has_multicast_off_and_short_lease() {
        let c = ZenohSettings::connect_to("tcp/127.0.0.1:7999")
            .to_config()
            .unwrap();
        let j = format!("{c}");
        assert!(j.contains("7999"), "{j}");
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(
            c.get_json("transport/link/tx/lease").unwrap(),
            LEASE_MS.to_string()
        );
        assert_eq!(
            c.get_json("listen/endpoints").unwrap(),
            r#"["tcp/127.0.0.1:0"]"#,
            "loopback only by default"
        );
    }

    #[test]
    fn shipped_zenoh_files_keep_the_lease_and_scouting_defaults() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/zenoh");
        for f in ["robot.json5", "station.json5", "router-client.json5"] {
            // Unchecked: router-client.json5 connects off loopback, which needs --pki.
            let c = ZenohSettings {
                file: Some(dir.join(f)),
                ..ZenohSettings::default()
            }
            .build_config()
            .unwrap_or_else(|e| panic!("{f}: {e}"));
            assert_eq!(
                c.get_json("transport/link/tx/lease").unwrap(),
                LEASE_MS.to_string(),
                "{f}"
            );
            assert_eq!(
                c.get_json("transport/link/tx/keep_alive").unwrap(),
                "4",
                "{f}"
            );
            assert_eq!(
                c.get_json("scouting/multicast/enabled").unwrap(),
                "false",
                "{f}"
            );
        }
    }
}

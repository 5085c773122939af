//! Helpers of the station tests: the station and simulated robots as real processes, a Zenoh
//! observer that asks robots for their tiles or puts raw payloads, synthetic robots on a real
//! Zenoh session (`robot_agent::bus`), and a tiny HTTP client.
//!
//! Everything is on loopback: explicit `tcp/127.0.0.1:PORT` endpoints and multicast scouting off
//! (the station's and the robot bus's Zenoh configs force it off).
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::grid::{decode_tile, encode_tile, Cell, CellState, Lattice, Tile, TileIndex};
use common::keys::{self, RobotId, Topic};
use common::msg::{Datum, MapFrame, Session};
use robot_agent::bus::{BusConfig, BusHandle, ZenohSettings};
use serde_json::Value;
use support::{bin, free_port, workspace_root, KillOnDrop};

/// The world of the live tests (two lanes, y = 0 and y = 6, landmarks around them).
pub fn field_scenario() -> PathBuf {
    workspace_root().join("config/scenarios/station-field.toml")
}

/// `s` without ANSI colour sequences (`ESC [ ... m`).
pub fn strip_ansi(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// The last `n` lines of a log file, for failure messages.
pub fn tail(path: &Path, n: usize) -> String {
    let text = strip_ansi(&std::fs::read_to_string(path).unwrap_or_default());
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Ports of one station.
#[derive(Clone, Copy, Debug)]
pub struct Ports {
    /// HTTP.
    pub http: u16,
    /// Zenoh listen.
    pub zenoh: u16,
}

impl Ports {
    /// Two fresh ports.
    pub fn new() -> Self {
        Self {
            http: free_port(),
            zenoh: free_port(),
        }
    }
    /// The station's Zenoh endpoint.
    pub fn endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.zenoh)
    }
}

/// `operator-station serve` as a child process; its stderr goes to a log file that is printed
/// when a test fails while it runs.
pub struct Station {
    proc: Option<KillOnDrop>,
    /// Its ports.
    pub ports: Ports,
    /// Its log (stderr).
    pub log: PathBuf,
    /// From the spawn to its first HTTP answer, and to the stored map being back.
    pub answered_after: (Duration, Duration),
}

impl Station {
    /// Starts the station and waits until it answers HTTP.
    pub fn start(ports: Ports, db: &Path) -> Station {
        Self::start_with(ports, db, &["--zenoh-listen".into(), ports.endpoint()])
    }

    /// Starts the station with these Zenoh arguments (e.g. `--pki DIR --zenoh-listen tls/...`)
    /// and waits until it answers HTTP and has put its stored map back (where `/api/health`
    /// may be read without credentials).
    pub fn start_with(ports: Ports, db: &Path, zenoh_args: &[String]) -> Station {
        let log = db.with_extension(format!("{}.log", ports.http));
        let err = std::fs::File::create(&log).expect("station log");
        let mut p = KillOnDrop::spawn(
            Command::new(bin("operator-station"))
                .args(["serve", "--port", &ports.http.to_string()])
                .args(zenoh_args)
                .arg("--db")
                .arg(db)
                .env("RUST_LOG", "info,zenoh=warn")
                .env("NO_COLOR", "1")
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(err),
        )
        .expect("start operator-station");
        let t0 = Instant::now();
        let mut answered = None;
        let mut ready = || match http(ports.http, "GET", "/api/health", "") {
            None => false,
            Some((status, body)) => {
                answered.get_or_insert_with(|| t0.elapsed());
                status != 200
                    || serde_json::from_str::<Value>(&body)
                        .is_ok_and(|h| h["restore"]["finished"] != Value::Bool(false))
            }
        };
        while !ready() {
            if let Ok(Some(s)) = p.0.try_wait() {
                panic!("station exited: {s}\n{}", tail(&log, 30));
            }
            // Generous: a hang, not a slow start on a loaded machine, is what this catches.
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "station did not start within 60 s\n{}",
                tail(&log, 30)
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let restored = t0.elapsed();
        Station {
            proc: Some(p),
            ports,
            log,
            answered_after: (answered.unwrap_or(restored), restored),
        }
    }

    /// SIGKILL now (no chance to flush anything).
    pub fn kill(&mut self) {
        self.proc.take();
    }

    /// The station's log so far, without terminal colours.
    pub fn log_text(&self) -> String {
        strip_ansi(&std::fs::read_to_string(&self.log).unwrap_or_default())
    }
}

impl Drop for Station {
    fn drop(&mut self) {
        if std::thread::panicking() && self.proc.is_some() {
            eprintln!("--- station log tail ---\n{}", tail(&self.log, 40));
        }
    }
}

/// `robot-agent sim --scenario ... --connect ... --robot ID` (live, not headless) as a child.
pub struct Robot {
    proc: Option<KillOnDrop>,
    /// Robot id.
    pub id: String,
    /// Its log (stderr).
    pub log: PathBuf,
}

impl Robot {
    /// Starts a simulated robot in `scenario` connecting to `endpoint`; `start` is `X,Y,YAW_DEG`.
    pub fn start(
        id: &str,
        scenario: &Path,
        endpoint: &str,
        start: &str,
        seed: u64,
        dir: &Path,
    ) -> Robot {
        Self::start_with(id, scenario, endpoint, start, seed, dir, &[])
    }

    /// [`Robot::start`] with more arguments (e.g. `--pki DIR --listen tls/...`).
    pub fn start_with(
        id: &str,
        scenario: &Path,
        endpoint: &str,
        start: &str,
        seed: u64,
        dir: &Path,
        extra: &[String],
    ) -> Robot {
        let log = dir.join(format!("{id}.log"));
        let err = std::fs::File::create(&log).expect("robot log");
        let p = KillOnDrop::spawn(
            Command::new(bin("robot-agent"))
                .current_dir(workspace_root())
                .arg("sim")
                .arg("--scenario")
                .arg(scenario)
                .args([
                    "--connect",
                    endpoint,
                    "--robot",
                    id,
                    "--seed",
                    &seed.to_string(),
                ])
                .arg(format!("--start={start}"))
                .args(extra)
                .env("RUST_LOG", "info,zenoh=warn")
                .env("NO_COLOR", "1")
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(err),
        )
        .expect("start robot-agent");
        Robot {
            proc: Some(p),
            id: id.into(),
            log,
        }
    }

    /// Process id.
    pub fn pid(&self) -> u32 {
        self.proc.as_ref().map(|p| p.0.id()).unwrap_or(0)
    }

    /// Sends a signal (`-KILL`, `-STOP`, ...).
    pub fn signal(&self, sig: &str) {
        let pid = self.pid().to_string();
        let ok = Command::new("kill")
            .args([sig, &pid])
            .status()
            .map(|s| s.success())
            .unwrap_or(false);
        assert!(ok, "kill {sig} {pid}");
    }

    /// Panics with the log tail when the process has exited.
    pub fn assert_running(&mut self) {
        if let Some(p) = self.proc.as_mut() {
            if let Ok(Some(s)) = p.0.try_wait() {
                panic!("robot {} exited: {s}\n{}", self.id, tail(&self.log, 30));
            }
        }
    }
}

impl Drop for Robot {
    fn drop(&mut self) {
        if std::thread::panicking() && self.proc.is_some() {
            eprintln!(
                "--- robot {} log tail ---\n{}",
                self.id,
                tail(&self.log, 30)
            );
        }
        // Continue a stopped process so the kill is delivered at once.
        if let Some(p) = &self.proc {
            let _ = Command::new("kill")
                .args(["-CONT", &p.0.id().to_string()])
                .stderr(Stdio::null())
                .status();
        }
    }
}

/// Minimal HTTP/1.1 request; (status, body) or None when nothing listens.
pub fn http(port: u16, method: &str, path: &str, body: &str) -> Option<(u16, String)> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .ok()?;
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).ok()?;
    let text = String::from_utf8_lossy(&buf).to_string();
    let status: u16 = text.split_whitespace().nth(1)?.parse().ok()?;
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    Some((status, body))
}

/// GET returning JSON.
pub fn get_json(port: u16, path: &str) -> Value {
    let (st, body) = http(port, "GET", path, "").expect("station answers");
    assert_eq!(st, 200, "{path}: {body}");
    serde_json::from_str(&body).expect("JSON body")
}

/// The station's entry for one robot in `/api/robots`, if any.
pub fn robot_entry(port: u16, robot: &str) -> Option<Value> {
    let (st, body) = http(port, "GET", "/api/robots", "")?;
    if st != 200 {
        return None;
    }
    let v: Value = serde_json::from_str(&body).ok()?;
    v.as_array()?.iter().find(|r| r["robot"] == robot).cloned()
}

/// Polls `f` every 50 ms until it is true or `limit` passes; returns whether it became true.
pub fn wait_for(limit: Duration, mut f: impl FnMut() -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    f()
}

/// Number of merged tiles the station reports.
pub fn station_tiles(port: u16) -> u64 {
    http(port, "GET", "/api/health", "")
        .and_then(|(_, b)| serde_json::from_str::<Value>(&b).ok())
        .and_then(|v| v["tiles"].as_u64())
        .unwrap_or(0)
}

/// Tile indices and versions of a datum's merged map, from `/api/map/<datum>/tiles`.
pub fn station_tile_index(port: u16, datum: &str) -> BTreeMap<TileIndex, u64> {
    let v = get_json(port, &format!("/api/map/{datum}/tiles"));
    v["tiles"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|t| {
                    Some((
                        TileIndex {
                            tx: t["tx"].as_i64()? as i32,
                            ty: t["ty"].as_i64()? as i32,
                        },
                        t["version"].as_u64()?,
                    ))
                })
                .collect()
        })
        .unwrap_or_default()
}

/// A Zenoh session of the test itself: connected to the station's endpoint to see what the
/// robots serve and to put raw payloads on their keys, or, with fleet certificates, an operator,
/// a monitor or an intruder on secure links.
pub struct Observer {
    rt: tokio::runtime::Runtime,
    /// The session.
    pub session: zenoh::Session,
    subscribers: Vec<zenoh::pubsub::Subscriber<()>>,
    tokens: Vec<zenoh::liveliness::LivelinessToken>,
}

/// One message an [`Observer`] heard: when, on which key, how many payload bytes, the payload.
pub struct Heard {
    /// When it arrived.
    pub at: Instant,
    /// Its key.
    pub key: String,
    /// Its payload.
    pub payload: Vec<u8>,
}

/// The certificates an [`Observer`] presents on secure links: the CA it trusts (none: plain
/// links only) and its own certificate and key (none: no client certificate).
#[derive(Clone, Copy, Default)]
pub struct Tls<'a> {
    /// The CA to trust.
    pub ca: Option<&'a Path>,
    /// Certificate and key to present.
    pub identity: Option<(&'a Path, &'a Path)>,
}

impl<'a> Tls<'a> {
    /// A fleet member's files: its CA, certificate and key.
    pub fn member(files: &'a common::security::CertFiles) -> Self {
        Tls {
            ca: Some(&files.ca),
            identity: Some((&files.cert, &files.key)),
        }
    }
}

impl Observer {
    /// Connects to `endpoint` (loopback, multicast scouting off).
    pub fn connect(endpoint: &str) -> Observer {
        let cfg = operator_station::station::zenoh_config(None, None, &[], &[endpoint.into()])
            .expect("zenoh config");
        let o = Self::open_config(cfg).expect("open zenoh");
        // Let the link come up and the routes propagate.
        std::thread::sleep(Duration::from_millis(500));
        o
    }

    /// Opens a session that listens nowhere, with `tls`'s certificates, as a client (served by
    /// what it connects to) or a peer (linked straight to each endpoint); panics when it cannot.
    pub fn open(connect: &[String], tls: Tls, client: bool) -> Observer {
        Self::try_open(connect, tls, client).expect("open zenoh")
    }

    /// As [`Observer::open`]; a client that cannot link fails to open.
    pub fn try_open(connect: &[String], tls: Tls, client: bool) -> Result<Observer, String> {
        let mut c = operator_station::station::zenoh_config(None, None, &[], connect)
            .expect("zenoh config");
        let mut set = |k: &str, v: String| c.insert_json5(k, &v).expect(k);
        set("listen/endpoints", "[]".into());
        if client {
            set("mode", "\"client\"".into());
        }
        let path = |p: &Path| serde_json::to_string(&p.display().to_string()).unwrap();
        if let Some(ca) = tls.ca {
            set("transport/link/tls/root_ca_certificate", path(ca));
        }
        match tls.identity {
            Some((cert, key)) => {
                set("transport/link/tls/enable_mtls", "true".into());
                set("transport/link/tls/connect_certificate", path(cert));
                set("transport/link/tls/connect_private_key", path(key));
            }
            None => set("transport/link/tls/enable_mtls", "false".into()),
        }
        Self::open_config(c)
    }

    fn open_config(cfg: zenoh::Config) -> Result<Observer, String> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        let session = rt
            .block_on(async { zenoh::open(cfg).await })
            .map_err(|e| e.to_string())?;
        Ok(Observer {
            rt,
            session,
            subscribers: Vec::new(),
            tokens: Vec::new(),
        })
    }

    /// Links (peers and routers) up after up to `wait` (the session keeps retrying).
    pub fn links_after(&self, want: usize, wait: Duration) -> usize {
        let t0 = Instant::now();
        loop {
            let n = self.rt.block_on(async {
                let info = self.session.info();
                info.peers_zid().await.count() + info.routers_zid().await.count()
            });
            if n >= want || t0.elapsed() > wait {
                return n;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Messages received on `key` within `d`.
    pub fn samples(&mut self, key: &str, d: Duration) -> Vec<Heard> {
        self.samples_while(key, d, || {})
    }

    /// Messages received on `key` within `d`, calling `poke` every 100 ms meanwhile (to make
    /// something publish while this session listens).
    pub fn samples_while(&mut self, key: &str, d: Duration, mut poke: impl FnMut()) -> Vec<Heard> {
        let heard = self.record(key);
        let end = Instant::now() + d;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            poke();
            std::thread::sleep(Duration::from_millis(100).min(left));
        }
        // The subscriber goes with the recording.
        self.subscribers.pop();
        let out = std::mem::take(&mut *heard.lock().unwrap_or_else(|p| p.into_inner()));
        out
    }

    /// A fresh goal command to map point (`x`, `y`), stamped by this session.
    pub fn goal_bytes(&self, goal_id: u32, x: f64, y: f64) -> Vec<u8> {
        let st = common::command::CommandStamper::new(operator_station::station::sender_id(
            &self.session,
        ));
        let g = common::msg::GoalCmd {
            goal_id,
            target: common::msg::GoalTarget::Map { x_m: x, y_m: y },
            tolerance_m: 0.0,
        };
        common::msg::encode_cmd(st.next(now_ms()), &g)
    }

    /// Keeps every message on `key_expr` from now on in the returned list.
    pub fn record(&mut self, key_expr: &str) -> std::sync::Arc<std::sync::Mutex<Vec<Heard>>> {
        let heard = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let h = heard.clone();
        let sub = self
            .rt
            .block_on(async {
                self.session
                    .declare_subscriber(key_expr.to_string())
                    .callback(move |s| {
                        h.lock().unwrap().push(Heard {
                            at: Instant::now(),
                            key: s.key_expr().as_str().to_string(),
                            payload: s.payload().to_bytes().to_vec(),
                        })
                    })
                    .await
            })
            .expect("subscriber");
        self.subscribers.push(sub);
        heard
    }

    /// Every tile `robot` serves now, decoded, from its `tile/**` queryable.
    pub fn robot_tiles(&self, robot: &str) -> BTreeMap<TileIndex, Tile> {
        let rid = RobotId::new(robot).expect("robot id");
        self.rt.block_on(async {
            let replies = self
                .session
                .get(keys::robot_tiles(&rid))
                .consolidation(zenoh::query::ConsolidationMode::None)
                .timeout(Duration::from_secs(5))
                .await
                .expect("tile query");
            let mut out = BTreeMap::new();
            while let Ok(r) = replies.recv_async().await {
                if let Ok(s) = r.result() {
                    let t = decode_tile(&s.payload().to_bytes()).expect("robot tiles decode");
                    out.insert(t.index, t);
                }
            }
            out
        })
    }

    /// Declares `robot`'s liveliness token, held as long as this observer: a station sees the
    /// robot online.
    pub fn declare_alive(&mut self, robot: &str) {
        let rid = RobotId::new(robot).expect("robot id");
        let token = self
            .rt
            .block_on(async {
                self.session
                    .liveliness()
                    .declare_token(keys::key(&rid, Topic::Alive))
                    .await
            })
            .expect("liveliness token");
        self.tokens.push(token);
    }

    /// Puts raw bytes on a key.
    pub fn put(&self, key: &str, bytes: Vec<u8>) {
        self.rt.block_on(async {
            self.session
                .put(key, bytes)
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .await
                .expect("put")
        });
    }
}

impl Drop for Observer {
    fn drop(&mut self) {
        let s = self.session.clone();
        let _ = self.rt.block_on(async { s.close().await });
    }
}

/// Cells of a set of tiles by global cell coordinate (`tx * n + col`, `ty * n + row`).
pub fn cells_by_coordinate<'a>(
    tiles: impl IntoIterator<Item = &'a Tile>,
) -> BTreeMap<(i64, i64), Cell> {
    let mut out = BTreeMap::new();
    for t in tiles {
        let n = t.lattice.tile_cells as i64;
        for r in 0..n {
            for c in 0..n {
                let cell = t.cells[(r * n + c) as usize];
                if cell.state != CellState::Unknown {
                    out.insert((t.index.tx as i64 * n + c, t.index.ty as i64 * n + r), cell);
                }
            }
        }
    }
    out
}

/// The station's merged tiles of a datum, read from its database (WAL: safe while it runs).
pub fn stored_tiles(db: &Path, datum: &str) -> Vec<Tile> {
    let c = operator_station::store::open(db).expect("open the station database");
    operator_station::store::tiles(&c, Some(datum))
        .expect("read tiles")
        .into_iter()
        .map(|(_, _, _, _, data)| decode_tile(&data).expect("stored tile decodes"))
        .collect()
}

/// The shared datum of the synthetic robots.
pub const DATUM: Datum = Datum {
    lat_deg: 47.397_71,
    lon_deg: 8.545_61,
    h_m: 488.0,
};

/// A synthetic robot's session on the shared datum.
pub fn session(robot: &str, start_unix_ms: u64) -> Session {
    Session {
        session_id: format!("{robot}-{start_unix_ms}"),
        robot: robot.into(),
        start_unix_ms,
        frame: MapFrame::EnuAtDatum,
        datum: Some(DATUM),
        cell_size_m: 0.2,
        tile_cells: 64,
        source: "test".into(),
        agent_version: "test".into(),
    }
}

/// A tile whose known cells are those for which `f(col, row)` gives a state.
pub fn tile(
    tx: i32,
    ty: i32,
    version: u64,
    stamp_s: u32,
    f: impl Fn(u16, u16) -> Option<CellState>,
) -> Tile {
    let mut t = Tile::new(TileIndex { tx, ty }, Lattice::default());
    t.version = version;
    for r in 0..64u16 {
        for c in 0..64u16 {
            if let Some(state) = f(c, r) {
                *t.get_mut(c, r) = Cell {
                    state,
                    cost: (c % 7) as u8,
                    height_cm: (r as i16) * 2,
                    hits: 3,
                    stamp_s,
                    rev: 0,
                };
            }
        }
    }
    t
}

/// A synthetic robot: the real robot bus (`robot_agent::bus`) on a real Zenoh session, publishing
/// what the test hands it. For what a simulated robot cannot be made to do on cue.
pub fn synthetic_robot(id: &str, endpoint: &str) -> BusHandle {
    let mut cfg = BusConfig::new(RobotId::new(id).expect("valid id"));
    cfg.zenoh = ZenohSettings::connect_to(endpoint);
    BusHandle::start(cfg).expect("open the robot bus")
}

/// Publishes fully traversable tiles `(tx, 0)` for `tx` in `range`.
pub fn publish_tiles(bus: &BusHandle, range: std::ops::Range<i32>, stamp_s: u32) {
    for tx in range {
        let t = tile(tx, 0, 1, stamp_s, |_, _| Some(CellState::Traversable));
        bus.publish_tile(t.index, encode_tile(&t));
    }
}

/// Unix ms now.
pub fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

//! Helpers for the station tests: the station as a real process, a simulated robot on a real
//! Zenoh session (`robot_agent::bus::BusHandle`), synthetic tiles, and a tiny HTTP client.
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::grid::{encode_tile, Cell, CellState, Lattice, Tile, TileIndex};
use common::keys::RobotId;
use common::msg::{Datum, MapFrame, Session};
use robot_agent::bus::{BusConfig, BusHandle, ZenohSettings};

/// A TCP port that was free a moment ago.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("bind an ephemeral port")
}

/// A child killed when dropped.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Proc {
    /// SIGKILL now.
    pub fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Ports of one station.
#[derive(Clone, Copy)]
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

/// Starts `operator-station serve` and waits until it answers HTTP.
pub fn start_station(ports: Ports, db: &Path) -> Proc {
    let mut p = Proc(
        Command::new(env!("CARGO_BIN_EXE_operator-station"))
            .args([
                "serve",
                "--port",
                &ports.http.to_string(),
                "--zenoh-listen",
                &ports.endpoint(),
            ])
            .arg("--db")
            .arg(db)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .expect("start operator-station"),
    );
    let t0 = Instant::now();
    while http(ports.http, "GET", "/api/health", "").is_none() {
        if let Ok(Some(s)) = p.0.try_wait() {
            panic!("station exited: {s}");
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "station did not start"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    p
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
pub fn get_json(port: u16, path: &str) -> serde_json::Value {
    let (st, body) = http(port, "GET", path, "").expect("station answers");
    assert_eq!(st, 200, "{path}: {body}");
    serde_json::from_str(&body).expect("JSON body")
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

/// The shared test datum.
pub const DATUM: Datum = Datum {
    lat_deg: 47.397_71,
    lon_deg: 8.545_61,
    h_m: 488.0,
};

/// A session on the shared datum.
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
                };
            }
        }
    }
    t
}

/// A simulated robot on a real Zenoh session connecting to `endpoint`.
pub fn robot(id: &str, endpoint: &str) -> BusHandle {
    let mut cfg = BusConfig::new(RobotId::new(id).expect("valid id"));
    cfg.zenoh = ZenohSettings::connect_to(endpoint);
    BusHandle::start(cfg).expect("open the robot bus")
}

/// Publishes `n` distinct tiles (tx = 0..n, ty = 0), fully traversable.
pub fn publish_tiles(bus: &BusHandle, range: std::ops::Range<i32>, stamp_s: u32) {
    for tx in range {
        let t = tile(tx, 0, 1, stamp_s, |_, _| Some(CellState::Traversable));
        bus.publish_tile(t.index, encode_tile(&t));
    }
}

/// Number of merged tiles the station reports.
pub fn station_tiles(port: u16) -> u64 {
    http(port, "GET", "/api/health", "")
        .and_then(|(_, b)| serde_json::from_str::<serde_json::Value>(&b).ok())
        .and_then(|v| v["tiles"].as_u64())
        .unwrap_or(0)
}

/// Unix ms now.
pub fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

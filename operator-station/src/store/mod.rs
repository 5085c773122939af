//! SQLite persistence: datums, sessions, tracks (decimated pose history), paths, goals, routes
//! and the merged tiles.
//!
//! WAL mode; every batch of writes is one transaction, so a station killed at any moment
//! restarts with everything up to the last committed batch. Writes are batched on a dedicated
//! thread ([`StoreWriter`]) fed by a channel; reads use their own connection.
//! Schema migrations are numbered by `PRAGMA user_version`.

use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use rusqlite::{params, Connection, OptionalExtension};

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// SQLite error.
    #[error("sqlite: {0}")]
    Sql(#[from] rusqlite::Error),
    /// The database was written by a newer station.
    #[error("database schema version {0} is newer than this station ({SCHEMA_VERSION})")]
    TooNew(i64),
}

/// Current schema version (`PRAGMA user_version`).
pub const SCHEMA_VERSION: i64 = 3;

const MIGRATIONS: &[&str] = &[
    // 0 -> 1
    "CREATE TABLE datums (
        datum_id TEXT PRIMARY KEY, lat_deg REAL, lon_deg REAL, h_m REAL,
        cell_size_m REAL NOT NULL, tile_cells INTEGER NOT NULL);
     CREATE TABLE sessions (
        session_id TEXT PRIMARY KEY, robot TEXT NOT NULL, start_unix_ms INTEGER NOT NULL,
        last_unix_ms INTEGER NOT NULL, datum_id TEXT NOT NULL, source TEXT NOT NULL, json TEXT NOT NULL);
     CREATE INDEX sessions_robot ON sessions(robot, start_unix_ms);
     CREATE TABLE track (
        session_id TEXT NOT NULL, t_unix_ms INTEGER NOT NULL, x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL);
     CREATE INDEX track_session ON track(session_id, t_unix_ms);
     CREATE TABLE paths (
        session_id TEXT NOT NULL, robot TEXT NOT NULL, t_unix_ms INTEGER NOT NULL, goal_id INTEGER NOT NULL, json TEXT NOT NULL);
     CREATE TABLE goals (
        id INTEGER PRIMARY KEY AUTOINCREMENT, robot TEXT NOT NULL, t_unix_ms INTEGER NOT NULL, goal_id INTEGER NOT NULL, json TEXT NOT NULL);
     CREATE TABLE routes (
        route_id TEXT PRIMARY KEY, name TEXT NOT NULL, robot TEXT NOT NULL, session_id TEXT NOT NULL,
        datum_id TEXT, points INTEGER NOT NULL, length_m REAL NOT NULL, json TEXT NOT NULL);
     CREATE TABLE tiles (
        datum_id TEXT NOT NULL, tx INTEGER NOT NULL, ty INTEGER NOT NULL, version INTEGER NOT NULL,
        data BLOB NOT NULL, PRIMARY KEY (datum_id, tx, ty));",
    // 1 -> 2: the operator's zones, missions and alerts (JSON of `zones::ZoneRecord`,
    // `missions::Mission`, `alerts::Alert`).
    "CREATE TABLE zones (zone_id TEXT PRIMARY KEY, json TEXT NOT NULL);
     CREATE TABLE alerts (id INTEGER PRIMARY KEY, json TEXT NOT NULL);
     CREATE TABLE missions (mission_id TEXT PRIMARY KEY, name TEXT NOT NULL, saved_unix_ms INTEGER NOT NULL, json TEXT NOT NULL);",
    // 2 -> 3: the merged map's history, one version per tile per history period (`bucket`, the
    // last one in it), for scrubbing past sessions (`crate::history`).
    "CREATE TABLE tile_history (
        datum_id TEXT NOT NULL, tx INTEGER NOT NULL, ty INTEGER NOT NULL, bucket INTEGER NOT NULL,
        t_unix_ms INTEGER NOT NULL, data BLOB NOT NULL, PRIMARY KEY (datum_id, tx, ty, bucket));
     CREATE INDEX tile_history_time ON tile_history(datum_id, t_unix_ms);",
];

/// Opens (creating and migrating) a database with WAL and a busy timeout.
pub fn open(path: &Path) -> Result<Connection, StoreError> {
    let mut c = Connection::open(path)?;
    c.busy_timeout(Duration::from_secs(5))?;
    c.pragma_update(None, "journal_mode", "WAL")?;
    // NORMAL with WAL: a crash loses at most the last transactions, never corrupts.
    c.pragma_update(None, "synchronous", "NORMAL")?;
    let v: i64 = c.pragma_query_value(None, "user_version", |r| r.get(0))?;
    if v > SCHEMA_VERSION {
        return Err(StoreError::TooNew(v));
    }
    for (i, m) in MIGRATIONS.iter().enumerate().skip(v as usize) {
        let tx = c.transaction()?;
        tx.execute_batch(m)?;
        tx.pragma_update(None, "user_version", (i + 1) as i64)?;
        tx.commit()?;
    }
    Ok(c)
}

/// A datum as stored.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DatumRow {
    /// Id, e.g. `d0` or `local-<session>`.
    pub datum_id: String,
    /// Latitude, degrees (None for local frames).
    pub lat_deg: Option<f64>,
    /// Longitude, degrees.
    pub lon_deg: Option<f64>,
    /// Height, metres.
    pub h_m: Option<f64>,
    /// Cell size, metres.
    pub cell_size_m: f32,
    /// Cells per tile side.
    pub tile_cells: u16,
}

/// A session as listed by the API.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SessionRow {
    /// Session id.
    pub session_id: String,
    /// Robot.
    pub robot: String,
    /// Start, Unix ms.
    pub start_unix_ms: u64,
    /// Last message, Unix ms.
    pub last_unix_ms: u64,
    /// Datum.
    pub datum_id: String,
    /// `sim:<scenario>` or `real`.
    pub source: String,
}

/// When a merged tile version enters the map history.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HistoryStamp {
    /// History period ([`crate::history::bucket`]).
    pub bucket: u64,
    /// When the merge made this version, Unix ms.
    pub t_unix_ms: u64,
}

/// A route summary as listed by the API.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RouteRow {
    /// Route id.
    pub route_id: String,
    /// Name.
    pub name: String,
    /// Robot that recorded it.
    pub robot: String,
    /// Session.
    pub session_id: String,
    /// Datum (None for imported routes without one).
    pub datum_id: Option<String>,
    /// Number of points.
    pub points: u32,
    /// Length, metres.
    pub length_m: f64,
}

/// One write.
#[derive(Clone, Debug)]
pub enum StoreOp {
    /// Insert or replace a datum.
    Datum(DatumRow),
    /// Insert or update a session (keeps the first start time).
    Session {
        /// The row.
        row: SessionRow,
        /// The `common::msg::Session` JSON.
        json: String,
    },
    /// Update a session's last-seen time.
    SessionSeen {
        /// Session id.
        session_id: String,
        /// Unix ms.
        last_unix_ms: u64,
    },
    /// One decimated track point.
    Track {
        /// Session id.
        session_id: String,
        /// Unix ms.
        t_unix_ms: u64,
        /// Map x, m.
        x: f64,
        /// Map y, m.
        y: f64,
        /// Yaw, rad.
        yaw: f64,
    },
    /// A planned path.
    Path {
        /// Session.
        session_id: String,
        /// Robot.
        robot: String,
        /// Unix ms.
        t_unix_ms: u64,
        /// Goal id.
        goal_id: u32,
        /// Points JSON.
        json: String,
    },
    /// A goal sent by the station.
    Goal {
        /// Robot.
        robot: String,
        /// Unix ms.
        t_unix_ms: u64,
        /// Goal id.
        goal_id: u32,
        /// GoalCmd JSON.
        json: String,
    },
    /// A route (summary + full `common::msg::Route` JSON).
    Route {
        /// Summary.
        row: RouteRow,
        /// Route JSON.
        json: String,
    },
    /// A merged tile (encoded with `common::grid::encode_tile`, version = station version), and
    /// with `history` also into the history, where it replaces the tile's version of the same
    /// period: one payload, written to both tables in one transaction.
    Tile {
        /// Datum.
        datum_id: String,
        /// Column.
        tx: i32,
        /// Row.
        ty: i32,
        /// Station version.
        version: u64,
        /// Encoded tile.
        data: Vec<u8>,
        /// The history period and time of this version, when the station keeps a history.
        history: Option<HistoryStamp>,
    },
    /// Insert or replace a zone (`zones::ZoneRecord` JSON).
    Zone {
        /// Id.
        zone_id: String,
        /// JSON.
        json: String,
    },
    /// Delete a zone.
    DeleteZone(String),
    /// Insert or replace a mission (`missions::Mission` JSON).
    Mission {
        /// Id.
        mission_id: String,
        /// Name.
        name: String,
        /// Unix ms.
        saved_unix_ms: u64,
        /// JSON.
        json: String,
    },
    /// Delete a mission.
    DeleteMission(String),
    /// Insert or replace an alert (`alerts::Alert` JSON).
    Alert {
        /// Id.
        id: u64,
        /// JSON.
        json: String,
    },
    /// Commit now and acknowledge (tests, shutdown).
    Flush(mpsc::Sender<()>),
    /// Commit and stop the writer thread.
    Shutdown,
}

fn apply(tx: &rusqlite::Transaction<'_>, op: &StoreOp) -> rusqlite::Result<()> {
    match op {
        StoreOp::Datum(d) => {
            tx.execute(
                "INSERT OR REPLACE INTO datums VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![
                    d.datum_id,
                    d.lat_deg,
                    d.lon_deg,
                    d.h_m,
                    d.cell_size_m as f64,
                    d.tile_cells
                ],
            )?;
        }
        StoreOp::Session { row, json } => {
            tx.execute(
                "INSERT INTO sessions VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)
                 ON CONFLICT(session_id) DO UPDATE SET last_unix_ms = max(last_unix_ms, excluded.last_unix_ms),
                   datum_id = excluded.datum_id, json = excluded.json",
                params![
                    row.session_id,
                    row.robot,
                    row.start_unix_ms as i64,
                    row.last_unix_ms as i64,
                    row.datum_id,
                    row.source,
                    json
                ],
            )?;
        }
        StoreOp::SessionSeen {
            session_id,
            last_unix_ms,
        } => {
            tx.execute(
                "UPDATE sessions SET last_unix_ms = max(last_unix_ms, ?2) WHERE session_id = ?1",
                params![session_id, *last_unix_ms as i64],
            )?;
        }
        StoreOp::Track {
            session_id,
            t_unix_ms,
            x,
            y,
            yaw,
        } => {
            tx.execute(
                "INSERT INTO track VALUES (?1, ?2, ?3, ?4, ?5)",
                params![session_id, *t_unix_ms as i64, x, y, yaw],
            )?;
        }
        StoreOp::Path {
            session_id,
            robot,
            t_unix_ms,
            goal_id,
            json,
        } => {
            tx.execute(
                "INSERT INTO paths VALUES (?1, ?2, ?3, ?4, ?5)",
                params![session_id, robot, *t_unix_ms as i64, goal_id, json],
            )?;
        }
        StoreOp::Goal {
            robot,
            t_unix_ms,
            goal_id,
            json,
        } => {
            tx.execute(
                "INSERT INTO goals (robot, t_unix_ms, goal_id, json) VALUES (?1, ?2, ?3, ?4)",
                params![robot, *t_unix_ms as i64, goal_id, json],
            )?;
        }
        StoreOp::Route { row, json } => {
            tx.execute(
                "INSERT OR REPLACE INTO routes VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
                params![
                    row.route_id,
                    row.name,
                    row.robot,
                    row.session_id,
                    row.datum_id,
                    row.points,
                    row.length_m,
                    json
                ],
            )?;
        }
        StoreOp::Tile {
            datum_id,
            tx: x,
            ty,
            version,
            data,
            history,
        } => {
            tx.execute(
                "INSERT OR REPLACE INTO tiles VALUES (?1, ?2, ?3, ?4, ?5)",
                params![datum_id, x, ty, *version as i64, data],
            )?;
            if let Some(h) = history {
                tx.execute(
                    "INSERT INTO tile_history VALUES (?1, ?2, ?3, ?4, ?5, ?6)
                     ON CONFLICT (datum_id, tx, ty, bucket)
                     DO UPDATE SET t_unix_ms = excluded.t_unix_ms, data = excluded.data",
                    params![datum_id, x, ty, h.bucket as i64, h.t_unix_ms as i64, data],
                )?;
            }
        }
        StoreOp::Zone { zone_id, json } => {
            tx.execute(
                "INSERT OR REPLACE INTO zones VALUES (?1, ?2)",
                params![zone_id, json],
            )?;
        }
        StoreOp::DeleteZone(id) => {
            tx.execute("DELETE FROM zones WHERE zone_id = ?1", params![id])?;
        }
        StoreOp::Mission {
            mission_id,
            name,
            saved_unix_ms,
            json,
        } => {
            tx.execute(
                "INSERT OR REPLACE INTO missions VALUES (?1, ?2, ?3, ?4)",
                params![mission_id, name, *saved_unix_ms as i64, json],
            )?;
        }
        StoreOp::DeleteMission(id) => {
            tx.execute("DELETE FROM missions WHERE mission_id = ?1", params![id])?;
        }
        StoreOp::Alert { id, json } => {
            tx.execute(
                "INSERT OR REPLACE INTO alerts VALUES (?1, ?2)",
                params![*id as i64, json],
            )?;
        }
        StoreOp::Flush(_) | StoreOp::Shutdown => {}
    }
    Ok(())
}

/// Longest a write waits before its batch is committed.
pub const BATCH_WINDOW: Duration = Duration::from_millis(100);
/// Largest batch.
pub const BATCH_MAX: usize = 2000;

/// The write thread.
pub struct StoreWriter {
    tx: mpsc::Sender<StoreOp>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl StoreWriter {
    /// Starts the writer on its own connection.
    pub fn start(path: &Path) -> Result<Self, StoreError> {
        let mut conn = open(path)?;
        let (tx, rx) = mpsc::channel::<StoreOp>();
        let thread = std::thread::Builder::new()
            .name("store".into())
            .spawn(move || {
                while let Ok(first) = rx.recv() {
                    let mut batch = vec![first];
                    let deadline = Instant::now() + BATCH_WINDOW;
                    while batch.len() < BATCH_MAX
                        && !matches!(batch.last(), Some(StoreOp::Flush(_) | StoreOp::Shutdown))
                    {
                        let left = deadline.saturating_duration_since(Instant::now());
                        match rx.recv_timeout(left) {
                            Ok(op) => batch.push(op),
                            Err(_) => break,
                        }
                    }
                    if let Err(e) = write_batch(&mut conn, &batch) {
                        tracing::error!("store: batch of {} writes failed: {e}", batch.len());
                    }
                    let mut stop = false;
                    for op in &batch {
                        match op {
                            StoreOp::Flush(ack) => {
                                let _ = ack.send(());
                            }
                            StoreOp::Shutdown => stop = true,
                            _ => {}
                        }
                    }
                    if stop {
                        break;
                    }
                }
            })
            .expect("spawn the store thread");
        Ok(Self {
            tx,
            thread: Some(thread),
        })
    }

    /// A sender for writes.
    pub fn sender(&self) -> mpsc::Sender<StoreOp> {
        self.tx.clone()
    }

    /// Commits everything queued so far and waits for it.
    pub fn flush(&self) {
        let (ack, done) = mpsc::channel();
        if self.tx.send(StoreOp::Flush(ack)).is_ok() {
            let _ = done.recv_timeout(Duration::from_secs(10));
        }
    }

    /// Commits the queue and stops.
    pub fn finish(mut self) {
        let _ = self.tx.send(StoreOp::Shutdown);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn write_batch(conn: &mut Connection, batch: &[StoreOp]) -> rusqlite::Result<()> {
    let tx = conn.transaction()?;
    for op in batch {
        apply(&tx, op)?;
    }
    tx.commit()
}

/// Every datum.
pub fn datums(c: &Connection) -> Result<Vec<DatumRow>, StoreError> {
    let mut st = c.prepare(
        "SELECT datum_id, lat_deg, lon_deg, h_m, cell_size_m, tile_cells FROM datums ORDER BY datum_id",
    )?;
    let rows = st
        .query_map([], |r| {
            Ok(DatumRow {
                datum_id: r.get(0)?,
                lat_deg: r.get(1)?,
                lon_deg: r.get(2)?,
                h_m: r.get(3)?,
                cell_size_m: r.get::<_, f64>(4)? as f32,
                tile_cells: r.get(5)?,
            })
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// A stored merged tile: (datum, tx, ty, version, encoded).
pub type TileRow = (String, i32, i32, u64, Vec<u8>);

/// Every stored merged tile, optionally of one datum.
pub fn tiles(c: &Connection, datum_id: Option<&str>) -> Result<Vec<TileRow>, StoreError> {
    let mut st = c.prepare(
        "SELECT datum_id, tx, ty, version, data FROM tiles WHERE ?1 IS NULL OR datum_id = ?1 ORDER BY datum_id, tx, ty",
    )?;
    let rows = st
        .query_map(params![datum_id], |r| {
            Ok((
                r.get(0)?,
                r.get(1)?,
                r.get(2)?,
                r.get::<_, i64>(3)? as u64,
                r.get(4)?,
            ))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// The newest history stamp of `datum_id` at or before `t_unix_ms` (None: no map then).
pub fn history_key(
    c: &Connection,
    datum_id: &str,
    t_unix_ms: u64,
) -> Result<Option<u64>, StoreError> {
    let t: Option<i64> = c.query_row(
        "SELECT MAX(t_unix_ms) FROM tile_history WHERE datum_id = ?1 AND t_unix_ms <= ?2",
        params![datum_id, t_unix_ms as i64],
        |r| r.get(0),
    )?;
    Ok(t.map(|t| t as u64))
}

/// The merged map of `datum_id` as it was at `t_unix_ms`: each tile's newest history version
/// stamped at or before then, as (datum, tx, ty, stamp Unix ms, encoded).
pub fn tiles_at(
    c: &Connection,
    datum_id: &str,
    t_unix_ms: u64,
) -> Result<Vec<TileRow>, StoreError> {
    let mut st = c.prepare(
        "SELECT tx, ty, t_unix_ms, data FROM (
            SELECT tx, ty, t_unix_ms, data,
                   ROW_NUMBER() OVER (PARTITION BY tx, ty ORDER BY t_unix_ms DESC) AS newest
            FROM tile_history WHERE datum_id = ?1 AND t_unix_ms <= ?2)
         WHERE newest = 1",
    )?;
    let rows = st
        .query_map(params![datum_id, t_unix_ms as i64], |r| {
            Ok((
                datum_id.to_string(),
                r.get(0)?,
                r.get(1)?,
                r.get::<_, i64>(2)? as u64,
                r.get(3)?,
            ))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// What the history of `datum_id` holds: (first stamp, last stamp, rows, bytes), None if empty.
pub fn history_span(
    c: &Connection,
    datum_id: &str,
) -> Result<Option<(u64, u64, u64, u64)>, StoreError> {
    let row: (Option<i64>, Option<i64>, i64, Option<i64>) = c.query_row(
        "SELECT MIN(t_unix_ms), MAX(t_unix_ms), COUNT(*), SUM(LENGTH(data))
         FROM tile_history WHERE datum_id = ?1",
        params![datum_id],
        |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
    )?;
    Ok(match row {
        (Some(a), Some(b), n, bytes) => {
            Some((a as u64, b as u64, n as u64, bytes.unwrap_or(0) as u64))
        }
        _ => None,
    })
}

fn session_row(r: &rusqlite::Row<'_>) -> rusqlite::Result<SessionRow> {
    Ok(SessionRow {
        session_id: r.get(0)?,
        robot: r.get(1)?,
        start_unix_ms: r.get::<_, i64>(2)? as u64,
        last_unix_ms: r.get::<_, i64>(3)? as u64,
        datum_id: r.get(4)?,
        source: r.get(5)?,
    })
}

/// Sessions, newest first, optionally of one robot.
pub fn sessions(c: &Connection, robot: Option<&str>) -> Result<Vec<SessionRow>, StoreError> {
    let mut st = c.prepare(
        "SELECT session_id, robot, start_unix_ms, last_unix_ms, datum_id, source FROM sessions
         WHERE ?1 IS NULL OR robot = ?1 ORDER BY start_unix_ms DESC, session_id",
    )?;
    let rows = st
        .query_map(params![robot], session_row)?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// One session.
pub fn session(c: &Connection, session_id: &str) -> Result<Option<SessionRow>, StoreError> {
    Ok(c.query_row(
        "SELECT session_id, robot, start_unix_ms, last_unix_ms, datum_id, source FROM sessions WHERE session_id = ?1",
        params![session_id],
        session_row,
    )
    .optional()?)
}

/// Track points of a session: (t_unix_ms, x, y, yaw).
pub fn track(c: &Connection, session_id: &str) -> Result<Vec<(u64, f64, f64, f64)>, StoreError> {
    let mut st = c.prepare(
        "SELECT t_unix_ms, x, y, yaw FROM track WHERE session_id = ?1 ORDER BY t_unix_ms",
    )?;
    let rows = st
        .query_map(params![session_id], |r| {
            Ok((r.get::<_, i64>(0)? as u64, r.get(1)?, r.get(2)?, r.get(3)?))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// The paths a session published: (t_unix_ms, goal_id, `Path` JSON), oldest first.
pub fn paths(c: &Connection, session_id: &str) -> Result<Vec<(u64, u32, String)>, StoreError> {
    let mut st = c.prepare(
        "SELECT t_unix_ms, goal_id, json FROM paths WHERE session_id = ?1 ORDER BY t_unix_ms",
    )?;
    let rows = st
        .query_map(params![session_id], |r| {
            Ok((r.get::<_, i64>(0)? as u64, r.get(1)?, r.get(2)?))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// The goals sent to `robot` within `[t0, t1]` Unix ms: (t_unix_ms, goal_id, `GoalCmd` JSON).
pub fn goals(
    c: &Connection,
    robot: &str,
    t0_unix_ms: u64,
    t1_unix_ms: u64,
) -> Result<Vec<(u64, u32, String)>, StoreError> {
    let mut st = c.prepare(
        "SELECT t_unix_ms, goal_id, json FROM goals WHERE robot = ?1 AND t_unix_ms BETWEEN ?2 AND ?3 ORDER BY t_unix_ms, id",
    )?;
    let rows = st
        .query_map(params![robot, t0_unix_ms as i64, t1_unix_ms as i64], |r| {
            Ok((r.get::<_, i64>(0)? as u64, r.get(1)?, r.get(2)?))
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// The routes taught in a session: `Route` JSON.
pub fn session_routes(c: &Connection, session_id: &str) -> Result<Vec<String>, StoreError> {
    let mut st = c.prepare("SELECT json FROM routes WHERE session_id = ?1 ORDER BY route_id")?;
    let rows = st
        .query_map(params![session_id], |r| r.get(0))?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// Route summaries.
pub fn routes(c: &Connection) -> Result<Vec<RouteRow>, StoreError> {
    let mut st = c.prepare(
        "SELECT route_id, name, robot, session_id, datum_id, points, length_m FROM routes ORDER BY route_id",
    )?;
    let rows = st
        .query_map([], |r| {
            Ok(RouteRow {
                route_id: r.get(0)?,
                name: r.get(1)?,
                robot: r.get(2)?,
                session_id: r.get(3)?,
                datum_id: r.get(4)?,
                points: r.get(5)?,
                length_m: r.get(6)?,
            })
        })?
        .collect::<Result<Vec<_>, _>>()?;
    Ok(rows)
}

/// A route's full JSON.
pub fn route_json(c: &Connection, route_id: &str) -> Result<Option<String>, StoreError> {
    Ok(c.query_row(
        "SELECT json FROM routes WHERE route_id = ?1",
        params![route_id],
        |r| r.get(0),
    )
    .optional()?)
}

/// Every stored zone's JSON.
pub fn zones(c: &Connection) -> Result<Vec<String>, StoreError> {
    let mut st = c.prepare("SELECT json FROM zones ORDER BY zone_id")?;
    let rows = st
        .query_map([], |r| r.get(0))?
        .collect::<Result<Vec<String>, _>>()?;
    Ok(rows)
}

/// The newest `limit` stored alerts' JSON, oldest first.
pub fn alerts(c: &Connection, limit: usize) -> Result<Vec<String>, StoreError> {
    let mut st = c.prepare(
        "SELECT json FROM (SELECT id, json FROM alerts ORDER BY id DESC LIMIT ?1) ORDER BY id",
    )?;
    let rows = st
        .query_map(params![limit as i64], |r| r.get(0))?
        .collect::<Result<Vec<String>, _>>()?;
    Ok(rows)
}

/// Every stored mission's JSON, newest first.
pub fn missions(c: &Connection) -> Result<Vec<String>, StoreError> {
    let mut st = c.prepare("SELECT json FROM missions ORDER BY saved_unix_ms DESC, mission_id")?;
    let rows = st
        .query_map([], |r| r.get(0))?
        .collect::<Result<Vec<String>, _>>()?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn migrates_once_and_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.db");
        let w = StoreWriter::start(&p).unwrap();
        let tx = w.sender();
        tx.send(StoreOp::Datum(DatumRow {
            datum_id: "d0".into(),
            lat_deg: Some(47.0),
            lon_deg: Some(8.0),
            h_m: Some(400.0),
            cell_size_m: 0.2,
            tile_cells: 64,
        }))
        .unwrap();
        tx.send(StoreOp::Tile {
            datum_id: "d0".into(),
            tx: -1,
            ty: 2,
            version: 3,
            data: vec![1, 2, 3],
            history: None,
        })
        .unwrap();
        w.finish();
        // Reopening does not migrate again and finds the rows.
        let c = open(&p).unwrap();
        let v: i64 = c
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .unwrap();
        assert_eq!(v, SCHEMA_VERSION);
        assert_eq!(datums(&c).unwrap().len(), 1);
        assert_eq!(
            tiles(&c, Some("d0")).unwrap(),
            vec![("d0".to_string(), -1, 2, 3, vec![1, 2, 3])]
        );
        let mode: String = c
            .pragma_query_value(None, "journal_mode", |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
    }

    #[test]
    fn the_history_keeps_one_version_per_period_and_answers_for_any_time() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.db");
        let w = StoreWriter::start(&p).unwrap();
        let tx = w.sender();
        let put = |t: i32, bucket: u64, t_ms: u64, byte: u8| {
            tx.send(StoreOp::Tile {
                datum_id: "d0".into(),
                tx: t,
                ty: 0,
                version: 1,
                data: vec![byte],
                history: Some(HistoryStamp {
                    bucket,
                    t_unix_ms: t_ms,
                }),
            })
            .unwrap();
        };
        put(0, 1, 60_500, 1);
        put(0, 1, 61_000, 2); // same period: replaces the version above
        put(0, 2, 125_000, 3);
        put(1, 2, 130_000, 4);
        w.finish();
        let c = open(&p).unwrap();
        let at = |t: u64| {
            tiles_at(&c, "d0", t)
                .unwrap()
                .into_iter()
                .map(|(_, tx, _, t_ms, d)| (tx, t_ms, d[0]))
                .collect::<Vec<_>>()
        };
        assert_eq!(at(60_000), vec![]);
        assert_eq!(at(100_000), vec![(0, 61_000, 2)]);
        assert_eq!(at(127_000), vec![(0, 125_000, 3)]);
        let mut now = at(200_000);
        now.sort();
        assert_eq!(now, vec![(0, 125_000, 3), (1, 130_000, 4)]);
        assert_eq!(history_key(&c, "d0", 127_000).unwrap(), Some(125_000));
        assert_eq!(history_key(&c, "d0", 10).unwrap(), None);
        assert_eq!(
            history_span(&c, "d0").unwrap(),
            Some((61_000, 130_000, 3, 3))
        );
        assert_eq!(history_span(&c, "d1").unwrap(), None);
    }

    #[test]
    fn newer_schema_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.db");
        let c = open(&p).unwrap();
        c.pragma_update(None, "user_version", 99).unwrap();
        drop(c);
        assert!(matches!(open(&p), Err(StoreError::TooNew(99))));
    }
}

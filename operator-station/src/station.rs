//! The station's wiring: handles what its bus ([`crate::bus`]) hears on `terranav/**`, tracks
//! liveliness, resyncs late or reconnecting robots through their queryables, feeds the merge
//! thread and the store thread, and broadcasts live events for the WebSocket. Every command it sends carries a
//! header from its [`CommandStamper`]. Its Zenoh session can be re-opened with a new config
//! ([`Station::reopen`]: new access rules after an issue or revocation) while everything else
//! runs on.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex, RwLock};
use std::time::{Duration, Instant};

use common::command::CommandStamper;
use common::grid::Lattice;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, CmdHeader, Datum, Path, Pose, Route, Session, Status};
use serde_json::json;
use tokio::sync::broadcast;

use crate::alerts::{AlertConfig, AlertKind, Alerts, Observation};
use crate::fleet::{Fleet, RateTopic, MAX_PENDING_TILES};
use crate::merge::restore::{restore_from_db, RestoreProgress};
use crate::merge::{MergeJob, MergeQueue, MergeWorker, MergedMap, TileChange};
use crate::missions::runner::{RobotNow, Run, RunAction};
use crate::missions::Mission;
use crate::store::{self, DatumRow, RouteRow, SessionRow, StoreOp, StoreWriter};
use crate::zones::{zone_set_for, ZoneRecord};

pub use crate::bus::{sender_id, zenoh_config, DEFAULT_LISTEN_ENDPOINT};

/// Version of the station.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// Why the station failed to start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StationError {
    /// Zenoh config or session error.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// Database error.
    #[error(transparent)]
    Store(#[from] store::StoreError),
}

/// Unix time now, milliseconds.
pub fn now_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// Options of a running station.
#[derive(Clone, Debug)]
pub struct StationOptions {
    /// Zenoh config.
    pub zenoh: zenoh::Config,
    /// Database file.
    pub db: PathBuf,
    /// What raises alerts.
    pub alerts: AlertConfig,
    /// History period of the merged map, seconds: each tile keeps its last version of every
    /// period, so a past session can be scrubbed with its map (0: no history).
    pub map_history_s: u32,
}

/// The operator's zones and the version of the set (Unix ms of the last change, so it grows
/// across restarts too).
#[derive(Clone, Debug, Default)]
pub struct ZoneBook {
    /// The zones.
    pub records: Vec<ZoneRecord>,
    /// Version of the set.
    pub version: u64,
}

/// How often the station looks at every robot for alerts and advances mission runs.
pub const WATCH_PERIOD: Duration = Duration::from_millis(250);

/// Known datums (ids stable across restarts through the store).
#[derive(Clone, Debug, Default)]
pub struct Datums {
    /// By id.
    pub rows: BTreeMap<String, DatumRow>,
}

impl Datums {
    /// The id of a session's datum, creating it if new. Returns (id, newly created).
    pub fn assign(&mut self, s: &Session) -> (String, bool) {
        let lattice = (s.cell_size_m, s.tile_cells);
        if let Some(d) = s.datum {
            for row in self.rows.values() {
                if let (Some(la), Some(lo), Some(h)) = (row.lat_deg, row.lon_deg, row.h_m) {
                    if (la - d.lat_deg).abs() < 1e-9
                        && (lo - d.lon_deg).abs() < 1e-9
                        && (h - d.h_m).abs() < 1e-3
                        && (row.cell_size_m, row.tile_cells) == lattice
                    {
                        return (row.datum_id.clone(), false);
                    }
                }
            }
            let n = self.rows.values().filter(|r| r.lat_deg.is_some()).count();
            let mut i = n;
            let id = loop {
                let id = format!("d{i}");
                if !self.rows.contains_key(&id) {
                    break id;
                }
                i += 1;
            };
            self.insert(&id, Some(d), lattice);
            (id, true)
        } else {
            let id = format!("local-{}", s.session_id);
            if self.rows.contains_key(&id) {
                return (id, false);
            }
            self.insert(&id, None, lattice);
            (id, true)
        }
    }

    fn insert(&mut self, id: &str, d: Option<Datum>, lattice: (f32, u16)) {
        self.rows.insert(
            id.to_string(),
            DatumRow {
                datum_id: id.to_string(),
                lat_deg: d.map(|d| d.lat_deg),
                lon_deg: d.map(|d| d.lon_deg),
                h_m: d.map(|d| d.h_m),
                cell_size_m: lattice.0,
                tile_cells: lattice.1,
            },
        );
    }

    /// The datum as WGS-84, when it has one.
    pub fn geodetic(&self, id: &str) -> Option<Datum> {
        let r = self.rows.get(id)?;
        Some(Datum {
            lat_deg: r.lat_deg?,
            lon_deg: r.lon_deg?,
            h_m: r.h_m.unwrap_or(0.0),
        })
    }
}

/// Shared state of a running station.
pub struct Inner {
    /// Zenoh session (replaced by [`Station::reopen`]; use [`Inner::session`]).
    session: RwLock<zenoh::Session>,
    /// Robots.
    pub fleet: Mutex<Fleet>,
    /// Datums.
    pub datums: Mutex<Datums>,
    /// Merged map.
    pub map: Arc<RwLock<MergedMap>>,
    /// How far putting the stored merged map back has come (the map is partial until finished).
    pub restore: Arc<RestoreProgress>,
    /// Overview tiles of the merged map for the browser (rebuilt as the merge changes tiles).
    pub pyramid: Arc<Mutex<crate::pyramid::Pyramid>>,
    /// Live events (JSON text) for WebSocket clients.
    pub events: broadcast::Sender<Arc<str>>,
    /// Payloads on robot keys that failed to decode.
    pub decode_errors: Arc<AtomicU64>,
    /// Database file (readers open their own connection).
    pub db: PathBuf,
    store_tx: Mutex<mpsc::Sender<StoreOp>>,
    merge_tx: MergeQueue,
    /// Next goal id.
    pub goal_seq: AtomicU32,
    /// Next drive sequence number.
    pub drive_seq: AtomicU32,
    /// Stamps every command this station sends (sender id, sequence, time).
    pub stamper: CommandStamper,
    reader: Mutex<Option<rusqlite::Connection>>,
    /// Keep-out and slow zones.
    pub zones: Mutex<ZoneBook>,
    /// Saved missions by id.
    pub missions: Mutex<BTreeMap<String, Mission>>,
    /// Mission runs by robot (the last one of each robot, also when it ended).
    pub runs: Mutex<BTreeMap<String, Run>>,
    /// The goal or stop sent to each robot through the API that its status has not shown yet
    /// ([`crate::deliveries`]).
    pub deliveries: Mutex<BTreeMap<String, crate::deliveries::Pending>>,
    /// The alert list.
    pub alerts: Mutex<Alerts>,
    /// History period of the merged map, seconds (0: none kept).
    pub map_history_s: u32,
    /// Past maps recently drawn (scrubbing).
    pub history: crate::history::SnapshotCache,
}

/// A running station.
pub struct Station {
    /// Shared state.
    pub inner: Arc<Inner>,
    merge: Option<MergeWorker>,
    store: Option<StoreWriter>,
    subs: Vec<Box<dyn std::any::Any + Send + Sync>>,
}

fn robot_event(r: &str, online: bool, t: u64) -> String {
    json!({"type": "robot", "robot": r, "online": online, "last_seen_unix_ms": t}).to_string()
}

impl Inner {
    /// The station's Zenoh session now.
    pub fn session(&self) -> zenoh::Session {
        self.session
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// The header of a command sent now.
    pub fn cmd_header(&self) -> CmdHeader {
        self.stamper.next(now_unix_ms())
    }

    /// Sends a live event to every WebSocket client.
    pub fn emit(&self, s: String) {
        let _ = self.events.send(Arc::from(s));
    }

    /// Queues a store write.
    pub fn store(&self, op: StoreOp) {
        let _ = self
            .store_tx
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .send(op);
    }

    fn merge(&self, job: MergeJob) {
        self.merge_tx.send(job);
    }

    /// Runs `f` with the read connection (opened on first use).
    pub fn read<T>(
        &self,
        f: impl FnOnce(&rusqlite::Connection) -> Result<T, store::StoreError>,
    ) -> Result<T, store::StoreError> {
        let mut g = self.reader.lock().unwrap_or_else(|p| p.into_inner());
        if g.is_none() {
            *g = Some(store::open(&self.db)?);
        }
        match g.as_ref() {
            Some(c) => f(c),
            None => unreachable!("opened above"),
        }
    }

    fn decode_error(&self, key: &str, e: impl std::fmt::Display) {
        self.decode_errors.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(key, "undecodable payload: {e}");
    }

    /// Handles one sample from `terranav/**`.
    pub fn on_sample(self: &Arc<Self>, key: &str, payload: &[u8]) {
        let Ok((robot, topic)) = keys::parse(key) else {
            // Not ours to judge (e.g. another application's key); count only robot keys.
            if key.starts_with("terranav/") {
                self.decode_error(key, "unknown key");
            }
            return;
        };
        let rid = robot.as_str().to_string();
        let now = Instant::now();
        let now_ms = now_unix_ms();
        match topic {
            Topic::Session => match msg::decode::<Session>(payload) {
                Ok(s) if s.robot == rid => self.on_session(&rid, s, now_ms),
                Ok(s) => self.decode_error(
                    key,
                    format!("session of robot {} on another robot's key", s.robot),
                ),
                Err(e) => self.decode_error(key, e),
            },
            Topic::Pose => match msg::decode::<Pose>(payload) {
                Ok(p) => self.on_pose(&rid, p, now, now_ms),
                Err(e) => self.decode_error(key, e),
            },
            Topic::Status => match msg::decode::<Status>(payload) {
                Ok(s) => self.on_status(&rid, s, now, now_ms),
                Err(e) => self.decode_error(key, e),
            },
            Topic::Path => match msg::decode::<Path>(payload) {
                Ok(p) => self.on_path(&rid, p, now, now_ms),
                Err(e) => self.decode_error(key, e),
            },
            Topic::Route => match msg::decode::<Route>(payload) {
                Ok(r) => self.on_route(&rid, r),
                Err(e) => self.decode_error(key, e),
            },
            Topic::Tile { tx, ty } => {
                // No decoding here (the network task): the merge pool decodes each tile once and
                // checks it against its key; a bad one is counted there.
                let key_index = common::grid::TileIndex { tx, ty };
                let datum = {
                    let mut f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
                    let r = f.robot(&rid);
                    r.hit(RateTopic::Tile, now, now_ms);
                    match r.datum_id.clone() {
                        Some(d) => Some(d),
                        None => {
                            if r.pending_tiles.len() < MAX_PENDING_TILES {
                                r.pending_tiles.push((key_index, payload.to_vec()));
                            }
                            None
                        }
                    }
                };
                match datum {
                    Some(datum_id) => self.merge(MergeJob {
                        datum_id,
                        robot: rid,
                        key_index: Some(key_index),
                        encoded: payload.to_vec(),
                    }),
                    None => self.spawn_query(robot, false),
                }
            }
            // Commands of other senders and the liveliness key are not station input.
            _ => {}
        }
    }

    fn on_session(self: &Arc<Self>, rid: &str, s: Session, now_ms: u64) {
        if !(s.cell_size_m.is_finite() && s.cell_size_m > 0.0 && s.tile_cells > 0) {
            return self.decode_error(&format!("terranav/{rid}/session"), "bad lattice");
        }
        let (datum_id, new_datum) = self
            .datums
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .assign(&s);
        if new_datum {
            let row = self
                .datums
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .rows
                .get(&datum_id)
                .cloned();
            if let Some(row) = row {
                self.store(StoreOp::Datum(row));
            }
        }
        let (changed, pending) = {
            let mut f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let r = f.robot(rid);
            r.last_seen_unix_ms = r.last_seen_unix_ms.max(now_ms);
            let changed = r
                .session
                .as_ref()
                .map(|o| o.session_id != s.session_id)
                .unwrap_or(true);
            if changed {
                r.last_track = None;
                r.path = None;
            }
            r.session = Some(s.clone());
            r.datum_id = Some(datum_id.clone());
            (changed, std::mem::take(&mut r.pending_tiles))
        };
        for (key_index, encoded) in pending {
            self.merge(MergeJob {
                datum_id: datum_id.clone(),
                robot: rid.to_string(),
                key_index: Some(key_index),
                encoded,
            });
        }
        // The robot's zones in its frame, every time its session is heard: a robot that
        // started (or a station that restarted) after the zones were drawn gets them now.
        self.spawn_zones_push(Some(rid.to_string()));
        let json_s = serde_json::to_string(&s).unwrap_or_default();
        self.store(StoreOp::Session {
            row: SessionRow {
                session_id: s.session_id.clone(),
                robot: rid.to_string(),
                start_unix_ms: s.start_unix_ms,
                last_unix_ms: now_ms,
                datum_id: datum_id.clone(),
                source: s.source.clone(),
            },
            json: json_s,
        });
        if changed {
            self.emit(
                json!({"type": "session", "robot": rid, "session": s, "datum_id": datum_id})
                    .to_string(),
            );
        }
    }

    fn on_pose(self: &Arc<Self>, rid: &str, p: Pose, now: Instant, now_ms: u64) {
        let (emit, track, session, datum) = {
            let mut f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let r = f.robot(rid);
            r.hit(RateTopic::Pose, now, now_ms);
            r.pose_latency.record(now_ms as i64 - p.t_unix_ms as i64);
            let emit = r
                .last_pose_event
                .map(|t| now.duration_since(t) >= Duration::from_millis(95))
                .unwrap_or(true);
            if emit {
                r.last_pose_event = Some(now);
            }
            let session = r.session.as_ref().map(|s| s.session_id.clone());
            let track = session.is_some() && r.track_point(&p);
            r.pose = Some(p.clone());
            (emit, track, session, r.datum_id.clone())
        };
        if let (true, Some(sid)) = (track, session) {
            self.store(StoreOp::Track {
                session_id: sid.clone(),
                t_unix_ms: p.t_unix_ms,
                x: p.x_m,
                y: p.y_m,
                yaw: p.yaw_rad as f64,
            });
            self.store(StoreOp::SessionSeen {
                session_id: sid,
                last_unix_ms: now_ms,
            });
        }
        if emit {
            self.emit(
                json!({"type": "pose", "robot": rid, "datum_id": datum, "pose": p}).to_string(),
            );
        }
    }

    fn on_status(self: &Arc<Self>, rid: &str, s: Status, now: Instant, now_ms: u64) {
        let new_error = {
            let mut f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let r = f.robot(rid);
            r.hit(RateTopic::Status, now, now_ms);
            let prev = r.status.as_ref().and_then(|o| o.last_error.clone());
            let new_error = match (&s.last_error, prev) {
                (Some(e), Some(p)) if *e == p => None,
                (Some(e), _) => Some(e.clone()),
                _ => None,
            };
            r.status = Some(s.clone());
            new_error
        };
        self.emit(json!({"type": "status", "robot": rid, "status": s}).to_string());
        if let Some(e) = new_error {
            self.emit(json!({"type": "error", "robot": rid, "message": e}).to_string());
        }
    }

    fn on_path(self: &Arc<Self>, rid: &str, p: Path, now: Instant, now_ms: u64) {
        let store_it = {
            let mut f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let r = f.robot(rid);
            r.last_seen_unix_ms = r.last_seen_unix_ms.max(now_ms);
            let store_it = match r.last_path_store {
                Some((t, g)) => g != p.goal_id || now.duration_since(t) >= Duration::from_secs(2),
                None => true,
            };
            if store_it {
                r.last_path_store = Some((now, p.goal_id));
            }
            r.path = Some(p.clone());
            store_it
                .then(|| r.session.as_ref().map(|s| s.session_id.clone()))
                .flatten()
        };
        let points: Vec<[f32; 2]> = p.points_m.iter().map(|&(x, y)| [x, y]).collect();
        if let Some(sid) = store_it {
            self.store(StoreOp::Path {
                session_id: sid,
                robot: rid.to_string(),
                t_unix_ms: p.t_unix_ms,
                goal_id: p.goal_id,
                json: serde_json::to_string(&points).unwrap_or_default(),
            });
        }
        self.emit(json!({"type": "path", "robot": rid, "points": points}).to_string());
    }

    fn on_route(self: &Arc<Self>, rid: &str, r: Route) {
        let datum_id = {
            let f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            f.robots.get(rid).and_then(|s| s.datum_id.clone())
        };
        let row = route_row(&r, datum_id);
        self.store(StoreOp::Route {
            row: row.clone(),
            json: serde_json::to_string(&r).unwrap_or_default(),
        });
        // The browser refetches GET /api/routes on this event: tell it only once the row is
        // committed (as the GPX import does), or the new route is missing until a reload.
        let me = self.clone();
        tokio::spawn(async move {
            me.flush_store_async().await;
            me.emit(json!({"type": "route", "route": row}).to_string());
        });
    }

    /// Handles a robot's liveliness token appearing (`alive`) or vanishing.
    pub fn on_liveliness(self: &Arc<Self>, key: &str, alive: bool) {
        let Ok((robot, Topic::Alive)) = keys::parse(key) else {
            return;
        };
        let now_ms = now_unix_ms();
        let flipped = self
            .fleet
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .set_online(robot.as_str(), alive, now_ms);
        if flipped {
            tracing::info!(robot = robot.as_str(), alive, "liveliness");
            self.emit(robot_event(robot.as_str(), alive, now_ms));
        }
        if alive {
            // A robot (re)appeared: fetch its session and every tile it has, so nothing
            // published while we were apart is lost.
            self.spawn_query(robot, true);
        }
    }

    /// Asks a robot's queryables for its session and (if `tiles`) every tile and route.
    pub fn spawn_query(self: &Arc<Self>, robot: RobotId, tiles: bool) {
        let me = self.clone();
        tokio::spawn(async move {
            me.resync(&robot, tiles).await;
        });
    }

    async fn get_all(self: &Arc<Self>, selector: String) -> usize {
        crate::bus::subscribe::query_all(&self.session(), &selector, |k, p| self.on_sample(k, p))
            .await
    }

    async fn resync(self: &Arc<Self>, robot: &RobotId, tiles: bool) {
        self.get_all(keys::key(robot, Topic::Session)).await;
        if tiles {
            let n = self.get_all(keys::robot_tiles(robot)).await;
            tracing::info!(robot = robot.as_str(), tiles = n, "resynced");
            self.get_all(keys::key(robot, Topic::Route)).await;
        }
    }

    /// The zone set of `robot` in its map frame, when its session is known.
    pub fn zone_set(&self, robot: &str) -> Option<common::msg::ZoneSet> {
        let (session, datum_id) = {
            let f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let r = f.robots.get(robot)?;
            (r.session.clone()?, r.datum_id.clone()?)
        };
        let z = self.zones.lock().unwrap_or_else(|p| p.into_inner());
        Some(zone_set_for(&z.records, z.version, &session, &datum_id))
    }

    /// Sends the zones to one robot (or every robot with a session) in its own frame.
    pub fn spawn_zones_push(self: &Arc<Self>, robot: Option<String>) {
        let me = self.clone();
        tokio::spawn(async move {
            let robots: Vec<String> = match robot {
                Some(r) => vec![r],
                None => me
                    .fleet
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .robots
                    .keys()
                    .cloned()
                    .collect(),
            };
            for r in robots {
                let (Some(set), Ok(id)) = (me.zone_set(&r), RobotId::new(r.clone())) else {
                    continue;
                };
                let key = keys::key(&id, Topic::Zones);
                if let Err(e) = crate::bus::put_command(&me.session(), key, msg::encode(&set)).await
                {
                    tracing::warn!("zones to {r}: {e}");
                }
            }
        });
    }

    /// Replaces the zone set (after an API change): stores, bumps the version, tells robots
    /// and browsers.
    pub fn zones_changed(self: &Arc<Self>) {
        let version = {
            let mut z = self.zones.lock().unwrap_or_else(|p| p.into_inner());
            z.version = now_unix_ms().max(z.version + 1);
            z.version
        };
        self.spawn_zones_push(None);
        self.emit(json!({"type": "zones", "version": version}).to_string());
    }

    /// One look at every robot: alerts, and the mission runs' next steps.
    pub async fn watch_once(self: &Arc<Self>) {
        let now_ms = now_unix_ms();
        type Snapshot = (String, bool, Option<Status>, Option<Pose>);
        let snap: Vec<Snapshot> = {
            let f = self.fleet.lock().unwrap_or_else(|p| p.into_inner());
            f.robots
                .iter()
                .map(|(id, r)| (id.clone(), r.online, r.status.clone(), r.pose.clone()))
                .collect()
        };
        let raised = {
            let mut a = self.alerts.lock().unwrap_or_else(|p| p.into_inner());
            let mut out = Vec::new();
            for (id, online, status, pose) in &snap {
                out.extend(a.observe(
                    id,
                    Observation {
                        online: *online,
                        status: status.as_ref(),
                        pose: pose.as_ref(),
                    },
                    now_ms,
                ));
            }
            out
        };
        for a in raised {
            tracing::info!(robot = a.robot, kind = ?a.kind, active = a.active, "alert: {}", a.message);
            self.alert_changed(&a);
        }
        // Mission runs.
        let mut sends: Vec<(String, RunAction)> = Vec::new();
        let mut changed = Vec::new();
        let mut failed = Vec::new();
        {
            let mut runs = self.runs.lock().unwrap_or_else(|p| p.into_inner());
            for (robot, run) in runs.iter_mut().filter(|(_, r)| !r.ended()) {
                let Some((_, online, status, pose)) = snap.iter().find(|s| &s.0 == robot) else {
                    continue;
                };
                let before = (run.index, run.phase.clone());
                let mut next_id = || self.goal_seq.fetch_add(1, Ordering::Relaxed);
                let acts = run.step(
                    now_ms,
                    RobotNow {
                        online: *online,
                        status: status.as_ref(),
                        pose: pose.as_ref(),
                    },
                    &mut next_id,
                );
                sends.extend(acts.into_iter().map(|a| (robot.clone(), a)));
                if before != (run.index, run.phase.clone()) {
                    changed.push(run.clone());
                    if let crate::missions::runner::RunPhase::Failed { reason } = &run.phase {
                        failed.push((robot.clone(), run.mission.name.clone(), reason.clone()));
                    }
                }
            }
        }
        for (robot, act) in sends {
            self.send_run_action(&robot, act).await;
        }
        for (robot, name, reason) in failed {
            let a = self.alerts.lock().unwrap_or_else(|p| p.into_inner()).raise(
                &robot,
                AlertKind::MissionFailed,
                format!("{robot}: mission {name:?} failed: {reason}"),
                now_ms,
            );
            self.alert_changed(&a);
        }
        for run in changed {
            self.emit(json!({"type": "mission_run", "run": run}).to_string());
        }
        let latest = |robot: &str| snap.iter().find(|s| s.0 == robot).and_then(|s| s.2.clone());
        self.deliver_pending(latest).await;
    }

    /// Sends again the API's goals and stops that no status has shown yet, and forgets those
    /// shown taken or refused, or sent every time without being shown (logged).
    async fn deliver_pending(self: &Arc<Self>, latest: impl Fn(&str) -> Option<Status>) {
        use crate::bus::confirm::{Outcome, Step};
        let now = std::time::Instant::now();
        let mut again = Vec::new();
        self.deliveries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .retain(|robot, p| {
                let kind = p.command.kind();
                match p.step(latest(robot).as_ref(), now) {
                    Step::WaitUntil(_) => true,
                    Step::Send => {
                        p.sent_again(now);
                        again.push((robot.clone(), p.command.clone()));
                        true
                    }
                    Step::Done(Outcome::Taken { attempts }) => {
                        if attempts > 1 {
                            tracing::info!("{kind} to {robot} taken after {attempts} sends");
                        }
                        false
                    }
                    Step::Done(Outcome::Superseded { goal_id, .. }) => {
                        tracing::info!(
                            "{kind} to {robot} not sent again: it took goal {goal_id} from another sender"
                        );
                        false
                    }
                    Step::Done(Outcome::Refused { reason, .. }) => {
                        tracing::info!("{kind} to {robot} refused by the robot: {reason}");
                        false
                    }
                    Step::Done(Outcome::Unconfirmed { attempts, statuses }) => {
                        tracing::warn!(
                            "{kind} to {robot}: sent {attempts} times, none of its {statuses} statuses since showed it"
                        );
                        false
                    }
                }
            });
        for (robot, command) in again {
            let Ok(id) = RobotId::new(robot.clone()) else {
                continue;
            };
            let kind = command.kind();
            tracing::info!("{kind} to {robot} sent again: no status has shown it yet");
            let payload = command.payload(self.cmd_header());
            if let Err(e) =
                crate::bus::put_command(&self.session(), keys::key(&id, command.topic()), payload)
                    .await
            {
                tracing::warn!("{kind} to {robot}: {e}");
            }
        }
    }

    /// Forgets the command waiting to be shown for `robot` (a newer one replaces it).
    pub fn supersede(&self, robot: &str) {
        self.deliveries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(robot);
    }

    /// Sends `command` again until `robot`'s status shows it (it was just sent once).
    pub fn follow_up(&self, robot: &str, command: crate::deliveries::Command) {
        let before = self
            .fleet
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .robots
            .get(robot)
            .and_then(|r| r.status.clone());
        let p = crate::deliveries::Pending::sent(command, before, std::time::Instant::now());
        self.deliveries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(robot.to_string(), p);
    }

    /// Keeps an alert that was raised, resolved or acknowledged, and tells the browsers.
    pub fn alert_changed(&self, a: &crate::alerts::Alert) {
        self.store(StoreOp::Alert {
            id: a.id,
            json: serde_json::to_string(a).unwrap_or_default(),
        });
        self.emit(json!({"type": "alert", "alert": a}).to_string());
    }

    /// Sends what a mission run asks for.
    pub async fn send_run_action(self: &Arc<Self>, robot: &str, act: RunAction) {
        let Ok(id) = RobotId::new(robot) else { return };
        self.supersede(robot);
        let h = self.cmd_header();
        let (topic, payload) = match act {
            RunAction::Goal { goal_id, target } => (
                Topic::CmdGoal,
                msg::encode_cmd(
                    h,
                    &msg::GoalCmd {
                        goal_id,
                        target,
                        tolerance_m: crate::missions::runner::WAYPOINT_TOLERANCE_M,
                    },
                ),
            ),
            RunAction::Speed(v) => (
                Topic::CmdSpeed,
                msg::encode_cmd(h, &msg::SpeedCmd { limit_mps: v }),
            ),
            RunAction::Stop => (
                Topic::CmdStop,
                msg::encode_cmd(
                    h,
                    &msg::StopCmd {
                        reason: "mission cancelled".into(),
                    },
                ),
            ),
        };
        if let Err(e) =
            crate::bus::put_command(&self.session(), keys::key(&id, topic), payload).await
        {
            tracing::warn!("mission command to {robot}: {e}");
        }
    }

    /// Commits queued writes now, without blocking the async runtime.
    pub async fn flush_store_async(self: &Arc<Self>) {
        let me = self.clone();
        let _ = tokio::task::spawn_blocking(move || me.flush_store()).await;
    }

    /// Commits queued writes now (tests).
    pub fn flush_store(&self) {
        let (ack, done) = mpsc::channel();
        self.store(StoreOp::Flush(ack));
        let _ = done.recv_timeout(Duration::from_secs(10));
    }
}

/// The route summary row.
pub fn route_row(r: &Route, datum_id: Option<String>) -> RouteRow {
    let length_m = r
        .points
        .windows(2)
        .map(|w| (w[1].x_m - w[0].x_m).hypot(w[1].y_m - w[0].y_m))
        .sum();
    RouteRow {
        route_id: r.route_id.clone(),
        name: r.name.clone(),
        robot: r.robot.clone(),
        session_id: r.session_id.clone(),
        datum_id,
        points: r.points.len() as u32,
        length_m,
    }
}

impl Station {
    /// Opens the database (restoring the merged map), the Zenoh session, and starts listening.
    pub async fn start(opts: StationOptions) -> Result<Station, StationError> {
        let store = StoreWriter::start(&opts.db)?;
        // The merged map's tiles come back on the merge thread (see `first` below); the rest is
        // small and read here.
        let (datums, zone_rows, mission_rows, alert_rows) = {
            let c = store::open(&opts.db)?;
            let mut datums = Datums::default();
            for d in store::datums(&c)? {
                datums.rows.insert(d.datum_id.clone(), d);
            }
            let zones: Vec<ZoneRecord> = store::zones(&c)?
                .iter()
                .filter_map(|j| serde_json::from_str(j).ok())
                .collect();
            let missions: BTreeMap<String, Mission> = store::missions(&c)?
                .iter()
                .filter_map(|j| serde_json::from_str::<Mission>(j).ok())
                .map(|m| (m.mission_id.clone(), m))
                .collect();
            let alerts: Vec<crate::alerts::Alert> = store::alerts(&c, crate::alerts::MAX_ALERTS)?
                .iter()
                .filter_map(|j| serde_json::from_str(j).ok())
                .collect();
            (datums, zones, missions, alerts)
        };
        let map = Arc::new(RwLock::new(MergedMap::default()));
        let (events, _) = broadcast::channel(4096);
        let decode_errors = Arc::new(AtomicU64::new(0));
        let store_tx = store.sender();
        let sink_events = events.clone();
        let sink_store = Mutex::new(store.sender());
        let pyramid = Arc::new(Mutex::new(crate::pyramid::Pyramid::new()));
        let restore = Arc::new(RestoreProgress::default());
        let first = {
            let (db, map, pyramid, restore) = (
                opts.db.clone(),
                map.clone(),
                pyramid.clone(),
                restore.clone(),
            );
            Box::new(move || {
                restore_from_db(&db, &map, &restore, |d, i| {
                    crate::pyramid::mark_changed(&pyramid, d, i)
                });
                crate::pyramid::warm_in_background(map, pyramid);
            })
        };
        let sink_pyramid = pyramid.clone();
        let history_s = opts.map_history_s;
        let merge = MergeWorker::start_after(
            map.clone(),
            Box::new(move |ch: TileChange, enc: Vec<u8>| {
                crate::pyramid::mark_changed(&sink_pyramid, &ch.datum_id, ch.index);
                let store = sink_store.lock().unwrap_or_else(|p| p.into_inner());
                let history = (history_s > 0).then(|| {
                    let t = now_unix_ms();
                    crate::store::HistoryStamp {
                        bucket: crate::history::bucket(t, history_s),
                        t_unix_ms: t,
                    }
                });
                let _ = store.send(StoreOp::Tile {
                    datum_id: ch.datum_id.clone(),
                    tx: ch.index.tx,
                    ty: ch.index.ty,
                    version: ch.version,
                    data: enc,
                    history,
                });
                let _ = sink_events.send(Arc::from(
                    json!({"type": "tile", "datum_id": ch.datum_id, "tx": ch.index.tx, "ty": ch.index.ty, "version": ch.version})
                        .to_string(),
                ));
            }),
            decode_errors.clone(),
            first,
        );
        let session = crate::bus::open(opts.zenoh).await?;
        let start_seq = (now_unix_ms() / 1000) as u32;
        let sender = sender_id(&session);
        let inner = Arc::new(Inner {
            session: RwLock::new(session),
            fleet: Mutex::new(Fleet::default()),
            datums: Mutex::new(datums),
            map,
            restore,
            pyramid,
            events,
            decode_errors,
            db: opts.db.clone(),
            store_tx: Mutex::new(store_tx),
            merge_tx: merge.sender(),
            goal_seq: AtomicU32::new(start_seq),
            drive_seq: AtomicU32::new(start_seq),
            stamper: CommandStamper::new(sender),
            reader: Mutex::new(None),
            zones: Mutex::new(ZoneBook {
                records: zone_rows,
                version: now_unix_ms(),
            }),
            missions: Mutex::new(mission_rows),
            runs: Mutex::new(BTreeMap::new()),
            deliveries: Mutex::new(BTreeMap::new()),
            alerts: Mutex::new(Alerts::restore(opts.alerts, alert_rows)),
            map_history_s: opts.map_history_s,
            history: Default::default(),
        });
        let subs = crate::bus::subscribe::declare(&inner).await?;
        let i5 = inner.clone();
        let watch_task = tokio::spawn(async move {
            let mut tick = tokio::time::interval(WATCH_PERIOD);
            loop {
                tick.tick().await;
                i5.watch_once().await;
            }
        });
        let mut subs = subs;
        subs.push(Box::new(crate::bus::AbortOnDrop(watch_task)));
        Ok(Station {
            inner,
            merge: Some(merge),
            store: Some(store),
            subs,
        })
    }

    /// Closes the Zenoh session and opens a new one with `zenoh` (new access rules, say), keeping
    /// fleet, map and store. Every robot's link drops; those still admitted reconnect within a
    /// second and are resynced as after any cut. Robots are shown offline until their liveliness
    /// token is seen again.
    pub async fn reopen(&mut self, zenoh: zenoh::Config) -> Result<(), StationError> {
        self.subs.clear();
        // The old session must release its listening port before the new one binds it.
        let _ = self.inner.session().close().await;
        let now_ms = now_unix_ms();
        let gone: Vec<String> = {
            let mut f = self.inner.fleet.lock().unwrap_or_else(|p| p.into_inner());
            let ids: Vec<String> = f
                .robots
                .iter()
                .filter(|(_, r)| r.online)
                .map(|(id, _)| id.clone())
                .collect();
            for id in &ids {
                f.set_online(id, false, now_ms);
            }
            ids
        };
        for id in gone {
            self.inner.emit(robot_event(&id, false, now_ms));
        }
        let session = crate::bus::open(zenoh).await?;
        *self
            .inner
            .session
            .write()
            .unwrap_or_else(|p| p.into_inner()) = session;
        self.subs = crate::bus::subscribe::declare(&self.inner).await?;
        Ok(())
    }

    /// Closes Zenoh, then drains the merge and store queues.
    pub async fn stop(mut self) {
        self.subs.clear();
        let _ = self.inner.session().close().await;
        let merge = self.merge.take();
        let store = self.store.take();
        let _ = tokio::task::spawn_blocking(move || {
            if let Some(m) = merge {
                m.finish();
            }
            if let Some(s) = store {
                s.finish();
            }
        })
        .await;
    }
}

/// The lattice of a datum, from the store rows.
pub fn datum_lattice(row: &DatumRow) -> Lattice {
    Lattice {
        cell_size_m: row.cell_size_m,
        tile_cells: row.tile_cells,
    }
}

//! The async face: one robot's Zenoh session, its command subscriber, its queryables and its
//! publishers.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::command::{ReplayGuard, RobotContext};
use common::grid::TileIndex;
use common::keys::{self, RobotId, Topic};
use common::msg::{self, Path, Pose, Route, Session, Status};
use tokio::sync::mpsc;
use zenoh::qos::{CongestionControl, Priority};

use super::{
    now_unix_ms, parse_command, secure, zerr, BusConfig, BusCounters, BusError, Command,
    CommandLimits, DEADMAN,
};

/// What the robot currently serves to queries.
#[derive(Default)]
struct Served {
    session: Option<Vec<u8>>,
    tiles: BTreeMap<TileIndex, Vec<u8>>,
    routes: BTreeMap<String, Vec<u8>>,
}

pub(super) struct Shared {
    robot: RobotId,
    limits: CommandLimits,
    /// What the robot knows about itself, for the goal checks (kept fresh by the loop).
    pub(super) context: Mutex<RobotContext>,
    served: Mutex<Served>,
    refused: AtomicU32,
    decode_errors: AtomicU32,
    replayed: AtomicU32,
    replay_guard: Mutex<ReplayGuard>,
    pub(super) last_drive: Mutex<Option<(Instant, u32)>>,
}

impl Shared {
    pub(super) fn counters(&self) -> BusCounters {
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
    pub(super) shared: Arc<Shared>,
    _token: zenoh::liveliness::LivelinessToken,
    tasks: Vec<tokio::task::JoinHandle<()>>,
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
        let cc = if reliable {
            CongestionControl::Block
        } else {
            CongestionControl::Drop
        };
        // On a congested link Zenoh's transmission queues then send pose, status and path
        // before the map (the uplink scheduler orders what reaches them; this orders the rest).
        let priority = if matches!(topic, Topic::Tile { .. }) {
            Priority::DataLow
        } else {
            Priority::Data
        };
        let key = keys::key(&self.shared.robot, topic);
        self.session
            .put(key, payload)
            .congestion_control(cc)
            .priority(priority)
            .await
            .map_err(zerr)
    }

    /// Length of the key `topic` is published on, bytes (the uplink budget counts it).
    pub fn key_len(&self, topic: Topic) -> usize {
        keys::key(&self.shared.robot, topic).len()
    }

    /// Serves the session from now on (queries); returns it encoded, for [`Self::put_encoded`].
    pub fn serve_session(&self, s: &Session) -> Vec<u8> {
        let b = msg::encode(s);
        self.shared.lock_served().session = Some(b.clone());
        b
    }

    /// Serves a recorded route from now on (queries); returns it encoded, for
    /// [`Self::put_encoded`].
    pub fn serve_route(&self, r: &Route) -> Vec<u8> {
        let b = msg::encode(r);
        self.shared
            .lock_served()
            .routes
            .insert(r.route_id.clone(), b.clone());
        b
    }

    /// Puts an encoded message on `topic`: poses best effort (the next one supersedes a lost
    /// one), everything else reliable.
    pub async fn put_encoded(&self, topic: Topic, payload: Vec<u8>) -> Result<(), BusError> {
        let reliable = !matches!(topic, Topic::Pose);
        self.put(topic, payload, reliable).await
    }

    /// Publishes (and from now on serves) the session.
    pub async fn publish_session(&self, s: &Session) -> Result<(), BusError> {
        let b = self.serve_session(s);
        self.put_encoded(Topic::Session, b).await
    }

    /// Publishes a pose.
    pub async fn publish_pose(&self, p: &Pose) -> Result<(), BusError> {
        self.put_encoded(Topic::Pose, msg::encode(p)).await
    }

    /// Publishes the planned path.
    pub async fn publish_path(&self, p: &Path) -> Result<(), BusError> {
        self.put_encoded(Topic::Path, msg::encode(p)).await
    }

    /// Publishes the status.
    pub async fn publish_status(&self, s: &Status) -> Result<(), BusError> {
        self.put_encoded(Topic::Status, msg::encode(s)).await
    }

    /// Publishes (and from now on serves) a recorded route.
    pub async fn publish_route(&self, r: &Route) -> Result<(), BusError> {
        let b = self.serve_route(r);
        self.put_encoded(Topic::Route, b).await
    }

    /// Publishes a changed tile, already encoded with `common::grid::encode_tile`, and keeps it
    /// for the tile queryable.
    pub async fn publish_tile(&self, index: TileIndex, encoded: Vec<u8>) -> Result<(), BusError> {
        self.serve_tile(index, &encoded);
        let topic = Topic::Tile {
            tx: index.tx,
            ty: index.ty,
        };
        self.put_encoded(topic, encoded).await
    }

    /// Keeps a tile for the tile queryable (the newest version is served at once, even while
    /// the uplink holds it back).
    pub fn serve_tile(&self, index: TileIndex, encoded: &[u8]) {
        self.shared
            .lock_served()
            .tiles
            .insert(index, encoded.to_vec());
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

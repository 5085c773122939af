//! The blocking-friendly face: the bus on a background tokio runtime, for a synchronous loop.

use std::sync::Arc;
use std::time::{Duration, Instant};

use common::command::RobotContext;
use common::grid::TileIndex;
use common::keys::Topic;
use common::msg::{Path, Pose, Route, Session, Status};
use tokio::sync::mpsc;

use super::session::{RobotBus, Shared};
use super::uplink::{Next, Uplink};
use super::{now_unix_ms, BusConfig, BusCounters, BusError, Command, DEADMAN};

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

/// A message encoded once, as the uplink counts it and the wire carries it.
struct Wire {
    topic: Topic,
    payload: Vec<u8>,
}

/// Hands `m` to the uplink scheduler, encoded. What is served on queries (tiles, the session,
/// routes) is served from now on, even while the uplink holds the message back.
fn queue_out(bus: &RobotBus, uplink: &mut Uplink<Wire>, m: Out, now_s: f64) {
    let (topic, payload) = match m {
        Out::Tile(i, b) => {
            bus.serve_tile(i, &b);
            let topic = Topic::Tile { tx: i.tx, ty: i.ty };
            let bytes = Uplink::<Wire>::cost(bus.key_len(topic), b.len());
            uplink.push_tile(i, Wire { topic, payload: b }, bytes, now_s);
            return;
        }
        Out::ClearTiles => {
            bus.clear_tiles();
            uplink.clear_tiles();
            return;
        }
        Out::Session(s) => (Topic::Session, bus.serve_session(&s)),
        Out::Pose(p) => (Topic::Pose, common::msg::encode(&p)),
        Out::Path(p) => (Topic::Path, common::msg::encode(&p)),
        Out::Status(s) => (Topic::Status, common::msg::encode(&s)),
        Out::Route(r) => (Topic::Route, bus.serve_route(&r)),
    };
    let bytes = Uplink::<Wire>::cost(bus.key_len(topic), payload.len());
    uplink.push_control(Wire { topic, payload }, bytes);
}

/// Puts one message the uplink let go on the wire.
async fn send_out(bus: &RobotBus, w: Wire) {
    if let Err(e) = bus.put_encoded(w.topic, w.payload).await {
        tracing::warn!("publish failed: {e}");
    }
}

impl BusHandle {
    /// Starts the runtime and opens the bus; returns when the session is open.
    pub fn start(config: BusConfig) -> Result<Self, BusError> {
        let uplink_policy = config.uplink;
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
                    let start = tokio::time::Instant::now();
                    let now_s = || start.elapsed().as_secs_f64();
                    let mut uplink = Uplink::new(uplink_policy, 0.0);
                    loop {
                        // Everything the budget lets go now, then wait for more or for the
                        // bucket to refill.
                        let wait = loop {
                            match uplink.next(now_s()) {
                                Next::Send(out) => send_out(&bus, out).await,
                                Next::Wait(d) => break Some(d),
                                Next::Idle => break None,
                            }
                        };
                        let first = tokio::select! {
                            m = rx.recv() => match m { Some(m) => m, None => break },
                            _ = tokio::time::sleep(wait.unwrap_or_default()), if wait.is_some() => continue,
                            _ = &mut stop_rx => break,
                        };
                        // Take whatever else is queued, so a burst of tiles is ordered as one.
                        let mut next = Some(first);
                        while let Some(m) = next {
                            queue_out(&bus, &mut uplink, m, now_s());
                            next = rx.try_recv().ok();
                        }
                    }
                    let c = uplink.counters();
                    tracing::info!(
                        "uplink: {} messages, {} bytes, {} tile versions coalesced, at most {} tiles queued",
                        c.messages_sent,
                        c.bytes_sent,
                        c.tiles_coalesced,
                        c.max_tiles_queued
                    );
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

//! The recording of one session at the runtime's boundary: every input as it arrived, every
//! command as it reached the agent, every control period's base command (these three are what a
//! replay feeds back), and the outputs as the bus got them (session, tiles, pose, status, path,
//! route) drawn for a viewer. Each call hands owned data to the writer thread and returns; the
//! JSON is made there.

use super::channels::{Channels, InputKind, DEPTH_FRAME, LIDAR_FRAME, MAP_FRAME};
use super::digest::{Digest, RunDigest};
use super::{inputs, SessionMeta};
use crate::runtime::{AgentCommand, Input};
use agent::{Agent, AgentConfig, Cmd};
use common::grid::{Tile, TileIndex};
use common::msg::{Datum, Pose, Route, Session, Status};
use record::foxglove::{self, level};
use record::{Recorder, Stats};
use serde::Serialize;
use serde_json::json;
use std::collections::{BTreeMap, HashMap};

/// How often the grid around the robot is drawn, seconds of session time.
const GRID_PERIOD_S: f64 = 1.0;
/// The grid reaches this many tiles from the robot's tile each way (5 x 5 tiles: 64 m square).
const GRID_REACH_TILES: i32 = 2;

/// What a finished recording holds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RecordSummary {
    /// The files.
    pub files: Vec<String>,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// The writer's counters.
    pub stats: Stats,
    /// The run's digest (also in the file's `terranav.digest` metadata).
    pub digest: Option<Digest>,
}

/// See the module docs.
pub struct SessionRecorder {
    rec: Recorder,
    ch: Channels,
    start_unix_ms: u64,
    t0_s: f64,
    digest: RunDigest,
    tiles: HashMap<TileIndex, Tile>,
    grid_dirty: bool,
    next_grid_s: f64,
    robot_m: (f64, f64, f64),
    datum: Option<Datum>,
    last_goal: Option<(f64, f64)>,
}

impl SessionRecorder {
    /// Starts recording a session (its metadata and the sensor mounts first).
    pub fn start(
        opts: &super::RecordOptions,
        meta: &SessionMeta,
        cfg: &AgentConfig,
    ) -> anyhow::Result<Self> {
        let mut w = record::Options::new(&opts.path);
        w.split = opts.split;
        w.profile = record::PROFILE.into();
        let mut rec = Recorder::start(w)?;
        let ch = Channels::declare(&mut rec);
        for (name, values) in meta.to_metadata() {
            rec.metadata(&name, values);
        }
        let mut me = Self {
            rec,
            ch,
            start_unix_ms: meta.identity.start_unix_ms,
            t0_s: meta.t0_s,
            digest: RunDigest::default(),
            tiles: HashMap::new(),
            grid_dirty: false,
            next_grid_s: 0.0,
            robot_m: (0.0, 0.0, 0.0),
            datum: cfg.datum,
            last_goal: None,
        };
        let t = me.unix_ns(0.0);
        let mount = |frame: &str, iso: nalgebra::Isometry3<f64>| {
            let v = iso.translation.vector;
            let q = iso.rotation;
            foxglove::frame_transform(t, "base_link", frame, [v.x, v.y, v.z], [q.i, q.j, q.k, q.w])
        };
        let tf = json!({"transforms": [
            mount(LIDAR_FRAME, cfg.profile.lidar.isometry()),
            mount(DEPTH_FRAME, cfg.profile.depth_camera.isometry()),
        ]});
        me.send_json(me.ch.tf_static, 0.0, tf);
        Ok(me)
    }

    /// Unix nanoseconds of session time `t_s`.
    pub fn unix_ns(&self, t_s: f64) -> u64 {
        let ns = self.start_unix_ms as f64 * 1e6 + t_s * 1e9;
        if ns.is_finite() && ns > 0.0 {
            ns.round() as u64
        } else {
            0
        }
    }

    fn send_json(&mut self, ch: record::ChannelId, t_s: f64, v: serde_json::Value) {
        let t = self.unix_ns(t_s);
        self.rec.write(ch, t, 1024, move || foxglove::bytes(&v));
    }

    /// An input as it arrived (before the stamp gate: a refused one is recorded too, and refused
    /// again on replay).
    pub fn input(&mut self, input: &Input) {
        let kind = InputKind::of(input);
        let t0 = self.t0_s;
        let start = self.start_unix_ms;
        let t = self.unix_ns(input.stamp_s() - t0);
        let size = match input {
            Input::Scan(s) | Input::Depth(s) => 48 * s.points.len() + 1024,
            _ => 512,
        };
        let input = input.clone();
        self.rec.write(self.ch.input(kind), t, size, move || {
            let to_unix = move |stamp_s: f64| {
                let ns = start as f64 * 1e6 + (stamp_s - t0) * 1e9;
                if ns.is_finite() && ns > 0.0 {
                    ns.round() as u64
                } else {
                    0
                }
            };
            foxglove::bytes(&inputs::to_json(&input, &to_unix))
        });
    }

    /// A message a driver could not decode, at session time `t_s`.
    pub fn undecodable(&mut self, stream: &str, why: &str, t_s: f64) {
        let v = foxglove::log(
            self.unix_ns(t_s),
            level::WARNING,
            stream,
            &format!("undecodable {stream} message: {why}"),
        );
        self.send_json(self.ch.log, t_s, v);
    }

    /// A line for the log channel.
    pub fn log(&mut self, lvl: u8, name: &str, message: &str, t_s: f64) {
        let v = foxglove::log(self.unix_ns(t_s), lvl, name, message);
        self.send_json(self.ch.log, t_s, v);
    }

    /// A command as it reached the agent.
    pub fn command(&mut self, c: &AgentCommand) {
        let t_s = c.t_s();
        let mut v = json!({"timestamp": foxglove::time(self.unix_ns(t_s)), "t_s": t_s});
        match c {
            AgentCommand::Do(cmd) => {
                v["command"] = serde_json::to_value(&cmd.kind).unwrap_or_default()
            }
            AgentCommand::Refused { refusal, .. } => {
                v["refusal"] = json!({"code": refusal.code, "message": refusal.message});
                self.log(level::WARNING, "command", &refusal.to_string(), t_s);
            }
        }
        if let AgentCommand::Do(agent::Command {
            kind: agent::command::CommandKind::Repeat { route, .. },
            ..
        }) = c
        {
            let pts: Vec<[f64; 3]> = route
                .points
                .iter()
                .map(|p| [p.x_m, p.y_m, self.robot_m.2])
                .collect();
            let v = foxglove::scene_line(
                self.unix_ns(t_s),
                MAP_FRAME,
                "route",
                &pts,
                foxglove::color(0.6, 0.3, 0.9, 1.0),
                0.1,
            );
            self.send_json(self.ch.route, t_s, v);
        }
        self.send_json(self.ch.commands, t_s, v);
    }

    /// One control period at `t_s` that sent `cmd` to the base (and the run's digest).
    pub fn control(&mut self, t_s: f64, agent: &Agent, cmd: Cmd) {
        self.digest.control(t_s, agent, cmd);
        let v = json!({
            "timestamp": foxglove::time(self.unix_ns(t_s)),
            "t_s": t_s,
            "v_mps": cmd.v_mps,
            "omega_rps": cmd.omega_rps,
        });
        self.send_json(self.ch.cmd_vel, t_s, v);
    }

    /// The session record.
    pub fn session(&mut self, s: &Session, t_s: f64) {
        if s.datum.is_some() {
            self.datum = s.datum;
        }
        let v = json!({"timestamp": foxglove::time(self.unix_ns(t_s)), "session": s});
        self.send_json(self.ch.session, t_s, v);
    }

    /// A tile as sent to the station.
    pub fn tile(&mut self, tile: &Tile, encoded: &[u8], t_s: f64) {
        let v = foxglove::tile_message(self.unix_ns(t_s), tile, encoded);
        self.send_json(self.ch.tiles, t_s, v);
        self.tiles.insert(tile.index, tile.clone());
        self.grid_dirty = true;
    }

    /// A taught route.
    pub fn route(&mut self, r: &Route, t_s: f64) {
        let pts: Vec<[f64; 3]> = r
            .points
            .iter()
            .map(|p| [p.x_m, p.y_m, self.robot_m.2])
            .collect();
        let v = foxglove::scene_line(
            self.unix_ns(t_s),
            MAP_FRAME,
            "route",
            &pts,
            foxglove::color(0.6, 0.3, 0.9, 1.0),
            0.1,
        );
        self.send_json(self.ch.route, t_s, v);
    }

    /// The pose as published (10 Hz); `h_m`: its ellipsoidal height when anchored. Draws the
    /// grid around the robot when one is due.
    pub fn pose(&mut self, p: &Pose, h_m: Option<f64>, t_s: f64) {
        let t = self.unix_ns(t_s);
        self.robot_m = (p.x_m, p.y_m, p.z_m);
        let q = foxglove::quaternion_ypr(
            f64::from(p.yaw_rad),
            f64::from(p.pitch_rad),
            f64::from(p.roll_rad),
        );
        let xyz = [p.x_m, p.y_m, p.z_m];
        let tf = foxglove::frame_transform(t, MAP_FRAME, "base_link", xyz, q);
        self.send_json(self.ch.tf, t_s, tf);
        let pose = foxglove::pose_in_frame(t, MAP_FRAME, xyz, q);
        self.send_json(self.ch.pose, t_s, pose);
        if let Some((lat, lon)) = p.lat_lon_deg {
            let h = h_m.or(self.datum.map(|d| d.h_m + p.z_m)).unwrap_or(0.0);
            let fix = foxglove::location_fix(t, "base_link", lat, lon, h);
            self.send_json(self.ch.fix, t_s, fix);
        }
        if self.grid_dirty && t_s >= self.next_grid_s {
            self.next_grid_s = t_s + GRID_PERIOD_S;
            self.grid_dirty = false;
            self.grid(t_s);
        }
    }

    fn grid(&mut self, t_s: f64) {
        let Some(lattice) = self.tiles.values().next().map(|t| t.lattice) else {
            return;
        };
        let s = lattice.cell_size_f64() * f64::from(lattice.tile_cells);
        let (cx, cy) = (
            (self.robot_m.0 / s).floor() as i32,
            (self.robot_m.1 / s).floor() as i32,
        );
        let near: Vec<Tile> = self
            .tiles
            .values()
            .filter(|t| {
                (t.index.tx - cx).abs() <= GRID_REACH_TILES
                    && (t.index.ty - cy).abs() <= GRID_REACH_TILES
            })
            .cloned()
            .collect();
        let t = self.unix_ns(t_s);
        let size = near.len() * 64 * 64 * 10;
        self.rec.write(self.ch.grid, t, size, move || {
            foxglove::tiles_grid(t, MAP_FRAME, near.iter())
                .map_or_else(Vec::new, |v| foxglove::bytes(&v))
        });
    }

    /// The status as published (and the goal, when it changed).
    pub fn status(&mut self, s: &Status, t_s: f64) {
        let stats = self.rec.stats();
        let v = json!({
            "timestamp": foxglove::time(self.unix_ns(t_s)),
            "status": s,
            "recording": {"written": stats.written, "dropped": stats.dropped()},
        });
        self.send_json(self.ch.status, t_s, v);
        if s.goal_m != self.last_goal {
            self.last_goal = s.goal_m;
            let t = self.unix_ns(t_s);
            let v = match s.goal_m {
                Some((x, y)) => foxglove::scene_marker(
                    t,
                    MAP_FRAME,
                    "goal",
                    [x, y, self.robot_m.2],
                    foxglove::color(1.0, 0.55, 0.0, 1.0),
                    &format!("goal {}", s.goal_id),
                ),
                None => foxglove::scene_delete(t, "goal"),
            };
            self.send_json(self.ch.goal, t_s, v);
        }
    }

    /// The path being followed (map frame).
    pub fn path(&mut self, path: &[(f64, f64)], t_s: f64) {
        let z = self.robot_m.2;
        let pts: Vec<[f64; 3]> = path.iter().map(|p| [p.0, p.1, z]).collect();
        let v = foxglove::scene_line(
            self.unix_ns(t_s),
            MAP_FRAME,
            "path",
            &pts,
            foxglove::color(0.1, 0.5, 1.0, 1.0),
            0.08,
        );
        self.send_json(self.ch.path, t_s, v);
    }

    /// The writer's counters now.
    pub fn stats(&self) -> Stats {
        self.rec.stats()
    }

    /// Closes the recording; with the agent, the run's digest is computed and stored in the file.
    pub fn finish(mut self, agent: Option<&Agent>) -> RecordSummary {
        let digest = agent.map(|a| std::mem::take(&mut self.digest).finish(a));
        if let Some(d) = &digest {
            let values = serde_json::to_value(d)
                .ok()
                .and_then(|v| v.as_object().cloned())
                .unwrap_or_default()
                .into_iter()
                .map(|(k, v)| (k, v.as_str().map_or_else(|| v.to_string(), str::to_string)))
                .collect();
            self.rec.metadata(super::DIGEST_METADATA, values);
        }
        let f = self.rec.finish();
        RecordSummary {
            files: f.files.iter().map(|p| p.display().to_string()).collect(),
            messages: f.messages,
            stats: f.stats,
            digest,
        }
    }
}

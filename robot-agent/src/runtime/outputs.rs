//! What a running agent tells the bus, and when: its session once the map frame is known,
//! changed tiles after each sweep (the tile policy), the taught route when one is finished, the
//! pose at 10 Hz, the status at 2 Hz and on every change of mode or phase, and the path when it
//! changes. The live simulator and the real-robot runtime publish through this one place, to the
//! bus and, when recording, to the recording (a replay or a headless run: to the recording only).

use crate::bus::tiles::{TilePolicy, TilePublisher};
use crate::bus::translate::{self, RuntimeCounters};
use crate::bus::BusHandle;
use crate::record::SessionRecorder;
use agent::localiser::FrameKind;
use agent::Agent;
use common::command::{BoundsM, RobotContext};
use common::msg::{Path, Session};
use std::collections::VecDeque;

/// Pose publication period, seconds (10 Hz).
const POSE_PERIOD_S: f64 = 0.1;
/// Status publication period, seconds (2 Hz, and on change).
const STATUS_PERIOD_S: f64 = 0.5;
/// Window of the scan-rate estimate, seconds.
const SCAN_RATE_WINDOW_S: f64 = 2.0;

/// Counters the loop around the agent adds to the status.
#[derive(Clone, Debug, Default)]
pub struct LoopCounters {
    /// Collisions (simulator truth; 0 on a real robot).
    pub collisions: u32,
    /// Bad inputs (refused stamps, undecodable messages).
    pub bad_inputs: u64,
    /// The sensor faults in force, for humans ("lidar silent for 0.6 s, base stopped").
    pub faults: Vec<String>,
}

/// See the module docs.
pub struct Outputs {
    source: String,
    tiles: TilePublisher,
    session_sent: bool,
    next_pose_s: f64,
    next_status_s: f64,
    pose_seq: u32,
    last_path: Vec<(f64, f64)>,
    last_state: Option<(agent::mission::Mode, agent::mission::Phase, bool)>,
    scan_times: VecDeque<f64>,
}

impl Outputs {
    /// Outputs for `agent`'s session; `source` names the robot's hardware in the session
    /// record (`sim:park`, `ros2`, ...).
    pub fn new(agent: &Agent, source: &str) -> Self {
        Self {
            source: source.to_string(),
            tiles: TilePublisher::new(TilePolicy::default(), agent.lattice(), agent.unix_ms(0.0)),
            session_sent: false,
            next_pose_s: 0.0,
            next_status_s: 0.0,
            pose_seq: 0,
            last_path: Vec::new(),
            last_state: None,
            scan_times: VecDeque::new(),
        }
    }

    /// Publishes what fell due at session time `t_s` to the bus and the recording (either may be
    /// absent); `scanned`: a sweep was processed since the last call.
    pub fn publish(
        &mut self,
        bus: Option<&BusHandle>,
        mut rec: Option<&mut SessionRecorder>,
        agent: &mut Agent,
        t_s: f64,
        scanned: bool,
        counters: &LoopCounters,
    ) {
        if let Some(bus) = bus {
            bus.set_context(context(agent, t_s));
        }
        if scanned {
            self.scan_times.push_back(t_s);
        }
        while self
            .scan_times
            .front()
            .is_some_and(|s| t_s - s > SCAN_RATE_WINDOW_S)
        {
            self.scan_times.pop_front();
        }
        if !self.session_sent {
            if let Some((frame, datum)) = agent.map_frame() {
                let lattice = agent.lattice();
                let session = Session {
                    session_id: agent.identity().session_id.clone(),
                    robot: agent.identity().robot.clone(),
                    start_unix_ms: agent.unix_ms(0.0),
                    frame: translate::frame_to_wire(frame),
                    datum: if frame == FrameKind::EnuAtDatum {
                        datum
                    } else {
                        None
                    },
                    cell_size_m: lattice.cell_size_m,
                    tile_cells: lattice.tile_cells,
                    source: self.source.clone(),
                    agent_version: env!("CARGO_PKG_VERSION").into(),
                };
                if let Some(bus) = bus {
                    bus.publish_session(&session);
                }
                if let Some(r) = rec.as_deref_mut() {
                    r.session(&session, t_s);
                }
                self.session_sent = true;
            }
        }
        if scanned {
            let changed = agent.take_changed_tiles();
            let a = &*agent;
            for tile in self
                .tiles
                .publish(t_s, &changed, |i| a.tile_cells(i), false)
            {
                let encoded = common::grid::encode_tile(&tile);
                if let Some(r) = rec.as_deref_mut() {
                    r.tile(&tile, &encoded, t_s);
                }
                if let Some(bus) = bus {
                    bus.publish_tile(tile.index, encoded);
                }
            }
        }
        if let Some(route) = agent.take_taught_route() {
            let route = translate::route_to_wire(&route);
            if let Some(bus) = bus {
                bus.publish_route(&route);
            }
            if let Some(r) = rec.as_deref_mut() {
                r.route(&route, t_s);
            }
        }
        if t_s >= self.next_pose_s {
            self.next_pose_s = (self.next_pose_s + POSE_PERIOD_S).max(t_s);
            if let Some(p) = agent.pose(t_s) {
                let pose = translate::pose_to_wire(&p, agent.unix_ms(t_s), self.pose_seq);
                if let Some(bus) = bus {
                    bus.publish_pose(&pose);
                }
                if let Some(r) = rec.as_deref_mut() {
                    r.pose(&pose, p.lla.map(|l| l.2), t_s);
                }
                self.pose_seq += 1;
            }
        }
        let mut agent_status = agent.status(t_s);
        if !counters.faults.is_empty() {
            // A sensor fault is the first thing an operator needs to read.
            agent_status.reason =
                format!("{}; {}", counters.faults.join("; "), agent_status.reason);
        }
        let state = (agent_status.mode, agent_status.phase, agent_status.driving);
        let bus_counters = bus.map(|b| b.counters()).unwrap_or_default();
        let status = translate::status_to_wire(
            &agent_status,
            agent.unix_ms(t_s),
            RuntimeCounters {
                decode_errors: bus_counters
                    .decode_errors
                    .saturating_add(u32::try_from(counters.bad_inputs).unwrap_or(u32::MAX)),
                commands_replayed: bus_counters.commands_replayed,
                collisions: counters.collisions,
                scan_hz: self.scan_times.len() as f32 / SCAN_RATE_WINDOW_S as f32,
                plan_hz: 0.0,
            },
        );
        if t_s >= self.next_status_s || self.last_state != Some(state) {
            self.next_status_s = t_s + STATUS_PERIOD_S;
            self.last_state = Some(state);
            if let Some(bus) = bus {
                bus.publish_status(&status);
            }
            if let Some(r) = rec.as_deref_mut() {
                r.status(&status, t_s);
            }
        }
        let path = agent.current_path();
        if path != self.last_path {
            let wire = Path {
                t_unix_ms: agent.unix_ms(t_s),
                goal_id: status.goal_id,
                points_m: path.iter().map(|p| (p.0 as f32, p.1 as f32)).collect(),
            };
            if let Some(bus) = bus {
                bus.publish_path(&wire);
            }
            if let Some(r) = rec {
                r.path(&path, t_s);
            }
            self.last_path = path;
        }
    }
}

/// What the bus's command checks should know about the robot at `t_s`.
pub fn context(agent: &Agent, t_s: f64) -> RobotContext {
    let pose = agent.pose(t_s);
    let s = agent.lattice().cell_size_f64();
    RobotContext {
        position_m: pose.map(|p| (p.pose.planar.x_m, p.pose.planar.y_m)),
        lat_lon_deg: pose.and_then(|p| p.lla.map(|l| (l.0, l.1))),
        mapped: agent.mapper().bounds().map(|((x0, y0), (x1, y1))| BoundsM {
            min_m: (x0 as f64 * s, y0 as f64 * s),
            max_m: ((x1 + 1) as f64 * s, (y1 + 1) as f64 * s),
        }),
    }
}

/// Hands a command from the bus to the agent at session time `t_s`; returns it as the agent got
/// it (for a recording).
pub fn apply_command(
    agent: &mut Agent,
    t_s: f64,
    cmd: crate::bus::Command,
) -> Option<crate::runtime::AgentCommand> {
    let c = crate::runtime::AgentCommand::from_bus(t_s, cmd)?;
    c.apply(agent);
    Some(c)
}

//! A simulated robot live on the Zenoh bus, in real time, until stopped.

use super::{HeadlessOptions, Rig};
use crate::bus::tiles::{TilePolicy, TilePublisher};
use crate::bus::translate::{self, RuntimeCounters};
use crate::bus::{BusConfig, BusHandle, Command};
use agent::localiser::FrameKind;
use agent::AgentConfig;
use common::command::{BoundsM, RobotContext};
use common::keys::RobotId;
use common::msg::{Path, Session};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Pose publication period, seconds (10 Hz).
const POSE_PERIOD_S: f64 = 0.1;
/// Status publication period, seconds (2 Hz, and on change).
const STATUS_PERIOD_S: f64 = 0.5;
/// Runs one simulated robot on the bus until `stop` is set (Ctrl-C) or the process is killed.
pub fn run_live(
    scenario: &sim::Scenario,
    scenario_name: &str,
    cfg: AgentConfig,
    robot: RobotId,
    bus_cfg: BusConfig,
    opts: &HeadlessOptions,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<()> {
    let mut rig = Rig::new(scenario, cfg, opts, robot.as_str())?;
    let bus = BusHandle::start(bus_cfg).map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    tracing::info!("robot {robot} live in scenario {scenario_name}");
    let wall0 = Instant::now();
    let mut session_sent = false;
    let (mut next_pose, mut next_status) = (0.0, 0.0);
    let mut pose_seq = 0u32;
    let mut last_path: Vec<(f64, f64)> = Vec::new();
    let mut last_state = None;
    let mut scan_times: std::collections::VecDeque<f64> = Default::default();
    let mut tiles = TilePublisher::new(
        TilePolicy::default(),
        rig.agent.lattice(),
        rig.agent.unix_ms(0.0),
    );
    while !stop.load(Ordering::Relaxed) {
        // Keep simulated time with the wall clock; if the CPU falls behind, time slows down
        // rather than the robot skipping sensor data.
        let target = wall0.elapsed().as_secs_f64();
        if rig.t_s() >= target {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        while let Some(cmd) = bus.try_recv() {
            apply(&mut rig, cmd);
        }
        bus.set_context(context(&rig));
        let ev = rig.step();
        let t = rig.t_s();
        if ev.scan {
            scan_times.push_back(t);
            while scan_times.front().is_some_and(|s| t - s > 2.0) {
                scan_times.pop_front();
            }
        }
        if !session_sent {
            if let Some((frame, datum)) = rig.agent.map_frame() {
                let lattice = rig.agent.lattice();
                bus.publish_session(&Session {
                    session_id: rig.agent.identity().session_id.clone(),
                    robot: robot.to_string(),
                    start_unix_ms: rig.agent.unix_ms(0.0),
                    frame: translate::frame_to_wire(frame),
                    datum: if frame == FrameKind::EnuAtDatum {
                        datum
                    } else {
                        None
                    },
                    cell_size_m: lattice.cell_size_m,
                    tile_cells: lattice.tile_cells,
                    source: format!("sim:{scenario_name}"),
                    agent_version: env!("CARGO_PKG_VERSION").into(),
                });
                session_sent = true;
            }
        }
        if ev.scan {
            let changed = rig.agent.take_changed_tiles();
            let agent = &rig.agent;
            for tile in tiles.publish(t, &changed, |i| agent.tile_cells(i), false) {
                bus.publish_tile(tile.index, common::grid::encode_tile(&tile));
            }
        }
        if let Some(route) = rig.agent.take_taught_route() {
            bus.publish_route(&translate::route_to_wire(&route));
        }
        if t >= next_pose {
            next_pose += POSE_PERIOD_S;
            if let Some(p) = rig.agent.pose(t) {
                bus.publish_pose(&translate::pose_to_wire(&p, rig.agent.unix_ms(t), pose_seq));
                pose_seq += 1;
            }
        }
        let agent_status = rig.agent.status(t);
        let state = (agent_status.mode, agent_status.phase, agent_status.driving);
        let status = translate::status_to_wire(
            &agent_status,
            rig.agent.unix_ms(t),
            RuntimeCounters {
                decode_errors: bus.counters().decode_errors,
                collisions: rig.collisions,
                scan_hz: scan_times.len() as f32 / 2.0,
                plan_hz: 0.0,
            },
        );
        if t >= next_status || last_state != Some(state) {
            next_status = t + STATUS_PERIOD_S;
            last_state = Some(state);
            bus.publish_status(&status);
        }
        let path = rig.agent.current_path();
        if path != last_path {
            bus.publish_path(&Path {
                t_unix_ms: rig.agent.unix_ms(t),
                goal_id: status.goal_id,
                points_m: path.iter().map(|p| (p.0 as f32, p.1 as f32)).collect(),
            });
            last_path = path;
        }
    }
    tracing::info!("robot {robot} stopping");
    bus.close();
    Ok(())
}

/// Hands a command from the bus to the agent, stamped with the agent's clock.
fn apply(rig: &mut Rig, cmd: Command) {
    let t = rig.t_s();
    match cmd {
        Command::Refused(r) => rig.agent.note_refusal(&r),
        cmd => {
            if let Some(kind) = translate::command_to_agent(cmd) {
                // A refusal is counted and logged by the agent.
                let _ = rig.agent.on_command(agent::Command::at(t, kind));
            }
        }
    }
}

/// What the bus's command checks should know about the robot now.
fn context(rig: &Rig) -> RobotContext {
    let pose = rig.agent.pose(rig.t_s());
    let lattice = rig.agent.lattice();
    let s = lattice.cell_size_f64();
    RobotContext {
        position_m: pose.map(|p| (p.pose.planar.x_m, p.pose.planar.y_m)),
        lat_lon_deg: pose.and_then(|p| p.lla.map(|l| (l.0, l.1))),
        mapped: rig
            .agent
            .mapper()
            .bounds()
            .map(|((x0, y0), (x1, y1))| BoundsM {
                min_m: (x0 as f64 * s, y0 as f64 * s),
                max_m: ((x1 + 1) as f64 * s, (y1 + 1) as f64 * s),
            }),
    }
}

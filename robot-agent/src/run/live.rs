//! A simulated robot live on the Zenoh bus, in real time, until stopped.

use super::{HeadlessOptions, Rig};
use crate::bus::{BusConfig, BusHandle};
use crate::runtime::outputs::{apply_command, LoopCounters, Outputs};
use agent::AgentConfig;
use common::keys::RobotId;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The simulated world a live robot runs in.
pub struct LiveWorld<'a> {
    /// The scenario.
    pub scenario: &'a sim::Scenario,
    /// Its name (the session's source is `sim:<name>`).
    pub name: &'a str,
    /// `--follow-drive`: a scripted drive that has the wheels until its polyline is done.
    pub drive: Option<&'a sim::scenario::RouteSpec>,
}

/// Runs one simulated robot on the bus until `stop` is set (Ctrl-C) or the process is killed.
pub fn run_live(
    world: LiveWorld<'_>,
    cfg: AgentConfig,
    robot: RobotId,
    bus_cfg: BusConfig,
    opts: &HeadlessOptions,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<()> {
    let LiveWorld {
        scenario,
        name: scenario_name,
        drive,
    } = world;
    let mut rig = Rig::new(scenario, cfg, opts, robot.as_str())?;
    // `--follow-drive`: the scripted driver has the wheels until the polyline is done.
    let mut driver = drive.map(|d| sim::drive::PathDriver::new(&d.points, d.speed_mps));
    // The bus loop publishes the agent's changed tiles.
    rig.own_tiles = false;
    let source = format!("sim:{scenario_name}");
    if let Some(m) = &opts.mcap {
        rig.record_to(m, &source, false)?;
    }
    let bus = BusHandle::start(bus_cfg).map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    tracing::info!("robot {robot} live in scenario {scenario_name}");
    let wall0 = Instant::now();
    let mut outputs = Outputs::new(&rig.agent, &source);
    let mut truth = opts
        .truth_out
        .as_deref()
        .map(crate::truth_log::TruthLog::create)
        .transpose()?;
    while !stop.load(Ordering::Relaxed) {
        // Keep simulated time with the wall clock; if the CPU falls behind, time slows down
        // rather than the robot skipping sensor data.
        let target = wall0.elapsed().as_secs_f64();
        if rig.t_s() >= target {
            std::thread::sleep(Duration::from_millis(2));
            continue;
        }
        let t = rig.t_s();
        while let Some(cmd) = bus.try_recv() {
            let applied = apply_command(&mut rig.agent, t, cmd);
            if let (Some(r), Some(c)) = (rig.recorder.as_mut(), applied) {
                r.command(&c);
            }
        }
        if let Some(d) = driver.as_mut() {
            if d.is_done() {
                driver = None;
                rig.drive_override = None;
                tracing::info!("drive done at {:.1} s", rig.t_s());
            } else {
                let (v, w) = d.command(&rig.sim.truth_pose2());
                rig.drive_override = Some(agent::Cmd {
                    v_mps: v,
                    omega_rps: w,
                });
            }
        }
        let ev = rig.step();
        let t = rig.t_s();
        if let Some(log) = truth.as_mut() {
            log.record(t, rig.agent.unix_ms(t), &rig.truth());
        }
        let counters = LoopCounters {
            collisions: rig.collisions,
            faults: recording_faults(rig.recorder.as_ref()),
            ..LoopCounters::default()
        };
        outputs.publish(
            Some(&bus),
            rig.recorder.as_mut(),
            &mut rig.agent,
            t,
            ev.scan,
            &counters,
        );
    }
    tracing::info!("robot {robot} stopping");
    bus.close();
    if let Some(summary) = rig.finish_recording() {
        println!("{}", serde_json::json!({ "record": summary }));
    }
    Ok(())
}

/// What the status should say about the recording: messages it had to drop, or that it stopped.
pub fn recording_faults(rec: Option<&crate::record::SessionRecorder>) -> Vec<String> {
    let Some(s) = rec.map(|r| r.stats()) else {
        return Vec::new();
    };
    let mut v = Vec::new();
    if let Some(e) = &s.error {
        v.push(format!("recording stopped: {e}"));
    } else if s.dropped() > 0 {
        v.push(format!("recording dropped {} messages", s.dropped()));
    }
    v
}

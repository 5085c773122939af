//! `robot-agent run`: the agent on a robot until stopped. Drivers run on their own threads and
//! send their messages here; this loop owns the [`Runtime`], keeps its clock (the newest header
//! stamp, advanced by the wall clock between messages so a silent sensor is noticed), applies
//! the station's commands, sends the base its command at the control rate, and publishes.
//! On stop (SIGINT/SIGTERM) the base gets a zero command before the bus closes.

use crate::bus::{BusConfig, BusHandle};
use crate::runtime::faults::FaultLog;
use crate::runtime::outputs::{apply_command, LoopCounters, Outputs};
use crate::runtime::stamps::Topic;
use crate::runtime::{Input, Runtime, RuntimeLimits};
use agent::{AgentConfig, Cmd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// What a driver thread tells the loop.
#[derive(Debug)]
pub enum SourceEvent {
    /// A decoded message.
    Input(Input),
    /// A message of `topic` that could not be decoded, and why (counted, logged at debug).
    Undecodable(Topic, String),
    /// The driver of `topic` stopped for good, and why (logged; the watchdog reports silence).
    Ended(Topic, String),
}

/// A driver: started on its own thread with the channel to the loop and the stop flag.
pub type SourceStart = Box<dyn FnOnce(Sender<SourceEvent>, Arc<AtomicBool>) + Send>;

/// Where base commands go (`cmd_vel`, a navigation computer, nowhere).
pub trait Base: Send {
    /// Sends one velocity command.
    fn drive(&mut self, cmd: Cmd) -> anyhow::Result<()>;
    /// The robot stops for good (the runtime is closing).
    fn stop(&mut self) -> anyhow::Result<()> {
        self.drive(Cmd::default())
    }
    /// What the base did, for the run's summary (`null`: nothing to say).
    fn report(&self) -> serde_json::Value {
        serde_json::Value::Null
    }
}

/// A base that only logs (a robot driven by hand, or mapping only).
pub struct NoBase;

impl Base for NoBase {
    fn drive(&mut self, _cmd: Cmd) -> anyhow::Result<()> {
        Ok(())
    }
}

/// Everything `run` needs.
pub struct RobotRun {
    /// The agent's configuration.
    pub agent: AgentConfig,
    /// Stamp gate and watchdog limits.
    pub limits: RuntimeLimits,
    /// Robot id.
    pub robot: String,
    /// The bus.
    pub bus: BusConfig,
    /// The inputs the robot has (for the watchdog).
    pub inputs: Vec<Topic>,
    /// The drivers to start.
    pub sources: Vec<SourceStart>,
    /// Where commands go.
    pub base: Box<dyn Base>,
    /// The session record's `source` (`ros2`, `vlp16-udp+nmea-tcp`, ...).
    pub source_name: String,
    /// Print every GNSS fix the agent takes as a JSON line on stdout (`{"fix": {...}}`).
    pub print_fixes: bool,
    /// Record the session to MCAP (`--mcap`).
    pub record: Option<crate::record::RecordOptions>,
}

fn wall_unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// Runs until `stop` is set. Returns the runtime's counts as a JSON value for the last line.
pub fn run_robot(mut r: RobotRun, stop: Arc<AtomicBool>) -> anyhow::Result<serde_json::Value> {
    let bus = BusHandle::start(r.bus.clone()).map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
    let (tx, rx) = std::sync::mpsc::channel();
    let mut threads = Vec::new();
    for start in r.sources.drain(..) {
        let (tx, stop) = (tx.clone(), stop.clone());
        threads.push(std::thread::spawn(move || start(tx, stop)));
    }
    drop(tx);
    r.base.drive(Cmd::default())?;
    tracing::info!("robot {} waiting for its first sensor message", r.robot);
    let Some((first, rt)) = first_input(&rx, &stop, &r)? else {
        // The drivers finish before their I/O runtimes go (they wait on its timers).
        for t in threads {
            let _ = t.join();
        }
        return close(bus, r.base.as_mut(), None);
    };
    let mut rt = rt;
    let mut outputs = Outputs::new(rt.agent(), &r.source_name);
    let mut rec = match &r.record {
        Some(opts) => {
            let cfg = rt.agent().config();
            let meta = crate::record::SessionMeta {
                identity: rt.agent().identity().clone(),
                t0_s: rt.t0_s(),
                source: r.source_name.clone(),
                inputs: r.inputs.clone(),
                config_files: opts.config_files.clone(),
                datum: cfg.datum,
                config_digest: crate::record::config_digest(cfg),
            };
            Some(crate::record::SessionRecorder::start(opts, &meta, cfg)?)
        }
        None => None,
    };
    let mut clock = LoopClock::default();
    let mut pending = Some(first);
    let mut fault_log = FaultLog::default();
    let mut last_rec_faults: Vec<String> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let event = match pending.take() {
            Some(e) => Some(e),
            None => match rx.recv_timeout(Duration::from_millis(5)) {
                Ok(e) => Some(e),
                Err(RecvTimeoutError::Timeout) => None,
                Err(RecvTimeoutError::Disconnected) => {
                    tracing::warn!("every driver stopped");
                    break;
                }
            },
        };
        let mut scanned = false;
        if let Some(e) = event {
            match e {
                SourceEvent::Input(input) => {
                    if let Some(rec) = rec.as_mut() {
                        rec.input(&input);
                    }
                    if let crate::runtime::Admitted::Yes { scan } = rt.on_input(input) {
                        scanned = scan;
                        if let Some(t) = rt.newest_s() {
                            clock.heard(t);
                        }
                    }
                    if let Some(f) = rt.take_new_fix().filter(|_| r.print_fixes) {
                        print_line(&serde_json::json!({ "fix": f }));
                    }
                }
                SourceEvent::Undecodable(topic, why) => {
                    rt.count_undecodable(topic);
                    tracing::debug!("undecodable {topic} message: {why}");
                    if let Some(rec) = rec.as_mut() {
                        rec.undecodable(&topic.to_string(), &why, clock.now_s());
                    }
                }
                SourceEvent::Ended(topic, why) => tracing::warn!("{topic} driver ended: {why}"),
            }
        }
        let now = clock.now_s();
        while let Some(cmd) = bus.try_recv() {
            let applied = apply_command(rt.agent_mut(), now, cmd);
            if let (Some(rec), Some(c)) = (rec.as_mut(), applied) {
                rec.command(&c);
            }
        }
        if let Some(cmd) = rt.control(now) {
            if let Some(rec) = rec.as_mut() {
                // The control time a replay runs control at (this loop's clock is the wall's).
                rec.control(now, rt.agent(), cmd);
            }
            if let Err(e) = r.base.drive(cmd) {
                tracing::warn!("base command: {e:#}");
            }
        }
        let in_force = rt.faults(now);
        let (began, ended) = fault_log.note(&in_force);
        for f in in_force.iter().filter(|f| began.contains(&f.topic)) {
            tracing::warn!("{f}");
            if let Some(rec) = rec.as_mut() {
                rec.log(
                    record::foxglove::level::WARNING,
                    "runtime",
                    &f.to_string(),
                    now,
                );
            }
        }
        let rec_faults = crate::run::live::recording_faults(rec.as_ref());
        if rec_faults != last_rec_faults {
            for f in rec_faults.iter().filter(|f| !last_rec_faults.contains(f)) {
                tracing::warn!("{f}");
            }
            last_rec_faults = rec_faults.clone();
        }
        for topic in ended {
            tracing::info!("{topic} is back");
        }
        let mut faults: Vec<String> = in_force.iter().map(ToString::to_string).collect();
        faults.extend(rec_faults);
        let counters = LoopCounters {
            collisions: 0,
            bad_inputs: rt.bad_inputs(),
            faults,
        };
        outputs.publish(
            Some(&bus),
            rec.as_mut(),
            rt.agent_mut(),
            now,
            scanned,
            &counters,
        );
    }
    for t in threads {
        let _ = t.join();
    }
    let record = rec.map(|rec| rec.finish(Some(rt.agent())));
    let mut summary = close(bus, r.base.as_mut(), Some((&rt, &fault_log)))?;
    if let Some(record) = record {
        summary["record"] = serde_json::to_value(record)?;
    }
    Ok(summary)
}

/// One JSON line on stdout, flushed (a reader may act on it at once).
fn print_line(v: &serde_json::Value) {
    use std::io::Write;
    let mut o = std::io::stdout().lock();
    let _ = writeln!(o, "{v}");
    let _ = o.flush();
}

/// Waits for the first decodable message to start the session clock.
fn first_input(
    rx: &Receiver<SourceEvent>,
    stop: &AtomicBool,
    r: &RobotRun,
) -> anyhow::Result<Option<(SourceEvent, Runtime)>> {
    while !stop.load(Ordering::Relaxed) {
        match rx.recv_timeout(Duration::from_millis(50)) {
            Ok(SourceEvent::Input(input)) => {
                let stamp = input.stamp_s();
                if !stamp.is_finite() || stamp < 0.0 {
                    continue;
                }
                let rt = Runtime::new(
                    r.agent.clone(),
                    r.limits,
                    &r.robot,
                    &r.inputs,
                    stamp,
                    wall_unix_ms(),
                )?;
                return Ok(Some((SourceEvent::Input(input), rt)));
            }
            Ok(SourceEvent::Undecodable(topic, why)) => {
                tracing::debug!("undecodable {topic} message before the first: {why}")
            }
            Ok(SourceEvent::Ended(topic, why)) => tracing::warn!("{topic} driver ended: {why}"),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => {
                anyhow::bail!("every driver stopped before sending a message")
            }
        }
    }
    Ok(None)
}

/// The summary: what the agent took in and made of it, the runtime's counts, the sensor faults
/// that came and went, and what the base did.
fn close(
    bus: BusHandle,
    base: &mut dyn Base,
    rt: Option<(&Runtime, &FaultLog)>,
) -> anyhow::Result<serde_json::Value> {
    if let Err(e) = base.stop() {
        tracing::warn!("stopping the base: {e:#}");
    }
    bus.close();
    Ok(match rt {
        Some((rt, faults)) => {
            let a = rt.agent();
            let tiles = a.all_tiles();
            serde_json::json!({
                "scans": a.scans(),
                "depth_frames": a.depth_frames(),
                "map": {
                    "scans_mapped": u64::from(a.scans()).saturating_sub(a.scans_not_mapped()),
                    "tiles": tiles.len(),
                    "known_cells": tiles.iter().map(|t| t.known_cells()).sum::<usize>(),
                },
                "counts": rt.counts(),
                "faults": faults,
                "base": base.report(),
            })
        }
        None => serde_json::json!({ "scans": 0, "base": base.report() }),
    })
}

/// The loop's session clock: the newest accepted stamp, advanced by the wall clock since it
/// arrived (so time goes on while every sensor is silent, and the watchdog can fire).
#[derive(Default)]
struct LoopClock {
    at: Option<(f64, Instant)>,
}

impl LoopClock {
    fn heard(&mut self, t_s: f64) {
        if self.at.is_none_or(|(t, _)| t_s > t) {
            self.at = Some((t_s, Instant::now()));
        }
    }

    fn now_s(&self) -> f64 {
        self.at.map_or(0.0, |(t, w)| t + w.elapsed().as_secs_f64())
    }
}

/// The VLP-16 driver on UDP `port`: scans from the packets' host receive times.
pub fn vlp16_udp(port: u16, config: sensing::velodyne::VelodyneConfig) -> SourceStart {
    Box::new(move |tx, stop| {
        let addr = std::net::SocketAddr::from(([0, 0, 0, 0], port));
        let mut src = match sensing::velodyne::udp::UdpScanSource::bind(addr, config) {
            Ok(s) => s,
            Err(e) => {
                let _ = tx.send(SourceEvent::Ended(
                    Topic::Lidar,
                    format!("binding {addr}: {e}"),
                ));
                return;
            }
        };
        let mut malformed = 0;
        while !stop.load(Ordering::Relaxed) {
            match src.next_scan(Duration::from_millis(200)) {
                Ok(Some(s)) => {
                    if tx
                        .send(SourceEvent::Input(Input::Scan(s.to_scan())))
                        .is_err()
                    {
                        return;
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    let _ = tx.send(SourceEvent::Ended(Topic::Lidar, e.to_string()));
                    return;
                }
            }
            let m = src.stats().malformed();
            for _ in malformed..m {
                let _ = tx.send(SourceEvent::Undecodable(
                    Topic::Lidar,
                    "malformed VLP-16 packet".into(),
                ));
            }
            malformed = m;
        }
    })
}

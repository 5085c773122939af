//! `robot-agent run --replay FILE`: a recording through the same [`Runtime`] that ran it.
//!
//! A terranav recording replays exactly: the runtime is rebuilt with the recorded identity, clock
//! origin and configuration; inputs go in in the recorded order, commands are applied at their
//! recorded agent time, and control runs at the recorded control times (the live loop's clock came
//! from the wall clock between messages; the recording kept the times it gave). Each control
//! period's command is checked against the recorded one, and the run's digest (poses, plans, map,
//! commands) against the one the recording closed with. A ROS 2 bag replays its inputs with
//! control every period on the bag's clock (a bag has no commands).
//!
//! `--speed X` paces the replay at X times the recorded time (1: as recorded); without pacing it
//! runs as fast as it can. With `--connect`/`--zenoh` the outputs go to a station as a live robot's
//! would; with `--mcap OUT` the replay is recorded in turn (a bag replayed to a terranav recording
//! is viewable with the grid, poses and plans the agent computed from it).

use super::digest::{Digest, RunDigest};
use super::rosbag::{self, BagTopics, Db3, Decoder};
use super::{config_digest, config_from_files, RecordOptions, SessionMeta, SessionRecorder};
use crate::bus::{BusConfig, BusHandle};
use crate::runtime::outputs::{LoopCounters, Outputs};
use crate::runtime::stamps::Topic;
use crate::runtime::{AgentCommand, Input, Runtime, RuntimeCounts, RuntimeLimits};
use agent::{AgentConfig, Cmd};
use record::Reader;
use serde::Serialize;
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod sources;
use sources::{is_terranav, mcap_topics, BagReader, BagSource, RecordingSource, Source};

/// One thing the runtime is told, in order.
#[derive(Clone, Debug)]
pub enum Event {
    /// A sensor input.
    Input(Input),
    /// A message that could not be read back (counted as the runtime counts a driver's).
    Undecodable(Topic, String),
    /// A command at its agent time.
    Command(AgentCommand),
    /// A control period at `t_s` that sent `cmd`.
    Control {
        /// Agent time, seconds.
        t_s: f64,
        /// What the base was sent.
        cmd: Cmd,
    },
}

/// What to replay and how.
pub struct ReplayOptions {
    /// The recording: an MCAP file, a folder of a split recording, or a `.db3` bag.
    pub path: PathBuf,
    /// Pace at this multiple of the recorded time; `None`: as fast as possible.
    pub speed: Option<f64>,
    /// The agent's configuration for a bag (and a recording's, with `override_config`).
    pub config: (AgentConfig, RuntimeLimits),
    /// Replay a recording with `config` instead of the one it recorded (`--config`).
    pub override_config: bool,
    /// Robot id for a bag (a recording has its own).
    pub robot: String,
    /// The bag topics the robot's `[io]` specs name.
    pub topics: BagTopics,
    /// Publish the outputs on this bus.
    pub bus: Option<BusConfig>,
    /// Record the replay.
    pub record: Option<RecordOptions>,
}

/// The last line of a replay.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReplayReport {
    /// What was replayed.
    pub replay: String,
    /// `terranav`, `ros2-mcap` or `ros2-db3`.
    pub format: String,
    /// Bag topics and what they fed (bags).
    pub topics: Vec<(String, String)>,
    /// Inputs fed to the runtime.
    pub inputs: u64,
    /// Commands applied.
    pub commands: u64,
    /// Control periods run.
    pub controls: u64,
    /// Control periods whose command differed from the recorded one (or that did not fall due).
    pub control_mismatches: u64,
    /// Sweeps the agent processed.
    pub scans: u64,
    /// The runtime's counts.
    pub counts: RuntimeCounts,
    /// Messages that could not be read back.
    pub bad_messages: u64,
    /// Messages the recording had dropped (gaps in its sequence numbers).
    pub recording_gaps: u64,
    /// Why the file ended early, when it did (a cut recording).
    pub truncated: Option<String>,
    /// Sweeps of a bag left out because the bag ended in them.
    pub partial_sweeps: u64,
    /// Session time replayed, seconds.
    pub time_s: f64,
    /// Wall-clock time, seconds.
    pub wall_s: f64,
    /// The replay's digest.
    pub digest: Option<Digest>,
    /// The digest the recording closed with.
    pub recorded_digest: Option<Digest>,
    /// The two are equal (None: the recording has none).
    pub digest_match: Option<bool>,
    /// The configuration is the recorded one (None: a bag).
    pub config_match: Option<bool>,
    /// The replay's own recording.
    pub record: Option<super::RecordSummary>,
}

/// Replays until the end (or `stop`); the report is the run's last line.
pub fn run_replay(opts: ReplayOptions, stop: Arc<AtomicBool>) -> anyhow::Result<ReplayReport> {
    let path = &opts.path;
    anyhow::ensure!(
        path.exists(),
        "--replay {}: no such file or folder",
        path.display()
    );
    let mut report = ReplayReport {
        replay: path.display().to_string(),
        ..ReplayReport::default()
    };
    let (cfg, limits) = (opts.config.0.clone(), opts.config.1);
    let bag = |reader: BagReader,
               topics: Vec<(String, String)>|
     -> anyhow::Result<(Source, Vec<Topic>)> {
        let roles = rosbag::assign(&topics, &opts.topics);
        anyhow::ensure!(
            roles.values().any(|r| *r == rosbag::Role::Lidar),
            "the bag has no LiDAR topic the runtime knows (topics: {topics:?}); name it with --lidar ros2:TOPIC"
        );
        let decoder = Decoder::new(
            roles,
            cfg.profile.lidar.isometry(),
            cfg.profile.depth_camera.isometry(),
        );
        let streams = decoder.streams();
        Ok((
            Source::Bag(Box::new(BagSource {
                reader,
                decoder,
                pending: VecDeque::new(),
                truncated: None,
                ended: false,
            })),
            streams,
        ))
    };
    let (mut source, streams) = if path.is_file() && rosbag::is_sqlite(path) {
        report.format = "ros2-db3".into();
        let (db, topics) = Db3::open(path)?;
        bag(BagReader::Db3(db), topics)?
    } else {
        let files = record::writer::recording_files(path)?;
        anyhow::ensure!(
            !files.is_empty(),
            "--replay {}: no .mcap files",
            path.display()
        );
        if is_terranav(&files[0])? {
            report.format = "terranav".into();
            let s = RecordingSource::open(files)?;
            let streams = s
                .meta
                .as_ref()
                .map(|m| m.inputs.clone())
                .unwrap_or_default();
            (Source::Recording(Box::new(s)), streams)
        } else {
            anyhow::ensure!(files.len() == 1, "a ROS 2 MCAP bag is one file");
            report.format = "ros2-mcap".into();
            let topics = mcap_topics(&files[0])?;
            bag(BagReader::Mcap(Box::new(Reader::open(&files[0])?)), topics)?
        }
    };
    if let Source::Bag(b) = &source {
        report.topics = b
            .decoder
            .roles()
            .iter()
            .map(|(t, r)| (t.clone(), format!("{r:?}").to_lowercase()))
            .collect();
        for (t, r) in &report.topics {
            tracing::info!("replay: {t} -> {r}");
        }
    }

    // The runtime: a recording's own, or a bag's at its first input.
    let meta = match &source {
        Source::Recording(r) => r.meta.clone(),
        Source::Bag(_) => None,
    };
    let mut rt: Option<Runtime> = None;
    if let Some(m) = &meta {
        let (c, l) = if opts.override_config {
            (cfg.clone(), limits)
        } else {
            let (c, run) = config_from_files(&m.config_files, m.datum)?;
            (c, run.runtime.limits()?)
        };
        let matches = config_digest(&c) == m.config_digest;
        if !matches {
            tracing::warn!("replaying with another configuration than the recorded one: the outputs will differ");
        }
        report.config_match = Some(matches);
        rt = Some(Runtime::resume(
            c,
            l,
            m.identity.clone(),
            &m.inputs,
            m.t0_s,
        )?);
    }
    let bus = match &opts.bus {
        Some(b) => Some(BusHandle::start(b.clone()).map_err(|e| anyhow::anyhow!("zenoh: {e}"))?),
        None => None,
    };
    let replays_control = matches!(source, Source::Recording(_));
    let mut outputs: Option<Outputs> = None;
    let mut recorder: Option<SessionRecorder> = None;
    let mut digest = RunDigest::default();
    let wall0 = Instant::now();
    let mut first_t: Option<f64> = None;
    let mut now = 0.0f64;
    while !stop.load(Ordering::Relaxed) {
        let Some(ev) = source.next_event() else {
            break;
        };
        let ev = match ev {
            Ok(e) => e,
            Err(e) => {
                report.bad_messages += 1;
                tracing::warn!("replay: {e:#}");
                continue;
            }
        };
        if rt.is_none() {
            // A bag: the session starts at its first input.
            let Event::Input(i) = &ev else {
                continue;
            };
            let stamp = i.stamp_s();
            if !stamp.is_finite() || stamp < 0.0 {
                continue;
            }
            rt = Some(Runtime::new(
                cfg.clone(),
                limits,
                &opts.robot,
                &streams,
                stamp,
                wall_unix_ms(),
            )?);
        }
        let Some(r) = rt.as_mut() else { continue };
        if outputs.is_none() && (bus.is_some() || opts.record.is_some()) {
            let source_name = format!("replay:{}", path.display());
            outputs = Some(Outputs::new(r.agent(), &source_name));
            if let Some(ro) = &opts.record {
                let m = SessionMeta {
                    identity: r.agent().identity().clone(),
                    t0_s: r.t0_s(),
                    source: source_name.clone(),
                    inputs: streams.clone(),
                    config_files: meta
                        .as_ref()
                        .map(|m| m.config_files.clone())
                        .unwrap_or_else(|| ro.config_files.clone()),
                    datum: r.agent().config().datum,
                    config_digest: config_digest(r.agent().config()),
                };
                recorder = Some(SessionRecorder::start(ro, &m, r.agent().config())?);
            }
        }
        let t_event = match &ev {
            Event::Input(i) => r.session_time_s(i.stamp_s()),
            Event::Command(c) => c.t_s(),
            Event::Control { t_s, .. } => *t_s,
            Event::Undecodable(..) => now,
        };
        if let Some(speed) = opts.speed {
            let t0 = *first_t.get_or_insert(t_event);
            let due = Duration::from_secs_f64(((t_event - t0) / speed).max(0.0));
            let elapsed = wall0.elapsed();
            if due > elapsed {
                std::thread::sleep(due - elapsed);
            }
        }
        let mut scanned = false;
        match ev {
            Event::Input(i) => {
                report.inputs += 1;
                if let Some(rec) = recorder.as_mut() {
                    rec.input(&i);
                }
                if let crate::runtime::Admitted::Yes { scan } = r.on_input(i) {
                    scanned = scan;
                    if let Some(t) = r.newest_s() {
                        now = now.max(t);
                    }
                }
            }
            Event::Undecodable(topic, why) => {
                report.bad_messages += 1;
                r.count_undecodable(topic);
                if let Some(rec) = recorder.as_mut() {
                    rec.undecodable(&topic.to_string(), &why, now);
                }
            }
            Event::Command(c) => {
                report.commands += 1;
                now = now.max(c.t_s());
                if let Some(rec) = recorder.as_mut() {
                    rec.command(&c);
                }
                c.apply(r.agent_mut());
            }
            Event::Control { t_s, cmd: recorded } => {
                now = now.max(t_s);
                match r.control(t_s) {
                    Some(cmd) => {
                        report.controls += 1;
                        if cmd != recorded {
                            report.control_mismatches += 1;
                        }
                        digest.control(t_s, r.agent(), cmd);
                        if let Some(rec) = recorder.as_mut() {
                            rec.control(t_s, r.agent(), cmd);
                        }
                    }
                    None => report.control_mismatches += 1,
                }
            }
        }
        if !replays_control {
            if let Some(cmd) = r.control(now) {
                report.controls += 1;
                digest.control(now, r.agent(), cmd);
                if let Some(rec) = recorder.as_mut() {
                    rec.control(now, r.agent(), cmd);
                }
            }
        }
        if let Some(o) = outputs.as_mut() {
            let counters = LoopCounters {
                collisions: 0,
                bad_inputs: r.bad_inputs(),
                faults: Vec::new(),
            };
            o.publish(
                bus.as_ref(),
                recorder.as_mut(),
                r.agent_mut(),
                now,
                scanned,
                &counters,
            );
        }
    }
    match &source {
        Source::Recording(s) => {
            report.recording_gaps = s.gaps;
            report.truncated = s.truncated.clone();
            report.recorded_digest = s.digest.clone();
        }
        Source::Bag(b) => {
            report.truncated = b.truncated.clone();
            report.partial_sweeps = b.decoder.partial_sweeps;
        }
    }
    if let Some(b) = bus {
        b.close();
    }
    report.wall_s = wall0.elapsed().as_secs_f64();
    report.time_s = now;
    if let Some(r) = &rt {
        report.scans = u64::from(r.agent().scans());
        report.counts = r.counts();
        let d = digest.finish(r.agent());
        report.digest_match = report.recorded_digest.as_ref().map(|rd| *rd == d);
        report.digest = Some(d);
    }
    if let Some(rec) = recorder {
        report.record = Some(rec.finish(rt.as_ref().map(Runtime::agent)));
    }
    Ok(report)
}

fn wall_unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

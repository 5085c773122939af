//! Helpers of the real-robot-path tests: the simulated world served as ROS 2 hardware
//! (`robot-agent sim --serve-ros2`, its stdout collected: datum, truth lines) and `robot-agent
//! run` against it, both real processes on loopback.
#![allow(dead_code)]

use crate::station_support::*;
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use support::{bin, free_port, workspace_root, KillOnDrop};

/// Holds the machine for one real-time world (and its agent and station) at a time: two of them
/// at once on two cores make each other's sensors late, and the LiDAR watchdog then stops the
/// robots over and over (`cargo test` runs a binary's tests on parallel threads).
pub fn one_world_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// `robot-agent sim --serve-ros2` with its stdout (datum, then truth lines) collected.
pub struct World {
    _proc: KillOnDrop,
    /// The Zenoh endpoint it listens on (the robot's ROS 2 side).
    pub endpoint: String,
    lines: Arc<Mutex<Vec<Value>>>,
    /// Its log (stderr).
    pub log: PathBuf,
}

impl World {
    /// Starts the world of `scenario` (a path from the workspace root) in key form `keys`, with
    /// `extra` arguments; waits for its datum line.
    pub fn start(scenario: &str, keys: &str, extra: &[&str], dir: &Path) -> World {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let log = dir.join(format!("world-{keys}.log"));
        let mut p = KillOnDrop::spawn(
            Command::new(bin("robot-agent"))
                .current_dir(workspace_root())
                .args([
                    "sim",
                    "--scenario",
                    scenario,
                    "--serve-ros2",
                    "--ros2-keys",
                    keys,
                    "--listen",
                    &endpoint,
                    "--truth-period-s",
                    "0.1",
                ])
                .args(extra)
                .env("RUST_LOG", "info,zenoh=warn")
                .env("NO_COLOR", "1")
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(&log).unwrap()),
        )
        .expect("start the world");
        let out = p.0.stdout.take().unwrap();
        let lines: Arc<Mutex<Vec<Value>>> = Arc::default();
        let sink = lines.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                if let Ok(v) = serde_json::from_str::<Value>(&l) {
                    sink.lock().unwrap().push(v);
                }
            }
        });
        let w = World {
            _proc: p,
            endpoint,
            lines,
            log,
        };
        assert!(
            wait_for(Duration::from_secs(20), || w.datum().is_some()),
            "the world never printed its datum\n{}",
            tail(&w.log, 20)
        );
        w
    }

    /// The datum line's `LAT,LON,H`.
    pub fn datum(&self) -> Option<String> {
        let l = self.lines.lock().unwrap();
        l.first()?["datum"].as_str().map(str::to_owned)
    }

    /// Unix time of the world's time 0, seconds.
    pub fn epoch_unix_s(&self) -> f64 {
        let l = self.lines.lock().unwrap();
        l.first().and_then(|v| v["epoch_unix_s"].as_f64()).unwrap()
    }

    /// The truth lines so far.
    pub fn truth(&self) -> Vec<Value> {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .filter(|v| v.get("x_m").is_some())
            .cloned()
            .collect()
    }

    /// Every stdout line so far (datum, truth, events such as `obstacles_added`).
    pub fn lines(&self) -> Vec<Value> {
        self.lines.lock().unwrap().clone()
    }

    /// The world's time now (its newest truth line), seconds.
    pub fn now_s(&self) -> f64 {
        self.truth()
            .last()
            .and_then(|v| v["t_s"].as_f64())
            .unwrap_or(0.0)
    }
}

/// `robot-agent run` against the world.
pub struct Agent {
    /// The process.
    pub proc: KillOnDrop,
    /// Its log (stderr).
    pub log: PathBuf,
}

impl Agent {
    /// Starts `robot-agent run --robot r1` on the world's topics (key form `keys`), connected
    /// to the station, with `extra` arguments.
    pub fn start(
        world: &World,
        station: &Station,
        keys: &str,
        extra: &[&str],
        dir: &Path,
    ) -> Agent {
        let log = dir.join(format!("run-{keys}.log"));
        let datum = world.datum().unwrap();
        let proc = KillOnDrop::spawn(
            Command::new(bin("robot-agent"))
                .current_dir(workspace_root())
                .args([
                    "run",
                    "--robot",
                    "r1",
                    "--connect",
                    &station.ports.endpoint(),
                    "--ros2-connect",
                    &world.endpoint,
                    "--ros2-keys",
                    keys,
                    "--heading",
                    "ros2:heading",
                    "--datum",
                    &datum,
                ])
                .args(extra)
                .env("RUST_LOG", "info,zenoh=warn")
                .env("NO_COLOR", "1")
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(&log).unwrap()),
        )
        .expect("start robot-agent run");
        Agent { proc, log }
    }

    /// Panics with the log's tail when the process has exited.
    pub fn assert_running(&mut self) {
        if let Ok(Some(s)) = self.proc.0.try_wait() {
            panic!("robot-agent run exited: {s}\n{}", tail(&self.log, 30));
        }
    }

    /// SIGTERM, then the summary line it prints on a clean stop.
    pub fn stop(mut self) -> Value {
        let pid = self.proc.0.id().to_string();
        assert!(Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success());
        let mut out = String::new();
        std::io::Read::read_to_string(self.proc.0.stdout.as_mut().unwrap(), &mut out).unwrap();
        let status = self.proc.0.wait().unwrap();
        assert!(
            status.success(),
            "run exited {status}\n{}",
            tail(&self.log, 30)
        );
        serde_json::from_str(out.lines().last().unwrap_or(""))
            .unwrap_or_else(|e| panic!("summary line {out:?}: {e}\n{}", tail(&self.log, 30)))
    }
}

/// Waits until the station shows `r1` online, anchored at the datum, with a pose.
pub fn wait_up(station: &Station, agent: &mut Agent) {
    let ok = wait_for(Duration::from_secs(60), || {
        agent.assert_running();
        robot_entry(station.ports.http, "r1").is_some_and(|r| {
            r["online"] == true && r["session"]["frame"] == "EnuAtDatum" && !r["pose"].is_null()
        })
    });
    assert!(
        ok,
        "robot never came up anchored: {:?}\n{}",
        robot_entry(station.ports.http, "r1"),
        tail(&agent.log, 30)
    );
}

/// The count of `topic` in a summary's per-topic list `key` (`undecodable`, `accepted`).
pub fn per_topic(summary: &Value, key: &str, topic: &str) -> u64 {
    summary["counts"][key]
        .as_array()
        .into_iter()
        .flatten()
        .find(|e| e[0] == topic)
        .and_then(|e| e[1].as_u64())
        .unwrap_or(0)
}

/// Stamps refused on `topic` for `reason` (`backwards`, `other_clock`, ...) in a summary.
pub fn stamp_refused(summary: &Value, topic: &str, reason: &str) -> u64 {
    summary["counts"]["stamp_refused"]
        .as_array()
        .into_iter()
        .flatten()
        .find(|e| e[0] == topic && e[1] == reason)
        .and_then(|e| e[2].as_u64())
        .unwrap_or(0)
}

/// The fault log entry of `topic` in a summary.
pub fn fault_episodes(summary: &Value, topic: &str) -> Option<Value> {
    summary["faults"]["inputs"]
        .as_array()?
        .iter()
        .find(|e| e["topic"] == topic)
        .cloned()
}

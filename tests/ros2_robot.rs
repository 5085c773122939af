//! The real-robot path end to end, all real processes on loopback: the simulated world served
//! as ROS 2 topics (`robot-agent sim --serve-ros2`, the robot's "hardware"), the agent on it
//! (`robot-agent run`, exactly as on a real robot) and `operator-station serve`. A goal sent
//! through the station is judged against the simulator's truth (the world's stdout), in both
//! ROS 2 key forms; sensor faults and garbage on the input topics are injected on the way.

mod station_support;

use serde_json::Value;
use station_support::*;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use support::{bin, free_port, workspace_root, KillOnDrop};

/// The park goal (30 m from the start at (-40, 0)) and how close the truth must end.
const GOAL: (f64, f64) = (-12.0, 0.0);
const GOAL_TOLERANCE_M: f64 = 0.5;
/// Real time allowed for the drive (about 60 s at the robot's 0.5 m/s).
const DRIVE: Duration = Duration::from_secs(240);

/// `robot-agent sim --serve-ros2` with its stdout (datum, then truth lines) collected.
struct World {
    _proc: KillOnDrop,
    endpoint: String,
    lines: Arc<Mutex<Vec<Value>>>,
    log: std::path::PathBuf,
}

impl World {
    fn start(keys: &str, extra: &[&str], dir: &Path) -> World {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let log = dir.join(format!("world-{keys}.log"));
        let mut p = KillOnDrop::spawn(
            Command::new(bin("robot-agent"))
                .current_dir(workspace_root())
                .args([
                    "sim",
                    "--scenario",
                    "config/scenarios/park.toml",
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

    fn datum(&self) -> Option<String> {
        let l = self.lines.lock().unwrap();
        l.first()?["datum"].as_str().map(str::to_owned)
    }

    /// The truth lines so far.
    fn truth(&self) -> Vec<Value> {
        self.lines
            .lock()
            .unwrap()
            .iter()
            .filter(|v| v.get("x_m").is_some())
            .cloned()
            .collect()
    }
}

/// `robot-agent run` against the world.
struct Agent {
    proc: KillOnDrop,
    log: std::path::PathBuf,
}

impl Agent {
    fn start(world: &World, station: &Station, keys: &str, dir: &Path) -> Agent {
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
                .env("RUST_LOG", "info,zenoh=warn")
                .env("NO_COLOR", "1")
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(std::fs::File::create(&log).unwrap()),
        )
        .expect("start robot-agent run");
        Agent { proc, log }
    }

    fn assert_running(&mut self) {
        if let Ok(Some(s)) = self.proc.0.try_wait() {
            panic!("robot-agent run exited: {s}\n{}", tail(&self.log, 30));
        }
    }

    /// SIGTERM, then the summary line it prints on a clean stop.
    fn stop(mut self) -> Value {
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

fn wait_up(station: &Station, agent: &mut Agent) {
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

fn send_goal(station: &Station) {
    let (st, body) = http(
        station.ports.http,
        "POST",
        "/api/robots/r1/goal",
        &format!(r#"{{"x": {}, "y": {}}}"#, GOAL.0, GOAL.1),
    )
    .expect("station answers");
    assert_eq!(st, 202, "{body}");
}

/// Waits for the station to report the goal reached, watching `each` status on the way.
fn drive(station: &Station, agent: &mut Agent, mut each: impl FnMut(&Value)) -> Value {
    let mut last = Value::Null;
    let ok = wait_for(DRIVE, || {
        agent.assert_running();
        let Some(r) = robot_entry(station.ports.http, "r1") else {
            return false;
        };
        each(&r);
        let m = r["status"]["mission"].clone();
        last = r;
        assert!(
            m != "NoPath" && m != "Stopped",
            "mission ended {m}: {}",
            last["status"]
        );
        m == "Reached"
    });
    assert!(ok, "goal not reached: {}", last["status"]);
    last
}

/// Judges the drive by the simulator's truth: within tolerance of the goal, no collision.
fn judge(world: &World) -> Value {
    std::thread::sleep(Duration::from_millis(300));
    let truth = world.truth();
    let last = truth.last().expect("truth lines").clone();
    let (x, y) = (last["x_m"].as_f64().unwrap(), last["y_m"].as_f64().unwrap());
    let err = (x - GOAL.0).hypot(y - GOAL.1);
    println!("truth at the end ({x:.2}, {y:.2}): {err:.2} m from the goal; {last}");
    assert!(
        err <= GOAL_TOLERANCE_M,
        "truth ({x:.2}, {y:.2}) is {err:.2} m from the goal"
    );
    assert_eq!(last["collisions"], 0, "{last}");
    assert!(last["cmd_vel_received"].as_u64().unwrap() > 100, "{last}");
    last
}

fn undecodable(summary: &Value, topic: &str) -> u64 {
    summary["counts"]["undecodable"]
        .as_array()
        .into_iter()
        .flatten()
        .find(|e| e[0] == topic)
        .and_then(|e| e[1].as_u64())
        .unwrap_or(0)
}

#[test]
fn bridge_keys_goal_through_the_station_is_reached_and_garbage_is_counted() {
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let world = World::start("bridge", &[], dir.path());
    let mut agent = Agent::start(&world, &station, "bridge", dir.path());
    wait_up(&station, &mut agent);
    send_goal(&station);
    // Garbage on every input topic while it drives, as a hostile or broken peer would send:
    // too short, a bad encapsulation header, random bytes after a valid header.
    let observer = Observer::connect(&world.endpoint);
    let garbage: [&[u8]; 3] = [
        b"",
        &[0, 9, 0, 0, 1, 2, 3],
        &[0, 1, 0, 0, 0xff, 0xff, 0xff, 0x7f, 1],
    ];
    let topics = [
        ("velodyne_points", "lidar"),
        ("odom", "odom"),
        ("imu/data", "imu"),
        ("fix", "gnss"),
        ("heading", "heading"),
    ];
    let mut sent = 0;
    let last = drive(&station, &mut agent, |_| {
        if sent < 5 {
            for (key, _) in topics {
                for g in garbage {
                    observer.put(key, g.to_vec());
                }
            }
            sent += 1;
        }
    });
    println!("station at the end: {}", last["status"]);
    judge(&world);
    let summary = agent.stop();
    println!("run summary: {summary}");
    for (_, topic) in topics {
        assert!(
            undecodable(&summary, topic) >= 3 * sent as u64,
            "{topic}: garbage not counted: {summary}"
        );
    }
    // The garbage reached the station's count of the robot's bad inputs, and nothing crashed.
    assert!(
        last["status"]["decode_errors"].as_u64().unwrap_or(0) > 0,
        "{}",
        last["status"]
    );
}

#[test]
fn rmw_keys_goal_is_reached_through_a_lidar_cut_that_stops_the_base() {
    // The world's clock starts with its process; the goal is sent at about 8-12 s, so at 25 s
    // the robot is driving.
    const CUT_FROM_S: f64 = 25.0;
    const CUT_FOR_S: f64 = 2.0;
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let cut = format!("lidar@{CUT_FROM_S}+{CUT_FOR_S}");
    let world = World::start("rmw", &["--silence", &cut], dir.path());
    let mut agent = Agent::start(&world, &station, "rmw", dir.path());
    wait_up(&station, &mut agent);
    send_goal(&station);
    let mut fault_seen = None;
    drive(&station, &mut agent, |r| {
        let reason = r["status"]["reason"].as_str().unwrap_or("");
        if fault_seen.is_none() && reason.contains("lidar silent") {
            fault_seen = Some(reason.to_string());
        }
    });
    judge(&world);
    let reason = fault_seen.expect("the station never showed the LiDAR fault");
    assert!(reason.contains("base stopped"), "{reason}");
    let truth = world.truth();
    let speed_at = |from: f64, to: f64| -> Vec<f64> {
        truth
            .iter()
            .filter(|v| (from..to).contains(&v["t_s"].as_f64().unwrap()))
            .map(|v| v["v_mps"].as_f64().unwrap())
            .collect()
    };
    let before = speed_at(CUT_FROM_S - 1.0, CUT_FROM_S);
    assert!(
        before.iter().any(|v| *v > 0.2),
        "not driving before the cut: {before:?}"
    );
    // lidar_timeout_s 0.5 + 0.1 for the command, then the plant's braking (1 m/s², 0.5 s from
    // 0.5 m/s) and a command period: standing still for the rest of the cut.
    let during = speed_at(CUT_FROM_S + 1.2, CUT_FROM_S + CUT_FOR_S);
    assert!(!during.is_empty(), "no truth lines during the cut");
    assert!(
        during.iter().all(|v| v.abs() < 0.05),
        "still moving during the cut: {during:?}"
    );
    println!("speed before the cut {before:?}, during {during:?}; status said {reason:?}");
    let summary = agent.stop();
    println!("run summary: {summary}");
}

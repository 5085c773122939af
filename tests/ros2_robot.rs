//! The real-robot path end to end, all real processes on loopback: the simulated world served
//! as ROS 2 topics (`robot-agent sim --serve-ros2`, the robot's "hardware"), the agent on it
//! (`robot-agent run`, exactly as on a real robot) and `operator-station serve`. A goal sent
//! through the station is judged against the simulator's truth (the world's stdout), in both
//! ROS 2 key forms; sensor faults and garbage on the input topics are injected on the way:
//! garbage on every input and a 60 s GNSS cut in the bridge form, a LiDAR cut, odometry and IMU
//! cuts and out-of-order odometry and IMU messages in the rmw form.

mod robot_support;
mod station_support;

use robot_support::*;
use serde_json::Value;
use station_support::*;
use std::time::{Duration, Instant};

/// The park world, its goal (28 m from the start at (-40, 0)) and how close the truth must end.
const PARK: &str = "config/scenarios/park.toml";
const GOAL: (f64, f64) = (-12.0, 0.0);
const GOAL_TOLERANCE_M: f64 = 0.5;
/// Real time allowed for the drive (about 60 s at the robot's 0.5 m/s).
const DRIVE: Duration = Duration::from_secs(240);

fn send_goal(station: &Station, goal: (f64, f64)) {
    let (st, body) = http(
        station.ports.http,
        "POST",
        "/api/robots/r1/goal",
        &format!(r#"{{"x": {}, "y": {}}}"#, goal.0, goal.1),
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
fn judge(world: &World, goal: (f64, f64)) -> Value {
    std::thread::sleep(Duration::from_millis(300));
    let truth = world.truth();
    let last = truth.last().expect("truth lines").clone();
    let (x, y) = (last["x_m"].as_f64().unwrap(), last["y_m"].as_f64().unwrap());
    let err = (x - goal.0).hypot(y - goal.1);
    println!("truth at the end ({x:.2}, {y:.2}): {err:.2} m from the goal; {last}");
    assert!(
        err <= GOAL_TOLERANCE_M,
        "truth ({x:.2}, {y:.2}) is {err:.2} m from the goal"
    );
    assert_eq!(last["collisions"], 0, "{last}");
    assert!(last["cmd_vel_received"].as_u64().unwrap() > 100, "{last}");
    last
}

/// The truth position at Unix time `unix_s`, interpolated between truth lines.
fn truth_at(truth: &[Value], unix_s: f64) -> Option<(f64, f64)> {
    let at = |v: &Value| {
        (
            v["unix_s"].as_f64().unwrap(),
            v["x_m"].as_f64().unwrap(),
            v["y_m"].as_f64().unwrap(),
        )
    };
    let k = truth.partition_point(|v| v["unix_s"].as_f64().unwrap() < unix_s);
    if k == 0 || k >= truth.len() {
        return None;
    }
    let ((t0, x0, y0), (t1, x1, y1)) = (at(&truth[k - 1]), at(&truth[k]));
    let f = if t1 > t0 {
        (unix_s - t0) / (t1 - t0)
    } else {
        0.0
    };
    Some((x0 + f * (x1 - x0), y0 + f * (y1 - y0)))
}

/// A pose the station showed: (Unix time s, x, y).
type ShownPose = (f64, f64, f64);

fn shown_pose(entry: &Value) -> Option<ShownPose> {
    let p = &entry["pose"];
    Some((
        p["t_unix_ms"].as_f64()? / 1000.0,
        p["x_m"].as_f64()?,
        p["y_m"].as_f64()?,
    ))
}

/// A shown pose against the truth: at the pose's time, and the nearest truth within 0.3 s of
/// it (the pose is published from the newest odometry, which the loop clock leads by the
/// transport latency: at 0.5 m/s, 0.1 s is 5 cm that are latency, not localisation).
fn pose_errors(truth: &[Value], (t, x, y): ShownPose) -> Option<(f64, f64)> {
    let (tx, ty) = truth_at(truth, t)?;
    let near = (0..=12)
        .filter_map(|k| truth_at(truth, t - 0.3 + 0.05 * f64::from(k)))
        .map(|(a, b)| (x - a).hypot(y - b))
        .fold(f64::INFINITY, f64::min);
    Some(((x - tx).hypot(y - ty), near))
}

/// A GNSS cut long enough to matter: from the start of the drive, for 60 s. The goal is sent at
/// about 5-12 s of world time and, 35 m away, reached at about 80-90 s, so the mission runs on
/// SLAM alone for most of its length and then with GNSS again.
const GNSS_CUT_FROM_S: f64 = 10.0;
const GNSS_CUT_FOR_S: f64 = 60.0;
const GNSS_GOAL: (f64, f64) = (-5.0, 0.0);
/// How far the pose may stray from the truth while GNSS is out, metres.
const GNSS_CUT_MAX_ERROR_M: f64 = 0.5;

#[test]
fn bridge_keys_goal_is_reached_through_a_60_s_gnss_cut_and_garbage_is_counted() {
    let _machine = one_world_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let cut = format!("gnss@{GNSS_CUT_FROM_S}+{GNSS_CUT_FOR_S}");
    let world = World::start(PARK, "bridge", &["--silence", &cut], dir.path());
    let mut agent = Agent::start(&world, &station, "bridge", &[], dir.path());
    wait_up(&station, &mut agent);
    send_goal(&station, GNSS_GOAL);
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
    let cut_end = GNSS_CUT_FROM_S + GNSS_CUT_FOR_S;
    // What the station showed while GNSS was out, and the poses it showed.
    let (mut lost_seen, mut fault_seen, mut moving_while_lost) = (false, None, 0.0f64);
    let mut poses: Vec<ShownPose> = Vec::new();
    let last = drive(&station, &mut agent, |r| {
        if sent < 5 {
            for (key, _) in topics {
                for g in garbage {
                    observer.put(key, g.to_vec());
                }
            }
            sent += 1;
        }
        let st = &r["status"];
        let now = world.now_s();
        if now > GNSS_CUT_FROM_S + 4.0 && now < cut_end {
            if st["gnss_lost"] == true {
                lost_seen = true;
                moving_while_lost =
                    moving_while_lost.max(r["pose"]["v_mps"].as_f64().unwrap_or(0.0));
            }
            let reason = st["reason"].as_str().unwrap_or("");
            if fault_seen.is_none() && reason.contains("gnss silent") {
                fault_seen = Some(reason.to_string());
            }
        }
        poses.extend(shown_pose(r));
    });
    println!("station at the end: {}", last["status"]);
    let truth_end = judge(&world, GNSS_GOAL);
    assert!(
        truth_end["t_s"].as_f64().unwrap() > GNSS_CUT_FROM_S + GNSS_CUT_FOR_S,
        "the goal was reached before GNSS came back: {truth_end}"
    );
    assert!(lost_seen, "the status never said GNSS was lost");
    assert!(
        moving_while_lost > 0.2,
        "the robot did not drive on SLAM while GNSS was lost ({moving_while_lost} m/s)"
    );
    let fault = fault_seen.expect("the status never named the GNSS fault");
    // How far the pose strayed from the truth while GNSS was out, and how far it had driven.
    let truth = world.truth();
    let epoch = world.epoch_unix_s();
    let in_cut: Vec<(f64, f64, f64)> = poses
        .iter()
        .filter(|p| (GNSS_CUT_FROM_S..cut_end).contains(&(p.0 - epoch)))
        .filter_map(|p| pose_errors(&truth, *p).map(|(at, near)| (p.0 - epoch, at, near)))
        .collect();
    assert!(
        in_cut.len() > 100,
        "only {} poses compared during the cut",
        in_cut.len()
    );
    let max_at = in_cut.iter().map(|e| e.1).fold(0.0, f64::max);
    let (worst_t, _, max_near) =
        in_cut
            .iter()
            .cloned()
            .fold((0.0, 0.0, 0.0), |w, e| if e.2 > w.2 { e } else { w });
    let at_end = in_cut.last().unwrap();
    let along: f64 = truth
        .windows(2)
        .filter(|w| (GNSS_CUT_FROM_S..cut_end).contains(&w[0]["t_s"].as_f64().unwrap()))
        .map(|w| {
            let (a, b) = (&w[0], &w[1]);
            (b["x_m"].as_f64().unwrap() - a["x_m"].as_f64().unwrap())
                .hypot(b["y_m"].as_f64().unwrap() - a["y_m"].as_f64().unwrap())
        })
        .sum();
    println!(
        "GNSS cut {GNSS_CUT_FROM_S}-{cut_end} s, {along:.1} m driven on SLAM: status {fault:?}; \
         pose vs truth at most {max_near:.3} m (at {worst_t:.1} s; {max_at:.3} m with the \
         pose's latency), {:.3} m at the cut's end ({} poses)",
        at_end.2,
        in_cut.len()
    );
    assert!(along > 20.0, "only {along:.1} m driven during the cut");
    assert!(
        max_near <= GNSS_CUT_MAX_ERROR_M,
        "pose {max_near:.2} m from the truth at {worst_t:.1} s without GNSS"
    );
    // GNSS comes back: the status says so, and the pose is held to it again.
    let ok = wait_for(Duration::from_secs(40), || {
        world.now_s() > cut_end + 5.0
            && robot_entry(station.ports.http, "r1").is_some_and(|r| {
                r["status"]["gnss_lost"] == false && r["status"]["fix"] == "RtkFixed"
            })
    });
    assert!(
        ok,
        "GNSS never came back: {:?}",
        robot_entry(station.ports.http, "r1")
    );
    let back = robot_entry(station.ports.http, "r1").unwrap();
    std::thread::sleep(Duration::from_millis(400));
    let err_back = shown_pose(&back).and_then(|p| pose_errors(&world.truth(), p));
    println!("GNSS back: pose vs truth {err_back:?} m");
    let summary = agent.stop();
    println!("run summary: {summary}");
    for (_, topic) in topics {
        assert!(
            per_topic(&summary, "undecodable", topic) >= 3 * sent as u64,
            "{topic}: garbage not counted: {summary}"
        );
    }
    let gnss = fault_episodes(&summary, "gnss").expect("the GNSS fault in the summary");
    assert!(
        gnss["longest_silent_s"].as_f64().unwrap() > GNSS_CUT_FOR_S - 5.0,
        "{gnss}"
    );
    // The garbage reached the station's count of the robot's bad inputs, and nothing crashed.
    assert!(
        last["status"]["decode_errors"].as_u64().unwrap_or(0) > 0,
        "{}",
        last["status"]
    );
}

/// Puts `n` messages of `topic` (rmw key form) whose stamps are `offset_s` off the world's
/// clock now: out of order (negative) or from the future.
fn put_stamped(world: &World, observer: &Observer, topic: &str, offset_s: f64, n: usize) {
    use io::ros2::keys::{Ros2Graph, IMU, ODOMETRY};
    use io::sample::{Imu, Odometry};
    let graph = Ros2Graph {
        form: io::ros2::keys::KeyForm::Rmw,
        domain_id: 0,
        namespace: String::new(),
    };
    for _ in 0..n {
        let stamp_s = world.epoch_unix_s() + world.now_s() + offset_s;
        let (key, payload) = match topic {
            "imu" => (
                graph.publish_key("imu/data", &IMU),
                io::cdr::encode_imu(&Imu {
                    stamp_s,
                    frame_id: "base_link".into(),
                    linear_acceleration_mps2: [0.0, 0.0, 9.81],
                    ..Imu::default()
                }),
            ),
            _ => (
                graph.publish_key("odom", &ODOMETRY),
                io::cdr::encode_odometry(&Odometry {
                    stamp_s,
                    frame_id: "odom".into(),
                    child_frame_id: "base_link".into(),
                    orientation: [0.0, 0.0, 0.0, 1.0],
                    ..Odometry::default()
                }),
            ),
        };
        observer.put(&key, payload);
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn rmw_keys_goal_is_reached_through_lidar_odometry_and_imu_faults() {
    // The world's clock starts with its process; the goal is sent at about 8-12 s, so from
    // 25 s on the robot is driving.
    const CUT_FROM_S: f64 = 25.0;
    const CUT_FOR_S: f64 = 2.0;
    const ODOM_CUT_FROM_S: f64 = 33.0;
    const IMU_CUT_FROM_S: f64 = 40.0;
    let _machine = one_world_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let cuts = [
        format!("lidar@{CUT_FROM_S}+{CUT_FOR_S}"),
        format!("odom@{ODOM_CUT_FROM_S}+2"),
        format!("imu@{IMU_CUT_FROM_S}+2"),
    ];
    let world = World::start(
        PARK,
        "rmw",
        &[
            "--silence",
            &cuts[0],
            "--silence",
            &cuts[1],
            "--silence",
            &cuts[2],
            "--depth",
        ],
        dir.path(),
    );
    // With the depth camera too: its frames are stamped at capture, a LiDAR sweep at its
    // revolution's start, so sweeps arrive older than the last frame mapped.
    let mut agent = Agent::start(
        &world,
        &station,
        "rmw",
        &["--depth", "ros2:depth/points"],
        dir.path(),
    );
    wait_up(&station, &mut agent);
    send_goal(&station, GOAL);
    let observer = Observer::connect(&world.endpoint);
    let mut seen: Vec<(&str, String)> = Vec::new();
    let mut injected = false;
    let started = Instant::now();
    drive(&station, &mut agent, |r| {
        let reason = r["status"]["reason"].as_str().unwrap_or("");
        for what in ["lidar silent", "odom silent", "imu silent"] {
            if reason.contains(what) && !seen.iter().any(|(w, _)| *w == what) {
                seen.push((what, reason.to_string()));
            }
        }
        // Odometry and IMU messages out of order (1 s old) and from the future (30 s ahead),
        // as a driver that restarts or a replayed buffer sends them, once while driving.
        if !injected && world.now_s() > 50.0 && started.elapsed() > Duration::from_secs(5) {
            for topic in ["odom", "imu"] {
                put_stamped(&world, &observer, topic, -1.0, 5);
                put_stamped(&world, &observer, topic, 30.0, 5);
            }
            injected = true;
        }
    });
    judge(&world, GOAL);
    let reason_of = |what: &str| {
        seen.iter()
            .find(|(w, _)| *w == what)
            .map(|(_, r)| r.clone())
            .unwrap_or_else(|| panic!("the station never showed {what:?}: {seen:?}"))
    };
    let lidar = reason_of("lidar silent");
    assert!(lidar.contains("base stopped"), "{lidar}");
    reason_of("odom silent");
    reason_of("imu silent");
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
    // Odometry and IMU faults are reported, not acted on: the robot drives on through them on
    // SLAM (no stop longer than a plan's).
    for from in [ODOM_CUT_FROM_S, IMU_CUT_FROM_S] {
        let v = speed_at(from + 0.6, from + 2.0);
        assert!(
            v.iter().any(|v| *v > 0.2),
            "stopped during the {from} s cut: {v:?}"
        );
    }
    println!("speed before the LiDAR cut {before:?}, during {during:?}; status said {seen:?}");
    let summary = agent.stop();
    println!("run summary: {summary}");
    assert!(
        injected,
        "the drive ended before the out-of-order messages were sent"
    );
    for topic in ["odom", "imu"] {
        let backwards = stamp_refused(&summary, topic, "backwards");
        let jumped = stamp_refused(&summary, topic, "jumped");
        assert!(
            backwards >= 5 && jumped >= 5,
            "{topic}: out-of-order stamps not refused ({backwards} backwards, {jumped} jumped): {summary}"
        );
        let f =
            fault_episodes(&summary, topic).unwrap_or_else(|| panic!("{topic} fault: {summary}"));
        assert!(
            f["episodes"].as_u64().unwrap() >= 1 && f["stopped_base"] == false,
            "{f}"
        );
    }
    let lidar = fault_episodes(&summary, "lidar").expect("lidar fault in the summary");
    assert!(lidar["stopped_base"] == true, "{lidar}");
    // Both sensors mapped: the depth frames, and the sweeps between them. (This world's frames
    // fall on sweep boundaries, so it does not reproduce a sweep arriving older than the last
    // frame; the mapper's unit test does.)
    let scans = summary["scans"].as_u64().unwrap_or(0);
    let mapped = summary["map"]["scans_mapped"].as_u64().unwrap_or(0);
    let frames = summary["depth_frames"].as_u64().unwrap_or(0);
    assert!(frames > 100, "depth frames mapped: {frames}: {summary}");
    assert!(
        scans > 100 && mapped * 10 >= scans * 9,
        "{mapped} of {scans} sweeps mapped beside the depth camera: {summary}"
    );
}

//! A robot driven through its own navigation computer (methods.md §7), all real processes on
//! loopback: the simulated world as ROS 2 hardware that also plays the robot's waypoint-following
//! computer (`robot-agent sim --serve-ros2 --nav-computer-listen udp:PORT`), `robot-agent run
//! --nav-computer orpheus-udp:...` and `operator-station serve`. The operator teaches a route by
//! driving through the station (`cmd_vel`), a box appears on it, and the return (repeat in
//! reverse) goes out to the navigation computer as a `$NALST` list with the detour around the
//! box as `$CAREM`/`$CAINS` edits; judged against the world's truth.

mod robot_support;
mod station_support;

use robot_support::*;
use serde_json::Value;
use station_support::*;
use std::time::{Duration, Instant};

const FIELD: &str = "config/scenarios/station-field.toml";
/// The teach drive from (0, 0) heading east: (seconds, v m/s, omega rad/s) legs: 6 m straight,
/// then a right-hand arc of 5 m radius through 1 rad. The route ends near (10.2, -2.3).
const TEACH: [(f64, f64, f64); 2] = [(12.0, 0.5, 0.0), (10.0, 0.5, -0.1)];
/// A box on the straight leg, appearing once the teach drive has passed it.
const BOX: (f64, f64) = (3.5, 0.0);
const BOX_AT_S: f64 = 45.0;
/// Limits of the return, judged on the truth.
const END_TOLERANCE_M: f64 = 0.5;
const FREE_MAX_M: f64 = 0.35;
const FREE_RMS_M: f64 = 0.15;

fn post(station: &Station, path: &str, body: &str) {
    let (st, b) = http(station.ports.http, "POST", path, body).expect("station answers");
    assert_eq!(st, 202, "POST {path} {body}: {b}");
}

fn xy(v: &Value) -> (f64, f64) {
    (v["x_m"].as_f64().unwrap(), v["y_m"].as_f64().unwrap())
}

/// Distance from `p` to the polyline `line`.
fn to_line(p: (f64, f64), line: &[(f64, f64)]) -> f64 {
    line.windows(2)
        .map(|w| common::zone::segment_distance_m(w[0], w[1], p))
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn teach_and_repeat_return_through_a_navigation_computer_detours_a_new_box() {
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let nc_port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .unwrap()
        .port();
    let obstacle = dir.path().join("box.toml");
    std::fs::write(
        &obstacle,
        format!(
            "[[box]]\nrect = {{ center_m = [{}, {}], size_m = [1.0, 1.0] }}\nheight_m = 0.6\n",
            BOX.0, BOX.1
        ),
    )
    .unwrap();
    let box_at = format!("{}@{BOX_AT_S}", obstacle.display());
    let world = World::start(
        FIELD,
        "bridge",
        &[
            "--nav-computer-listen",
            &format!("udp:{nc_port}"),
            "--obstacles-at",
            &box_at,
        ],
        dir.path(),
    );
    let mut agent = Agent::start(
        &world,
        &station,
        "bridge",
        &[
            "--nav-computer",
            &format!("orpheus-udp:127.0.0.1:{nc_port}"),
        ],
        dir.path(),
    );
    wait_up(&station, &mut agent);

    // Teach: the operator drives through the station (the UI's 10 Hz drive commands).
    post(
        &station,
        "/api/robots/r1/route",
        r#"{"action": "record", "name": "nc-return"}"#,
    );
    let teach_from_s = world.now_s();
    for (secs, v, w) in TEACH {
        let t0 = Instant::now();
        while t0.elapsed().as_secs_f64() < secs {
            agent.assert_running();
            post(
                &station,
                "/api/robots/r1/drive",
                &format!(r#"{{"v_mps": {v}, "omega_rps": {w}, "deadman": true}}"#),
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    post(&station, "/api/robots/r1/stop", "{}");
    std::thread::sleep(Duration::from_millis(1500));
    post(
        &station,
        "/api/robots/r1/route",
        r#"{"action": "stop_recording"}"#,
    );
    let teach_to_s = world.now_s();
    let mut route_id = None;
    assert!(
        wait_for(Duration::from_secs(20), || {
            let Some((200, body)) = http(station.ports.http, "GET", "/api/routes", "") else {
                return false;
            };
            let routes: Value = serde_json::from_str(&body).unwrap();
            route_id = routes
                .as_array()
                .and_then(|a| a.iter().find(|r| r["robot"] == "r1"))
                .map(|r| r["route_id"].as_str().unwrap().to_owned());
            route_id.is_some()
        }),
        "the taught route never reached the station\n{}",
        tail(&agent.log, 20)
    );
    let taught: Vec<(f64, f64)> = world
        .truth()
        .iter()
        .filter(|v| (teach_from_s..=teach_to_s).contains(&v["t_s"].as_f64().unwrap()))
        .map(xy)
        .collect();
    let start = taught[0];
    let teach_end = *taught.last().unwrap();
    println!(
        "taught {} truth points from {start:?} to {teach_end:?}",
        taught.len()
    );
    assert!(
        teach_end.0 > 8.0,
        "the teach drive fell short: {teach_end:?}"
    );

    // The box appears behind the robot; then the return.
    assert!(
        wait_for(Duration::from_secs(60), || world.now_s() > BOX_AT_S + 0.5),
        "the world's clock stalled"
    );
    let appeared = world
        .lines()
        .iter()
        .find(|v| v.get("obstacles_added").is_some())
        .cloned()
        .expect("the box never appeared");
    let at_box = world
        .truth()
        .iter()
        .find(|v| v["t_s"].as_f64().unwrap() >= BOX_AT_S)
        .map(xy)
        .unwrap();
    assert!(
        at_box.0 > BOX.0 + 2.0,
        "the robot was still near the box when it appeared ({at_box:?}): teaching started late"
    );
    println!("box appeared: {appeared}");
    post(
        &station,
        "/api/robots/r1/route",
        &format!(
            r#"{{"action": "repeat", "route_id": "{}", "direction": "reverse"}}"#,
            route_id.unwrap()
        ),
    );
    let repeat_from_s = world.now_s();
    let mut repeating = false;
    let mut last = Value::Null;
    let done = wait_for(Duration::from_secs(150), || {
        agent.assert_running();
        let Some(r) = robot_entry(station.ports.http, "r1") else {
            return false;
        };
        let st = r["status"].clone();
        repeating |= st["mode"] == "Repeat";
        last = st.clone();
        repeating && st["mode"] == "Idle" && st["reason"] == "route finished"
    });
    assert!(
        done,
        "the return did not finish: {last}\n{}",
        tail(&agent.log, 30)
    );
    std::thread::sleep(Duration::from_millis(500));

    // Judged on the truth: home near the start, on the taught line away from the box, around
    // the box without touching it.
    let truth = world.truth();
    let ret: Vec<(f64, f64)> = truth
        .iter()
        .filter(|v| v["t_s"].as_f64().unwrap() >= repeat_from_s)
        .map(xy)
        .collect();
    let end = *ret.last().unwrap();
    let end_err = (end.0 - start.0).hypot(end.1 - start.1);
    let near_box = |p: &(f64, f64)| (p.0 - BOX.0).hypot(p.1 - BOX.1) < 3.0;
    let free: Vec<f64> = ret
        .iter()
        .filter(|p| !near_box(p))
        .map(|p| to_line(*p, &taught))
        .collect();
    let free_max = free.iter().cloned().fold(0.0, f64::max);
    let free_rms = (free.iter().map(|d| d * d).sum::<f64>() / free.len() as f64).sqrt();
    let detour_off = ret
        .iter()
        .filter(|p| near_box(p))
        .map(|p| to_line(*p, &taught))
        .fold(0.0, f64::max);
    let box_clearance = ret
        .iter()
        .map(|p| (p.0 - BOX.0).abs().max((p.1 - BOX.1).abs()) - 0.5)
        .fold(f64::INFINITY, f64::min);
    // Seconds the navigation computer was held (speed 0) with waypoints ahead: the wait for the
    // box to prove it stays put, and the agent's safety stop if it fired.
    let held_s = truth
        .iter()
        .filter(|v| v["t_s"].as_f64().unwrap() >= repeat_from_s + 1.0)
        .filter(|v| {
            let nc = &v["nc"];
            nc["speed_pct"] == 0
                && nc["target"].as_u64() < nc["waypoints"].as_u64().map(|n| n.saturating_sub(1))
        })
        .count() as f64
        * 0.1;
    let last_truth = truth.last().unwrap();
    let nc = &last_truth["nc"];
    println!(
        "return: ends {end_err:.3} m from the start; free stretches {} points, max {free_max:.3} m, \
         RMS {free_rms:.3} m off the taught line; detour {detour_off:.2} m off the line, \
         {box_clearance:.2} m from the box; held {held_s:.1} s; NC {nc}",
        free.len()
    );
    assert_eq!(last_truth["collisions"], 0, "{last_truth}");
    assert!(
        end_err <= END_TOLERANCE_M,
        "ends {end_err:.2} m from the start"
    );
    assert!(
        free_max <= FREE_MAX_M && free_rms <= FREE_RMS_M,
        "off the taught line: max {free_max:.3} m, RMS {free_rms:.3} m"
    );
    assert!(
        detour_off > 0.8,
        "no detour round the box ({detour_off:.2} m off the line)"
    );
    // The navigation computer got the list, the detour as edits, and reported waypoints.
    let counts = &nc["counts"];
    assert!(counts["lists"].as_u64().unwrap() >= 1, "{nc}");
    assert!(
        counts["removed"].as_u64().unwrap() >= 1 && counts["inserted"].as_u64().unwrap() >= 1,
        "no $CAREM/$CAINS edit reached the navigation computer: {nc}"
    );
    assert!(counts["reached"].as_u64().unwrap() >= 5, "{nc}");
    assert_eq!(counts["refused"], 0, "{nc}");
    let summary = agent.stop();
    println!("run summary: {summary}");
    let base = &summary["base"];
    assert!(base["sent"]["edits"].as_u64().unwrap() >= 1, "{base}");
    assert!(base["waypoints_reached"].as_u64().unwrap() >= 5, "{base}");
    assert_eq!(base["lines_refused"], 0, "{base}");
}

//! One goal contract at every door (issue 23): a GNSS goal with latitude and longitude swapped
//! (4 000 km from the robot) and one at (0, 0) are refused with their stable codes by the
//! station's HTTP API, by `operator-station goal`, and by the robot itself when a peer puts the
//! goal straight on its key. Real processes on loopback: `operator-station serve` and a simulated
//! robot in the `station-field` world (datum 47.3769 N, 8.5417 E). `operator-station goal` and
//! `stop` then report what the robot's status showed: a goal the robot refused (in a keep-out
//! zone the CLI does not check) fails with the robot's reason, a goal it took and a stop are
//! confirmed.

mod station_support;

use common::keys::{self, RobotId, Topic};
use common::msg::{self, GoalCmd, GoalTarget};
use serde_json::Value;
use station_support::*;
use std::process::{Command, Stdio};
use std::time::Duration;
use support::bin;

/// Near the robot, as the operator meant it.
const LAT: f64 = 47.3770;
const LON: f64 = 8.5418;

fn post_goal(station: &Station, body: &str) -> (u16, Value) {
    let (st, b) = http(station.ports.http, "POST", "/api/robots/r1/goal", body).expect("answer");
    (st, serde_json::from_str(&b).unwrap_or(Value::Null))
}

/// `operator-station ARGS --robot r1 --connect ENDPOINT`: exit status, stdout and stderr.
fn cli(station: &Station, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(bin("operator-station"))
        .args(args)
        .args(["--robot", "r1", "--connect"])
        .arg(station.ports.endpoint())
        .stdin(Stdio::null())
        .output()
        .expect("run operator-station");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

/// `operator-station goal --gnss LAT,LON`: exit status and stderr.
fn cli_goal(station: &Station, gnss: &str) -> (bool, String) {
    let (ok, _, err) = cli(station, &["goal", "--gnss", gnss]);
    (ok, err)
}

fn refused(robot: &Value) -> u64 {
    robot["status"]["commands_refused"].as_u64().unwrap_or(0)
}

#[test]
fn swapped_and_null_island_goals_are_refused_at_the_api_the_cli_and_the_robot_and_the_cli_confirms_what_the_robot_took(
) {
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let _robot = Robot::start(
        "r1",
        &field_scenario(),
        &station.ports.endpoint(),
        "0,0,0",
        1,
        dir.path(),
    );
    assert!(
        wait_for(Duration::from_secs(60), || {
            robot_entry(station.ports.http, "r1")
                .is_some_and(|r| r["online"] == true && !r["pose"]["lat_lon_deg"].is_null())
        }),
        "robot never reported an anchored pose"
    );

    // The HTTP API: 422 with the code, nothing sent.
    let (st, b) = post_goal(&station, &format!(r#"{{"lat": {LON}, "lon": {LAT}}}"#));
    assert_eq!(st, 422, "{b}");
    assert_eq!(b["code"], "goal_too_far", "{b}");
    let e = b["error"].as_str().unwrap_or("");
    assert!(
        e.contains("look swapped"),
        "the message names the likely cause: {e}"
    );
    let (st, b) = post_goal(&station, r#"{"lat": 0, "lon": 0}"#);
    assert_eq!((st, b["code"].as_str()), (422, Some("null_island")), "{b}");
    // A goal the operator meant is still accepted (the check is not a blanket refusal).
    let (st, b) = post_goal(&station, &format!(r#"{{"lat": {LAT}, "lon": {LON}}}"#));
    assert_eq!(st, 202, "{b}");

    // The station CLI, talking to the robot directly: refused before anything is sent.
    let (ok, err) = cli_goal(&station, &format!("{LON},{LAT}"));
    assert!(!ok && err.contains("[goal_too_far]"), "{err}");
    let (ok, err) = cli_goal(&station, "0,0");
    assert!(!ok && err.contains("[null_island]"), "{err}");
    let before = refused(&robot_entry(station.ports.http, "r1").unwrap());
    assert_eq!(before, 0, "nothing refused reached the robot yet");

    // The robot: a peer that skips every check puts the swapped goal on the robot's key.
    let observer = Observer::connect(&station.ports.endpoint());
    let rid = RobotId::new("r1").unwrap();
    let stamper = common::command::CommandStamper::new(0x901);
    for (goal_id, lat, lon) in [(901, LON, LAT), (902, 0.0, 0.0)] {
        let cmd = GoalCmd {
            goal_id,
            target: GoalTarget::Gnss {
                lat_deg: lat,
                lon_deg: lon,
                h_m: None,
            },
            tolerance_m: 0.0,
        };
        let now_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_millis() as u64;
        observer.put(
            &keys::key(&rid, Topic::CmdGoal),
            msg::encode_cmd(stamper.next(now_ms), &cmd),
        );
    }
    let mut last = Value::Null;
    let counted = wait_for(Duration::from_secs(10), || {
        last = robot_entry(station.ports.http, "r1").unwrap_or_default();
        refused(&last) >= 2
    });
    assert!(
        counted,
        "the robot did not count both refusals: {}",
        last["status"]
    );
    let err = last["status"]["last_error"].as_str().unwrap_or("");
    assert!(err.contains("null_island"), "{err}");

    // A keep-out zone drawn at the station: the CLI does not check zones, the robot does, and
    // the CLI says so from the robot's status instead of reporting the goal as sent.
    let datum = last["datum_id"].as_str().expect("datum id").to_string();
    let fc = r#"{"type":"FeatureCollection","features":[{"type":"Feature","properties":{"kind":"keep_out","name":"pond"},"geometry":{"type":"Polygon","coordinates":[[[10,10],[14,10],[14,14],[10,14],[10,10]]]}}]}"#;
    let (st, b) = http(
        station.ports.http,
        "POST",
        &format!("/api/zones?frame=map&datum_id={datum}"),
        fc,
    )
    .expect("answer");
    assert_eq!(st, 201, "{b}");
    assert!(
        wait_for(Duration::from_secs(20), || {
            robot_entry(station.ports.http, "r1")
                .is_some_and(|r| r["status"]["zones_version"].as_u64() > Some(0))
        }),
        "the zone never reached the robot"
    );
    let (ok, out, err) = cli(&station, &["goal", "--xy", "12,12"]);
    assert!(!ok, "a goal in a keep-out zone reported as taken: {out}");
    assert!(
        err.contains("refused by robot r1") && err.contains("keep-out"),
        "the CLI gives the robot's reason: {err}"
    );

    // A goal the robot takes: confirmed from its status, which shows the goal's id.
    let (ok, out, err) = cli(&station, &["goal", "--xy", "6,0"]);
    assert!(ok, "{err}");
    let sent: Value = serde_json::from_str(out.trim()).expect("one JSON line");
    assert_eq!(sent["confirmed"], true, "{sent}");
    assert!(sent["attempts"].as_u64() >= Some(1), "{sent}");
    let goal_id = sent["sent"]["goal_id"].as_u64().expect("goal id");
    assert!(
        wait_for(Duration::from_secs(10), || {
            robot_entry(station.ports.http, "r1")
                .is_some_and(|r| r["status"]["goal_id"].as_u64() == Some(goal_id))
        }),
        "the station never saw goal {goal_id}"
    );
    println!(
        "goal {goal_id} confirmed after {} send(s): {} / {}",
        sent["attempts"], sent["mission"], sent["reason"]
    );

    // The stop: confirmed once the robot shows itself halted.
    let (ok, out, err) = cli(&station, &["stop"]);
    assert!(ok, "{err}");
    let sent: Value = serde_json::from_str(out.trim()).expect("one JSON line");
    assert_eq!(sent["confirmed"], true, "{sent}");
    assert!(
        sent["mission"] != "Driving" && sent["mission"] != "Planning",
        "{sent}"
    );
    assert!(
        wait_for(Duration::from_secs(10), || {
            robot_entry(station.ports.http, "r1")
                .is_some_and(|r| r["status"]["mission"] == "Stopped")
        }),
        "the station never saw the robot stopped"
    );
}

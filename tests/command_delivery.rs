//! The station sends an operator's goal again until the robot's status shows it. A real
//! `operator-station serve` and a robot played by a Zenoh session on loopback: the robot is
//! online and publishes its status, but declares its goal subscriber only after the operator's
//! goal was put (a robot that came up or reconnected a moment before), so the first put reaches
//! nobody. The station must send it again, and stop once the status shows the goal.

mod station_support;

use std::time::{Duration, Instant};

use common::keys::{self, RobotId, Topic};
use common::msg::{self, GoalCmd, Status};
use station_support::*;

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

#[test]
fn a_goal_the_robot_did_not_receive_is_sent_again_until_its_status_shows_it() {
    let dir = tempfile::tempdir().unwrap();
    let station = Station::start(Ports::new(), &dir.path().join("s.db"));
    let mut robot = Observer::connect(&station.ports.endpoint());
    robot.declare_alive("late");
    let rid = RobotId::new("late").unwrap();
    robot.put(
        &keys::key(&rid, Topic::Session),
        msg::encode(&session("late", now_ms())),
    );
    let status_key = keys::key(&rid, Topic::Status);
    let show = |robot: &Observer, goal_id: u32| {
        let s = Status {
            t_unix_ms: now_ms(),
            goal_id,
            ..Status::default()
        };
        robot.put(&status_key, msg::encode(&s));
    };
    let online = wait_for(Duration::from_secs(20), || {
        show(&robot, 7);
        std::thread::sleep(Duration::from_millis(200));
        robot_entry(station.ports.http, "late")
            .is_some_and(|r| r["online"] == true && r["status"]["goal_id"] == 7)
    });
    assert!(
        online,
        "the station never saw the robot online with its status"
    );

    // The operator's goal: the robot has no goal subscriber yet, so this put reaches nobody.
    let (st, body) = http(
        station.ports.http,
        "POST",
        "/api/robots/late/goal",
        r#"{"x": 3, "y": 4}"#,
    )
    .expect("answer");
    assert_eq!(st, 202, "{body}");
    let sent: serde_json::Value = serde_json::from_str(&body).unwrap();
    let goal_id = sent["sent"]["goal_id"].as_u64().expect("goal id") as u32;
    let t_post = Instant::now();

    // Now it listens, still showing its old goal.
    let heard = robot.record(&keys::key(&rid, Topic::CmdGoal));
    let arrived = wait_for(Duration::from_secs(10), || {
        show(&robot, 7);
        std::thread::sleep(Duration::from_millis(250));
        !heard.lock().unwrap().is_empty()
    });
    assert!(
        arrived,
        "the goal was never sent again\n{}",
        station.log_text()
    );
    let again = t_post.elapsed();
    let (_, goal): (_, GoalCmd) =
        msg::decode_cmd(&heard.lock().unwrap()[0].payload).expect("a goal in its envelope");
    assert_eq!(goal.goal_id, goal_id, "the same goal");
    println!(
        "goal {goal_id} sent again {:.1} s after the operator's put",
        again.as_secs_f64()
    );

    // The status shows it: the station stops sending (it would send a third time 2 s later).
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(5) {
        show(&robot, goal_id);
        std::thread::sleep(Duration::from_millis(250));
    }
    assert_eq!(
        heard.lock().unwrap().len(),
        1,
        "sent again after the status showed it"
    );
    assert!(
        station
            .log_text()
            .contains("goal to late sent again: no status has shown it yet"),
        "{}",
        station.log_text()
    );
}

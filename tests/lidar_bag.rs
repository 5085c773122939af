//! The real VLP-16 ROS 2 bag (`../shared/data/lidar/vlp16/`: `velodyne_msgs/msg/VelodyneScan` on
//! `/velodyne_packets`) played over Zenoh in the bridge key form (`robot-agent lidar play`, as the
//! robot's driver would publish it) into `robot-agent run --lidar ros2:velodyne_packets
//! --lidar-msg VelodyneScan`: the packets are cut into sweeps that reach SLAM and the mapper.
//! Needs `../shared/data` (skipped with a notice without it; a failure under CI=true).

use serde_json::Value;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use support::{bin, free_port, workspace_root, KillOnDrop};

fn last_json(out: &str) -> Value {
    serde_json::from_str(out.lines().last().unwrap_or(""))
        .unwrap_or_else(|e| panic!("summary line of {out:?}: {e}"))
}

fn log_tail(path: &std::path::Path) -> String {
    let s = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = s.lines().collect();
    lines[lines.len().saturating_sub(30)..].join("\n")
}

#[test]
fn the_real_vlp16_bag_reaches_the_mapper_through_run() {
    let Some(data) = support::shared_data("the VLP-16 bag test") else {
        return;
    };
    let bag = data.join("lidar/vlp16");
    let dir = tempfile::tempdir().unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let (play_log, run_log) = (dir.path().join("play.log"), dir.path().join("run.log"));
    // The player listens, as zenoh-bridge-ros2dds does on a robot, and waits for a subscriber.
    let mut player = KillOnDrop::spawn(
        Command::new(bin("robot-agent"))
            .current_dir(workspace_root())
            .args(["lidar", "play"])
            .arg(&bag)
            .args([
                "--ros2-keys",
                "bridge",
                "--listen",
                &endpoint,
                "--wait-subscriber-s",
                "60",
            ])
            .env("RUST_LOG", "info,zenoh=warn")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&play_log).unwrap()),
    )
    .unwrap();
    let mut run = KillOnDrop::spawn(
        Command::new(bin("robot-agent"))
            .current_dir(workspace_root())
            .args([
                "run",
                "--robot",
                "bag-1",
                "--connect",
                &format!("tcp/127.0.0.1:{}", free_port()),
                "--ros2-connect",
                &endpoint,
                "--ros2-keys",
                "bridge",
                "--lidar",
                "ros2:velodyne_packets",
                "--lidar-msg",
                "VelodyneScan",
                "--odom",
                "",
                "--imu",
                "",
                "--gnss",
                "",
                "--cmd-vel",
                "",
            ])
            .env("RUST_LOG", "info,zenoh=warn")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&run_log).unwrap()),
    )
    .unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = player.0.try_wait().unwrap() {
            break s;
        }
        if let Ok(Some(s)) = run.0.try_wait() {
            panic!("run exited: {s}\n{}", log_tail(&run_log));
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "the player did not finish\n{}\n{}",
            log_tail(&play_log),
            log_tail(&run_log)
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut out = String::new();
    std::io::Read::read_to_string(player.0.stdout.as_mut().unwrap(), &mut out).unwrap();
    assert!(
        status.success(),
        "player: {status}\n{}",
        log_tail(&play_log)
    );
    let played = last_json(&out);
    println!("player: {played}");
    assert_eq!(played["messages"], 4, "{played}");
    // Give the last sweep time to pass through SLAM and the mapper, then stop the agent.
    std::thread::sleep(Duration::from_secs(2));
    let pid = run.0.id().to_string();
    assert!(Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap()
        .success());
    let mut out = String::new();
    std::io::Read::read_to_string(run.0.stdout.as_mut().unwrap(), &mut out).unwrap();
    let status = run.0.wait().unwrap();
    assert!(status.success(), "run: {status}\n{}", log_tail(&run_log));
    let summary = last_json(&out);
    println!("run summary: {summary}");
    // 4 messages of a continuous packet stream: the sweeps cut at 0 deg that close within it
    // (the first one partial), each localised and mapped.
    let scans = summary["scans"].as_u64().unwrap();
    assert!(scans >= 3, "{summary}");
    let map = &summary["map"];
    assert_eq!(map["scans_mapped"].as_u64().unwrap(), scans, "{summary}");
    assert!(map["tiles"].as_u64().unwrap() > 0, "{summary}");
    assert!(map["known_cells"].as_u64().unwrap() > 100, "{summary}");
    let undecodable = summary["counts"]["undecodable"].as_array().unwrap();
    assert!(undecodable.is_empty(), "{summary}");
}

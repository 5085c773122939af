//! ICP SLAM on a recorded park drive among walkers (issue 4): the real `robot-agent` records the
//! scripted drive (`sim --record`, truth poses and the walkers' real positions included), then
//! `slam eval --scenario` scores the SLAM trajectory and what the walkers left in the map.

use support::{num, robot_agent_json};

/// Seconds of the park drive to record: the scripted route passes 200 m at ~250 s.
const DRIVE_S: &str = "260";

/// Drift at most 0.5% over at least 200 m, and no walker points left in the final map.
#[test]
fn park_drive_drift_and_walker_leftovers() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let rec = tmp.path().join("park");
    let rec_s = rec.to_str().expect("utf-8 temp path");
    let sim = robot_agent_json(&[
        "sim",
        "--scenario",
        "config/scenarios/park.toml",
        "--headless",
        "--follow-drive",
        "--duration",
        DRIVE_S,
        "--record",
        rec_s,
    ]);
    eprintln!("sim: {sim}");
    let e = robot_agent_json(&[
        "slam",
        "eval",
        rec_s,
        "--config",
        "config/slam.toml",
        "--scenario",
        "config/scenarios/park.toml",
        "--json",
    ]);
    let w = &e["walkers"];
    eprintln!(
        "slam: frames {} path_m {:.1} ate_m {:.3} drift_pct {:.3} ms_per_frame {:.1}; walkers {w}",
        e["frames"],
        num(&e, "path_m"),
        num(&e, "ate_m"),
        num(&e, "drift_pct"),
        num(&e, "ms_per_frame"),
    );
    assert!(num(&e, "path_m") >= 200.0, "drive too short: {e}");
    assert!(num(&e, "drift_pct") <= 0.5, "drift: {e}");
    assert!(num(&e, "ate_m") <= 0.3, "ATE: {e}");
    // The walkers were seen and mapped (so leftovers had every chance to appear)...
    assert!(
        num(w, "points_inserted") >= 500.0,
        "walkers barely seen: {w}"
    );
    // ...and none of it stayed behind them.
    assert_eq!(
        num(w, "left_final"),
        0.0,
        "walker points left in the final map: {w}"
    );
}

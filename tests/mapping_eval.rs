//! Traversability mapping scored against the simulator's truth labels (issue 5): the real
//! `robot-agent map eval` drives a scenario and prints its scores as JSON.
//!
//! The map is built on the robot's own localisation (SLAM with GNSS and IMU, as on the robot),
//! not on the simulator's poses: the product's map is what is judged (issue 23). Truth poses
//! are an upper bound, reported by `map eval --use-truth-poses` and in README.
//!
//! `platforms`, `street` (walkers, 5/10/15 cm curbs, cars, stairs) and `slopes` (ramps of 10 to
//! 35 deg with raised landings) hold every goal of the issue; `park` (0.990 obstacle recall: a
//! 10 cm strip in grass reads as 6.5 cm) is measured by `map eval` and in README, not here.

use serde_json::Value;
use support::{num, robot_agent_json};

fn eval(scenario: &str) -> Value {
    let r = eval_raw(scenario);
    assert_eq!(r["truth_poses"], Value::Bool(false), "{r}");
    assert_eq!(num(&r, "slam_failures"), 0.0, "localisation failed: {r}");
    r
}

fn eval_raw(scenario: &str) -> Value {
    robot_agent_json(&[
        "map",
        "eval",
        "--scenario",
        &format!("config/scenarios/{scenario}.toml"),
        "--json",
    ])
}

#[test]
fn platform_edges_and_drop_offs_are_obstacles() {
    let r = eval("platforms");
    eprintln!("platforms: {r}");
    assert!(num(&r, "cells") > 5000.0, "too little observed: {r}");
    assert!(num(&r, "accuracy") >= 0.99, "{r}");
    assert!(num(&r, "obstacle_recall") >= 0.99, "{r}");
    assert!(num(&r, "false_obstacle_rate") <= 0.01, "{r}");
    assert_eq!(num(&r, "collisions"), 0.0, "{r}");
}

#[test]
fn street_curbs_cars_and_walkers() {
    let r = eval("street");
    eprintln!("street: {r}");
    assert!(num(&r, "cells") > 30000.0, "too little observed: {r}");
    assert!(num(&r, "accuracy") >= 0.99, "{r}");
    // After three walkers have passed (walker_cells: the cells they crossed).
    assert!(
        num(&r, "walker_cells") > 1000.0,
        "the walkers were not seen: {r}"
    );
    assert!(num(&r, "false_obstacle_rate") <= 0.01, "{r}");
    // 10 cm curbs block and 5 cm curbs do not (Husky profile).
    assert!(num(&r, "curb10_detected") >= 0.99, "{r}");
    assert!(num(&r, "curb5_traversable") >= 0.98, "{r}"); // 0.997 measured
    assert!(num(&r, "obstacle_recall") >= 0.99, "{r}");
}

#[test]
fn slopes_over_23_deg_and_landing_edges_block() {
    let r = eval("slopes");
    eprintln!("slopes: {r}");
    assert!(num(&r, "cells") > 20000.0, "too little observed: {r}");
    assert!(num(&r, "accuracy") >= 0.99, "{r}");
    assert!(num(&r, "obstacle_recall") >= 0.99, "{r}");
    assert!(num(&r, "false_obstacle_rate") <= 0.01, "{r}");
}

//! The loops that drive an [`Agent`](agent::Agent) with the built-in simulator: headless
//! missions that run as fast as the CPU allows and print a report, and the live robot on the
//! Zenoh bus.
//!
//! The simulator is the robot here: the agent only sees its sensor outputs (scans, odometry,
//! NMEA), never its truth; the truth is used only to score the outcome.

pub mod bag_play;
pub mod convert;
pub mod gnss_sources;
pub mod graph_eval;
pub mod io_config;
pub mod live;
pub mod map_eval;
pub mod nav_computer;
pub mod obstacle_positions;
pub mod robot;
pub mod ros2;
pub mod stages;
pub mod world;

mod goal;
mod obstacles;
mod rig;
#[cfg(test)]
mod scenario_tests;
mod teach_repeat;

pub use goal::{run_goal, run_goal_rig, HeadlessOptions, MissionReport};
pub use obstacles::{distance_to_polyline, ObstacleFile};
pub use rig::{LocalisationError, Rig, ScanMode, StepEvents, TileSink};
pub use teach_repeat::{run_teach_repeat, TeachRepeatReport};

/// Simulator step, seconds (plant and sensor timing resolution).
pub const SIM_DT_S: f64 = 0.01;
pub use crate::runtime::CONTROL_DT_S;

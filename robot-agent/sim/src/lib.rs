//! The built-in simulated world: terrain, obstacles, walkers, VLP-16 and depth-camera ray
//! casting, differential-drive plant, odometry and GNSS.
//!
//! - [`scenario`]: the scenario TOML schema (`config/scenarios/*.toml`).
//! - [`robot`]: the robot profile (`config/robot.toml`, Husky A200 defaults).
//! - [`world`]: ground height field, solids, walkers, ray casting.
//! - [`labels`]: ground-truth traversability labels on a [`common::grid::Lattice`].
//!
//! Pure library: deterministic for a seed, no clocks, no threads.
#![deny(missing_docs)]

pub mod labels;
pub mod robot;
pub mod scenario;
pub mod world;

pub use labels::{LabelParams, TruthCell, TruthGrid};
pub use robot::RobotProfile;
pub use scenario::{Scenario, ScenarioError};
pub use world::{Hit, HitKind, Obstacle, World};

//! The built-in simulated world: terrain, obstacles, walkers, VLP-16 and depth-camera ray
//! casting, differential-drive plant, odometry and GNSS.
//!
//! - [`scenario`]: the scenario TOML schema (`config/scenarios/*.toml`).
//! - [`world`]: ground height field, solids, walkers, ray casting.
//! - [`labels`]: ground-truth traversability labels on a [`common::grid::Lattice`].
//! - [`plant`]: differential drive with limits, terrain following, collisions.
//! - [`sensors`]: VLP-16, SR4000 depth camera, wheel odometry, RTK GNSS (GGA + `$PTNL,AVR`).
//! - [`simulation`]: [`Simulation`], the plant plus sensors stepped by the caller.
//! - [`record`]: writes a run as a sequence folder; [`render`]: top-down PNG with labels.
//! - [`drive`]: [`drive::PathDriver`], a pure-pursuit scripted driver on the truth pose.
//!
//! Pure library: deterministic for a seed, no clocks, no threads.
#![deny(missing_docs)]

pub mod drive;
pub mod labels;
pub mod plant;
pub mod record;
pub mod render;
pub mod scenario;
pub mod sensors;
pub mod simulation;
pub mod world;

pub use labels::{LabelParams, TruthCell, TruthGrid};
pub use plant::{Collision, CollisionKind};
pub use scenario::{Scenario, ScenarioError};
pub use sensors::{
    DepthConfig, GnssConfig, GnssFix, ImuConfig, LidarConfig, LidarModel, OdomConfig,
};
pub use simulation::{SimConfig, Simulation, StepOutput};
pub use world::{Hit, HitKind, Obstacle, WalkerState, World};

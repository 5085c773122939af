//! Scan-to-map ICP SLAM with dynamic-point map maintenance (docs/algorithms.md §3).
//!
//! A pure library: feed [`Slam`] scans (and optionally wheel odometry) with their time stamps;
//! it returns `map<-base_link`, `map<-odom`, the map around the robot and ICP diagnostics. No
//! threads, clocks or files inside.
//!
//! - [`filters`]: reading filters (sampling, robot box, voxel, PCA normals, max density).
//! - [`icp`]: point-to-plane Gauss-Newton on SE(3) with Cauchy weights and checkers.
//! - [`map`]: the point map, its spatial index and the dynamic-point ray model.
//! - [`adaptive`]: voxel size, map spacing and the match gate from the data (`"auto"` keys).
//! - [`pipeline`]: the per-scan step ([`Slam::process`]).
//! - [`gravity`]: the frame's roll and pitch from an accelerometer (gravity against the estimate).
//! - [`graph`]: the pose graph behind the odometry (keyframes, GNSS and loop factors, LM).
//! - [`place`]: Scan Context place recognition for loop candidates.
//! - [`eval`]: ATE / RPE / drift against ground truth, map-point provenance.
#![deny(missing_docs)]

pub mod adaptive;
pub mod config;
mod deskew;
pub mod eval;
pub mod filters;
pub mod graph;
pub mod gravity;
pub mod icp;
pub mod index;
pub mod map;
pub mod pipeline;
pub mod place;
pub mod se3;

pub use config::{Auto, Config};
pub use eval::{trajectory_errors, Cylinder, Provenance, TrajectoryErrors};
pub use pipeline::{register_pair, Diagnostics, PriorKind, Slam, SlamError, SlamOutput};

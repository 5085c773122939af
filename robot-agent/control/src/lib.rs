//! Path following and safety (docs/algorithms.md §6): pure pursuit with speed limits that slow the
//! robot on tight curvature and near obstacles, and the safety stop on raw scan points.
//!
//! Pure functions and small structs: poses and paths in, velocity commands out.
#![deny(missing_docs)]

pub mod pursuit;
pub mod safety;

pub use pursuit::{Config, Follower, FollowerCmd};
pub use safety::{SafetyConfig, SafetyVerdict};

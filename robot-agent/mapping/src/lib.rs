//! 2.5D traversability grid from LiDAR points, and map tiles (docs/algorithms.md §4).
//!
//! A pure library: feed a [`Mapper`] map-frame points (one scan with its pose, or the SLAM map
//! cloud around the robot), the robot pose and a time; it returns the lattice tiles that changed
//! and keeps a grid the planner reads through [`Mapper::planner_view`]. No threads, clocks or
//! files inside; it cannot tell simulated from real data.
//!
//! Pipeline per update: free space from the sweep's beams, [`filters::height_filter`] (step 1),
//! [`filters::isolated_point_filter`] (step 2), binning under the per-cell ceiling `h_max2`
//! (step 3), evidence per cell in two time epochs so newer observations replace what walkers
//! left, classification of the dirty cells by [`classify::Rules`] (step 4, with a plane-fit slope
//! and step tests beyond the source) and the far rules beyond the processing distance, negative
//! obstacles and proprioception (step 6), inflation with decaying costs (step 5). The mapper's
//! own module keeps the cell store; each stage is a module of its own under `src/mapper/`.
//!
//! ```
//! use mapping::{Config, Mapper, RobotPose, Evidence};
//! let mut m = Mapper::new(Config::default()).unwrap();
//! let mut pts = Vec::new();
//! for i in 0..200 { for j in 0..200 { pts.push([i as f32 * 0.05 - 5.0, j as f32 * 0.05 - 5.0, 0.0]); } }
//! let rep = m.update_points(pts, &RobotPose::default(), 0.0, Evidence::Scan).unwrap();
//! assert!(!rep.changed_tiles.is_empty());
//! assert_eq!(m.cell(10, 10).state, common::grid::CellState::Traversable);
//! ```
#![deny(missing_docs)]

pub mod classify;
pub mod config;
pub mod filters;
mod mapper;
pub mod render;
pub mod synth;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_far_view;
#[cfg(test)]
mod tests_revisit;

pub use classify::Class;
pub use config::{Config, ConfigError, IsolatedPair};
pub use mapper::{Evidence, MapError, Mapper, PlannerView, Replaced, RobotPose, UpdateReport};

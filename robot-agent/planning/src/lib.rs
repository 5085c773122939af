//! Goal assignment, reachability floods, A* on the traversability grid, path smoothing
//! (docs/algorithms.md §5).
//!
//! Plain library: cell coordinates and map-frame metres in, paths out; no clocks, threads or
//! transport. The only I/O is the Moving AI benchmark file reader in [`movingai`].
//!
//! ```
//! use planning::{astar::Planner, grid::{CellXY, PlanGrid}};
//! let mut grid = PlanGrid::new(50, 50, 0.2, (0.0, 0.0));
//! for y in 0..40 { grid.set_blocked(25, y); }
//! let path = Planner::new().plan(&grid, CellXY::new(0, 0), CellXY::new(49, 0)).unwrap();
//! assert!(path.length_m > 49.0 * 0.2);
//! ```
#![deny(missing_docs)]

pub mod astar;
#[cfg(feature = "baseline")]
pub mod baseline;
mod config;
pub mod goal;
pub mod grid;
pub mod movingai;
pub mod reach;
pub mod smooth;

pub use astar::{GridPath, PlanError, Planner, SearchLimits};
pub use config::PlannerConfig;
pub use grid::{CellXY, CostRule, GridWindow, PlanGrid, BLOCKED};

//! Planner parameters (`config/planner.toml`, docs/algorithms.md §5).

use serde::{Deserialize, Serialize};

/// Planner parameters. Every field has its default in code; a TOML file may set any subset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerConfig {
    // Planning window (docs/algorithms.md §5.1).
    /// Cells per side of the robot-centred planning window.
    pub num_of_grid_cells: u32,
    /// Cell edge, metres.
    pub grid_size_m: f64,

    // Costs.
    /// Step penalty per unit of a cell's 0..=255 cost, metres per cell entered.
    pub penalty_per_cost_m: f64,
    /// Whether never-observed cells may be planned through (the goal is often beyond the map).
    pub unknown_traversable: bool,
    /// Step penalty of a never-observed cell, metres.
    pub unknown_penalty_m: f64,

    // Goals (docs/algorithms.md §5.2).
    /// Radius searched for a traversable cell when the goal cell is not, metres.
    pub goal_search_radius_m: f64,
    /// GNSS goals are re-evaluated at each fix unless closer than this, metres.
    pub goal_refresh_min_distance_m: f64,

    // Search.
    /// Replanning rate, hertz (the source ran 1.4 Hz).
    pub replan_rate_hz: f64,
    /// A* expansion budget per search (a 300 x 300 window has 90 000 cells).
    pub max_expansions: usize,

    // Smoothing.
    /// Moving-average window, points (odd; 1 disables smoothing).
    pub smoothing_window_points: usize,
    /// Moving-average passes.
    pub smoothing_iterations: usize,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            num_of_grid_cells: 300,
            grid_size_m: 0.2,
            penalty_per_cost_m: 0.01,
            unknown_traversable: true,
            unknown_penalty_m: 0.1,
            goal_search_radius_m: 1.0,
            goal_refresh_min_distance_m: 5.0,
            replan_rate_hz: 2.0,
            max_expansions: 1_000_000,
            smoothing_window_points: 5,
            smoothing_iterations: 2,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_toml_keeps_defaults_and_unknown_keys_fail() {
        let c: PlannerConfig = toml::from_str("grid_size_m = 0.1").unwrap();
        assert_eq!(c.grid_size_m, 0.1);
        assert_eq!(c.num_of_grid_cells, 300);
        assert!(toml::from_str::<PlannerConfig>("grid_size = 0.1").is_err());
    }

    #[test]
    fn shipped_file_matches_defaults() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/planner.toml");
        let Ok(text) = std::fs::read_to_string(path) else {
            println!("skipping shipped_file_matches_defaults: config/planner.toml is absent");
            return;
        };
        let c: PlannerConfig = toml::from_str(&text).unwrap();
        assert_eq!(c, PlannerConfig::default());
    }
}

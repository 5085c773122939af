//! Layers over the planning grid, the way Nav2's costmap layers sit over its static map: each is
//! a pure function of a plain grid and what it needs, so it tests alone.
//!
//! - [`clear_footprint`]: the robot stands on its footprint, so those cells are drivable whatever
//!   inflation says (a walker passing close inflates the cells around the robot and would wall it
//!   in); cells classified as obstacles themselves stay blocked.
//! - [`stamp_blocked_disc`]: a safety stop that lasts is a blockage the map may not hold (too
//!   low, too new, beside the corridor): the cells within reach of its point are blocked, except
//!   under the robot's own footprint where a plan has to start.
//! - [`corridor`]: the grid a taught route is checked on: only cells the mapper classified as
//!   obstacles (with a teach-time view, only those that are new), grown by the corridor radius.

use common::grid::{CellState, Lattice};
use planning::{CellXY, GridWindow, PlanGrid};

/// Unblocks the cells of `grid` (built over `window`) whose centres lie within `radius_m` plus
/// half a cell of `robot_m`, unless `state_of` calls them obstacles.
pub fn clear_footprint(
    grid: &mut PlanGrid,
    window: &GridWindow,
    robot_m: (f64, f64),
    radius_m: f64,
    state_of: impl Fn(i64, i64) -> CellState,
) {
    let lattice: Lattice = window.lattice;
    let s = lattice.cell_size_f64();
    let r_cells = (radius_m / s).ceil() as i64;
    let (rcx, rcy) = lattice.cell_of(robot_m.0, robot_m.1);
    for cy in rcy - r_cells..=rcy + r_cells {
        for cx in rcx - r_cells..=rcx + r_cells {
            let (x, y) = lattice.cell_center_m(cx, cy);
            if (x - robot_m.0).hypot(y - robot_m.1) > radius_m + 0.5 * s {
                continue;
            }
            let (gx, gy) = (cx - window.min_cx, cy - window.min_cy);
            if state_of(cx, cy) != CellState::Obstacle
                && !grid.is_free(gx, gy)
                && grid.contains(gx, gy)
            {
                grid.set(gx, gy, 0.0, false);
            }
        }
    }
}

/// Blocks the cells of `grid` whose centres lie within `radius_m` of `at_m`, except those within
/// `keep_free.1` of `keep_free.0` (the robot's footprint).
pub fn stamp_blocked_disc(
    grid: &mut PlanGrid,
    at_m: (f64, f64),
    radius_m: f64,
    keep_free: Option<((f64, f64), f64)>,
) {
    let s = grid.cell_size_m();
    let (px, py) = grid.world_to_cell_unbounded(at_m.0, at_m.1);
    let r = (radius_m / s).ceil() as i64;
    for y in py - r..=py + r {
        for x in px - r..=px + r {
            if !grid.contains(x, y) {
                continue;
            }
            let c = grid.cell_center_m(CellXY {
                x: x as u32,
                y: y as u32,
            });
            let under_robot =
                keep_free.is_some_and(|(robot, fr)| (c.0 - robot.0).hypot(c.1 - robot.1) <= fr);
            if (c.0 - at_m.0).hypot(c.1 - at_m.1) <= radius_m && !under_robot {
                grid.set_blocked(x, y);
            }
        }
    }
}

/// A grid over `window` (the same cells as the planning grid) with every cell within
/// `radius_m` of a `blocking(cx, cy)` cell blocked and every other cell free.
pub fn corridor(
    window: &GridWindow,
    radius_m: f64,
    blocking: impl Fn(i64, i64) -> bool,
) -> PlanGrid {
    let s = window.lattice.cell_size_f64();
    // The same cells as the planning grid (`PlanGrid::from_cells` puts the origin there too).
    let origin = (window.min_cx as f64 * s, window.min_cy as f64 * s);
    let mut grid = PlanGrid::new(window.width, window.height, s, origin);
    let r = (radius_m / s).floor() as i64;
    let disc: Vec<(i64, i64)> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| ((dx * dx + dy * dy) as f64).sqrt() * s <= radius_m)
        .collect();
    for gy in 0..i64::from(window.height) {
        for gx in 0..i64::from(window.width) {
            if blocking(window.min_cx + gx, window.min_cy + gy) {
                for (dx, dy) in &disc {
                    if grid.contains(gx + dx, gy + dy) {
                        grid.set_blocked(gx + dx, gy + dy);
                    }
                }
            }
        }
    }
    grid
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window() -> GridWindow {
        GridWindow::centred(Lattice::default(), 0.0, 0.0, 50)
    }

    fn blocked_grid(w: &GridWindow) -> PlanGrid {
        let s = w.lattice.cell_size_f64();
        let mut g = PlanGrid::new(
            w.width,
            w.height,
            s,
            (w.min_cx as f64 * s, w.min_cy as f64 * s),
        );
        for y in 0..i64::from(w.height) {
            for x in 0..i64::from(w.width) {
                g.set_blocked(x, y);
            }
        }
        g
    }

    fn free_at(g: &PlanGrid, p: (f64, f64)) -> bool {
        let c = g.world_to_cell(p.0, p.1).unwrap();
        g.is_free(i64::from(c.x), i64::from(c.y))
    }

    #[test]
    fn the_footprint_is_cleared_except_real_obstacles() {
        let w = window();
        let mut g = blocked_grid(&w);
        // One obstacle cell under the robot's edge, at (0.3, 0.1).
        let obstacle = w.lattice.cell_of(0.3, 0.1);
        clear_footprint(&mut g, &w, (0.0, 0.0), 0.5, |cx, cy| {
            if (cx, cy) == obstacle {
                CellState::Obstacle
            } else {
                CellState::Inflated
            }
        });
        assert!(free_at(&g, (0.0, 0.0)));
        assert!(free_at(&g, (-0.4, 0.1)));
        assert!(!free_at(&g, (0.3, 0.1)), "an obstacle stays");
        assert!(!free_at(&g, (1.0, 0.0)), "outside the footprint");
    }

    #[test]
    fn a_lasting_stop_blocks_a_disc_but_not_the_robot() {
        let w = window();
        let s = w.lattice.cell_size_f64();
        let mut g = PlanGrid::new(
            w.width,
            w.height,
            s,
            (w.min_cx as f64 * s, w.min_cy as f64 * s),
        );
        stamp_blocked_disc(&mut g, (1.0, 0.0), 0.6, Some(((0.0, 0.0), 0.6)));
        assert!(!free_at(&g, (1.0, 0.0)));
        assert!(!free_at(&g, (1.5, 0.0)));
        assert!(free_at(&g, (0.3, 0.0)), "under the robot");
        assert!(free_at(&g, (2.0, 0.0)), "beyond the disc");
    }

    #[test]
    fn the_corridor_grows_only_blocking_cells() {
        let w = window();
        let c = w.lattice.cell_of(2.0, 0.0);
        let g = corridor(&w, 0.45, |cx, cy| (cx, cy) == c);
        assert!(!free_at(&g, (2.1, 0.1)));
        assert!(!free_at(&g, (2.1, 0.5)), "within 0.45 m");
        assert!(free_at(&g, (2.1, 0.9)));
        assert!(free_at(&g, (0.0, 0.0)));
    }
}

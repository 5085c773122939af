//! The goal-cell rules (docs/algorithms.md §5.2).
//!
//! 1. The goal is the cell containing the goal point.
//! 2. If that cell may not be entered, the nearest enterable cell within `goal_search_radius_m`
//!    (1 m) replaces it; none -> no path.
//! 3. If the goal is outside the planning window, the goal is the cell where the segment from the
//!    robot to the goal leaves the window; if that cell may not be entered, the nearest
//!    enterable cell on the window's edge.
//! 4. A robot standing in a cell it may not enter cannot plan: that is reported, not repaired
//!    (the operator nudges the robot).

use crate::grid::{CellXY, PlanGrid};

/// How the goal cell was chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum GoalRule {
    /// The cell containing the goal.
    Contains,
    /// The goal cell was blocked; this is the nearest free cell within the search radius.
    NearestFree,
    /// The goal is outside the window; this is where the robot-goal segment leaves it.
    EdgeCrossing,
    /// The goal is outside the window and the crossing cell is blocked; nearest free edge cell.
    NearestEdge,
}

/// The resolved goal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GoalCell {
    /// Cell to plan to.
    pub cell: CellXY,
    /// Which rule gave it.
    pub rule: GoalRule,
}

/// Why there is no goal cell (or no start cell).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum GoalError {
    /// The robot is outside the planning window (the window should be centred on it).
    #[error("robot at ({x_m:.2}, {y_m:.2}) m is outside the planning window")]
    RobotOutsideGrid {
        /// Robot x, map frame, metres.
        x_m: f64,
        /// Robot y, map frame, metres.
        y_m: f64,
    },
    /// The robot stands in a cell it may not enter.
    #[error("robot stands in non-traversable cell ({}, {}); nudge it free", .0.x, .0.y)]
    RobotInBlockedCell(CellXY),
    /// The goal cell and every cell within the search radius are non-traversable.
    #[error("goal cell ({}, {}) is non-traversable with no traversable cell within {radius_m} m", .cell.x, .cell.y)]
    NoFreeCellNearGoal {
        /// The goal's own cell.
        cell: CellXY,
        /// Radius searched, metres.
        radius_m: f64,
    },
    /// The goal is outside the window and no edge cell is traversable.
    #[error("goal is outside the planning window and no edge cell is traversable")]
    NoFreeEdgeCell,
    /// Coordinates are NaN or infinite.
    #[error("goal or robot position is not finite")]
    NotFinite,
}

/// The robot's own cell, checked to be enterable.
pub fn start_cell(grid: &PlanGrid, robot_m: (f64, f64)) -> Result<CellXY, GoalError> {
    if !robot_m.0.is_finite() || !robot_m.1.is_finite() {
        return Err(GoalError::NotFinite);
    }
    let c = grid
        .world_to_cell(robot_m.0, robot_m.1)
        .ok_or(GoalError::RobotOutsideGrid {
            x_m: robot_m.0,
            y_m: robot_m.1,
        })?;
    if !grid.is_free(i64::from(c.x), i64::from(c.y)) {
        return Err(GoalError::RobotInBlockedCell(c));
    }
    Ok(c)
}

/// The goal cell for a map-frame goal seen from a robot at `robot_m` (rules in the module doc).
pub fn goal_cell(
    grid: &PlanGrid,
    robot_m: (f64, f64),
    goal_m: (f64, f64),
    search_radius_m: f64,
) -> Result<GoalCell, GoalError> {
    if ![robot_m.0, robot_m.1, goal_m.0, goal_m.1]
        .iter()
        .all(|v| v.is_finite())
    {
        return Err(GoalError::NotFinite);
    }
    if let Some(c) = grid.world_to_cell(goal_m.0, goal_m.1) {
        if grid.is_free(i64::from(c.x), i64::from(c.y)) {
            return Ok(GoalCell {
                cell: c,
                rule: GoalRule::Contains,
            });
        }
        let r_cells = (search_radius_m / grid.cell_size_m()).floor() as i64;
        return nearest_free_within(grid, c, r_cells)
            .map(|cell| GoalCell {
                cell,
                rule: GoalRule::NearestFree,
            })
            .ok_or(GoalError::NoFreeCellNearGoal {
                cell: c,
                radius_m: search_radius_m,
            });
    }
    let crossing = edge_crossing(grid, robot_m, goal_m).ok_or(GoalError::RobotOutsideGrid {
        x_m: robot_m.0,
        y_m: robot_m.1,
    })?;
    if grid.is_free(i64::from(crossing.x), i64::from(crossing.y)) {
        return Ok(GoalCell {
            cell: crossing,
            rule: GoalRule::EdgeCrossing,
        });
    }
    nearest_free_edge(grid, crossing)
        .map(|cell| GoalCell {
            cell,
            rule: GoalRule::NearestEdge,
        })
        .ok_or(GoalError::NoFreeEdgeCell)
}

/// Nearest enterable cell to `c` within `r` cells (Euclidean), ties to the smallest (y, x).
fn nearest_free_within(grid: &PlanGrid, c: CellXY, r: i64) -> Option<CellXY> {
    let (cx, cy) = (i64::from(c.x), i64::from(c.y));
    let mut best: Option<(i64, i64, i64)> = None;
    for y in cy - r..=cy + r {
        for x in cx - r..=cx + r {
            let d2 = (x - cx).pow(2) + (y - cy).pow(2);
            if d2 > r * r || !grid.is_free(x, y) {
                continue;
            }
            if best.is_none_or(|b| (d2, y, x) < b) {
                best = Some((d2, y, x));
            }
        }
    }
    best.map(|(_, y, x)| CellXY::new(x as u32, y as u32))
}

/// The last window cell on the segment robot -> goal, for a robot inside and a goal outside.
fn edge_crossing(grid: &PlanGrid, robot_m: (f64, f64), goal_m: (f64, f64)) -> Option<CellXY> {
    grid.world_to_cell(robot_m.0, robot_m.1)?;
    let (ox, oy) = grid.origin_m();
    let s = grid.cell_size_m();
    let (xmax, ymax) = (
        ox + f64::from(grid.width()) * s,
        oy + f64::from(grid.height()) * s,
    );
    let (dx, dy) = (goal_m.0 - robot_m.0, goal_m.1 - robot_m.1);
    // Largest t in [0, 1] with the point inside the window (slab clipping).
    let mut t_exit = 1.0f64;
    for (p, d, lo, hi) in [(robot_m.0, dx, ox, xmax), (robot_m.1, dy, oy, ymax)] {
        if d > 0.0 {
            t_exit = t_exit.min((hi - p) / d);
        } else if d < 0.0 {
            t_exit = t_exit.min((lo - p) / d);
        }
    }
    let (x, y) = (robot_m.0 + t_exit * dx, robot_m.1 + t_exit * dy);
    // The exit point lies on the boundary; clamp into the last cell inside.
    let (cx, cy) = grid.world_to_cell_unbounded(x, y);
    let cx = cx.clamp(0, i64::from(grid.width()) - 1);
    let cy = cy.clamp(0, i64::from(grid.height()) - 1);
    Some(CellXY::new(cx as u32, cy as u32))
}

/// Nearest enterable cell on the window's border to `c`, ties to the smallest (y, x).
fn nearest_free_edge(grid: &PlanGrid, c: CellXY) -> Option<CellXY> {
    let (w, h) = (i64::from(grid.width()), i64::from(grid.height()));
    let (cx, cy) = (i64::from(c.x), i64::from(c.y));
    let mut best: Option<(i64, i64, i64)> = None;
    let mut consider = |x: i64, y: i64| {
        if grid.is_free(x, y) {
            let d2 = (x - cx).pow(2) + (y - cy).pow(2);
            if best.is_none_or(|b| (d2, y, x) < b) {
                best = Some((d2, y, x));
            }
        }
    };
    for x in 0..w {
        consider(x, 0);
        consider(x, h - 1);
    }
    for y in 0..h {
        consider(0, y);
        consider(w - 1, y);
    }
    best.map(|(_, y, x)| CellXY::new(x as u32, y as u32))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> PlanGrid {
        // 20 x 20 cells of 0.2 m, window [0, 4) x [0, 4) m.
        PlanGrid::new(20, 20, 0.2, (0.0, 0.0))
    }

    #[test]
    fn goal_inside_and_free() {
        let g = grid();
        let r = goal_cell(&g, (0.5, 0.5), (3.1, 2.1), 1.0).unwrap();
        assert_eq!(
            r,
            GoalCell {
                cell: CellXY::new(15, 10),
                rule: GoalRule::Contains
            }
        );
    }

    #[test]
    fn blocked_goal_moves_within_radius_or_fails() {
        let mut g = grid();
        // Block a disc of radius 3 cells around (10, 10).
        for y in 0..20 {
            for x in 0..20 {
                if (x - 10i64).pow(2) + (y - 10i64).pow(2) <= 9 {
                    g.set_blocked(x, y);
                }
            }
        }
        let goal = g.cell_center_m(CellXY::new(10, 10));
        let r = goal_cell(&g, (0.1, 0.1), goal, 1.0).unwrap();
        assert_eq!(r.rule, GoalRule::NearestFree);
        assert!(g.is_free(i64::from(r.cell.x), i64::from(r.cell.y)));
        let d2 = (i64::from(r.cell.x) - 10).pow(2) + (i64::from(r.cell.y) - 10).pow(2);
        assert_eq!(
            d2, 10,
            "the nearest free cell of a radius-3 disc is at distance sqrt(10)"
        );
        // 0.5 m = 2.5 cells: nothing free inside.
        assert!(matches!(
            goal_cell(&g, (0.1, 0.1), goal, 0.5),
            Err(GoalError::NoFreeCellNearGoal { .. })
        ));
    }

    #[test]
    fn goal_outside_uses_the_edge_crossing() {
        let mut g = grid();
        // Robot at the centre, goal far east on the same row.
        let r = goal_cell(&g, (2.0, 2.1), (50.0, 2.1), 1.0).unwrap();
        assert_eq!(
            r,
            GoalCell {
                cell: CellXY::new(19, 10),
                rule: GoalRule::EdgeCrossing
            }
        );
        // Diagonal goal to the north-west leaves through the corner region.
        let r = goal_cell(&g, (2.0, 2.0), (-10.0, 14.0), 1.0).unwrap();
        assert_eq!(r.cell, CellXY::new(0, 19));
        // Crossing blocked: nearest free edge cell.
        g.set_blocked(19, 10);
        g.set_blocked(19, 11);
        g.set_blocked(19, 9);
        let r = goal_cell(&g, (2.0, 2.1), (50.0, 2.1), 1.0).unwrap();
        assert_eq!(r.rule, GoalRule::NearestEdge);
        assert_eq!(r.cell, CellXY::new(19, 8), "ties go to the smaller row");
        for i in 0..20 {
            g.set_blocked(i, 0);
            g.set_blocked(i, 19);
            g.set_blocked(0, i);
            g.set_blocked(19, i);
        }
        assert_eq!(
            goal_cell(&g, (2.0, 2.1), (50.0, 2.1), 1.0),
            Err(GoalError::NoFreeEdgeCell)
        );
    }

    #[test]
    fn robot_cell_checks() {
        let mut g = grid();
        assert_eq!(start_cell(&g, (0.3, 0.3)), Ok(CellXY::new(1, 1)));
        g.set_blocked(1, 1);
        assert_eq!(
            start_cell(&g, (0.3, 0.3)),
            Err(GoalError::RobotInBlockedCell(CellXY::new(1, 1)))
        );
        assert!(matches!(
            start_cell(&g, (-1.0, 0.3)),
            Err(GoalError::RobotOutsideGrid { .. })
        ));
        assert_eq!(start_cell(&g, (f64::NAN, 0.3)), Err(GoalError::NotFinite));
        assert!(matches!(
            goal_cell(&g, (-1.0, 0.3), (9.0, 9.0), 1.0),
            Err(GoalError::RobotOutsideGrid { .. })
        ));
    }
}

//! The `pathfinding` crate's A* on a [`PlanGrid`], as the speed baseline of `robot-agent plan
//! bench` and the criterion benchmark (feature `baseline`; never part of the robot's runtime).
//!
//! Same movement rule as [`crate::astar`]: 8-connected, no corner cutting, step = length +
//! penalty of the cell entered. `pathfinding` needs a totally ordered cost, so costs are fixed
//! point in nanometres (rounding error ~1e-9 per step, far below the benchmark's 1e-5).

use crate::grid::{CellXY, PlanGrid};

const SCALE: f64 = 1e9;

/// Shortest path cost (metres) and cells, or None when there is no path.
pub fn pathfinding_astar(
    grid: &PlanGrid,
    start: CellXY,
    goal: CellXY,
) -> Option<(Vec<CellXY>, f64)> {
    let s = grid.cell_size_m();
    let ortho = (s * SCALE).round() as u64;
    let diag = (s * std::f64::consts::SQRT_2 * SCALE).round() as u64;
    let (gx, gy) = (i64::from(goal.x), i64::from(goal.y));
    let penalty = |x: i64, y: i64| (f64::from(grid.penalty_m(x, y)) * SCALE).round() as u64;
    let successors = |c: &(i64, i64)| {
        let (x, y) = *c;
        let mut out: Vec<((i64, i64), u64)> = Vec::with_capacity(8);
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (nx, ny) = (x + dx, y + dy);
                if (dx == 0 && dy == 0) || !grid.is_free(nx, ny) {
                    continue;
                }
                let diagonal = dx != 0 && dy != 0;
                if diagonal && (!grid.is_free(x + dx, y) || !grid.is_free(x, y + dy)) {
                    continue;
                }
                out.push((
                    (nx, ny),
                    if diagonal { diag } else { ortho } + penalty(nx, ny),
                ));
            }
        }
        out
    };
    // Floor keeps the fixed-point heuristic admissible.
    let heuristic = |c: &(i64, i64)| {
        let dx = (c.0 - gx).unsigned_abs() as f64;
        let dy = (c.1 - gy).unsigned_abs() as f64;
        (s * (dx + dy + (std::f64::consts::SQRT_2 - 2.0) * dx.min(dy)) * SCALE).floor() as u64
    };
    if !grid.is_free(i64::from(start.x), i64::from(start.y)) || !grid.is_free(gx, gy) {
        return None;
    }
    let (cells, cost) = pathfinding::prelude::astar(
        &(i64::from(start.x), i64::from(start.y)),
        successors,
        heuristic,
        |c| *c == (gx, gy),
    )?;
    Some((
        cells
            .into_iter()
            .map(|(x, y)| CellXY::new(x as u32, y as u32))
            .collect(),
        cost as f64 / SCALE,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::astar::Planner;

    #[test]
    fn agrees_with_our_astar() {
        let mut g = PlanGrid::new(30, 20, 0.2, (0.0, 0.0));
        for y in 0..15 {
            g.set_blocked(10, y);
        }
        g.set(5, 5, 0.3, false);
        let ours = Planner::new()
            .plan(&g, CellXY::new(0, 0), CellXY::new(29, 0))
            .unwrap();
        let (_, cost) = pathfinding_astar(&g, CellXY::new(0, 0), CellXY::new(29, 0)).unwrap();
        assert!(
            (ours.cost_m - cost).abs() < 1e-6,
            "{} vs {cost}",
            ours.cost_m
        );
    }
}

//! Path smoothing (docs/algorithms.md §5.5: moving average before following) and cell path ->
//! polyline.
//!
//! The A* path zig-zags between cell centres in 45 degree steps; a moving average turns that into
//! a path pure pursuit can follow. Averaging pulls points towards the inside of bends, which can
//! drag a point into an obstacle, so every moved point is checked and falls back to its previous
//! position when it, or the segments to its neighbours, would enter a blocked cell.

use crate::grid::{CellXY, PlanGrid};

/// Map-frame centres of the cells of a path, metres.
pub fn cells_to_polyline(grid: &PlanGrid, cells: &[CellXY]) -> Vec<(f64, f64)> {
    cells.iter().map(|&c| grid.cell_center_m(c)).collect()
}

/// Moving average of `points` over `window_points` (odd; shrunk near the ends so that it stays
/// centred), repeated `iterations` times. The end points never move; a point that would land in
/// a blocked cell or make a segment cross one keeps its position from the previous pass. If the
/// input polyline is free, so is the output.
pub fn smooth_polyline(
    grid: &PlanGrid,
    points: &[(f64, f64)],
    window_points: usize,
    iterations: usize,
) -> Vec<(f64, f64)> {
    let half = window_points / 2;
    let mut prev = points.to_vec();
    if half == 0 || points.len() < 3 {
        return prev;
    }
    let mut out = prev.clone();
    for _ in 0..iterations {
        for i in 1..prev.len() - 1 {
            let k = half.min(i).min(prev.len() - 1 - i);
            let n = (2 * k + 1) as f64;
            let (sx, sy) = prev[i - k..=i + k]
                .iter()
                .fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
            let cand = (sx / n, sy / n);
            // out[i-1] is final; prev[i+1] is where the next point stays if it is rejected.
            let ok = point_free(grid, cand)
                && segment_free(grid, out[i - 1], cand)
                && segment_free(grid, cand, prev[i + 1]);
            out[i] = if ok { cand } else { prev[i] };
        }
        std::mem::swap(&mut prev, &mut out);
        out.copy_from_slice(&prev);
    }
    prev
}

/// Whether a map-frame point lies in an enterable cell.
pub fn point_free(grid: &PlanGrid, p: (f64, f64)) -> bool {
    let (x, y) = grid.world_to_cell_unbounded(p.0, p.1);
    grid.is_free(x, y)
}

/// Whether the segment a-b stays in enterable cells (sampled every eighth of a cell).
pub fn segment_free(grid: &PlanGrid, a: (f64, f64), b: (f64, f64)) -> bool {
    segment_samples(grid.cell_size_m(), a, b).all(|p| point_free(grid, p))
}

/// The points [`segment_free`] tests on the segment a-b: both ends and every eighth of a
/// `cell_size_m` between them.
pub fn segment_samples(
    cell_size_m: f64,
    a: (f64, f64),
    b: (f64, f64),
) -> impl Iterator<Item = (f64, f64)> {
    let len = (b.0 - a.0).hypot(b.1 - a.1);
    let steps = (len / (cell_size_m / 8.0)).ceil().max(1.0) as usize;
    (0..=steps).map(move |k| {
        let t = k as f64 / steps as f64;
        (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
    })
}

/// Length of a polyline, metres.
pub fn polyline_length_m(points: &[(f64, f64)]) -> f64 {
    points
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::astar::Planner;

    #[test]
    fn smoothing_shortens_a_zigzag_and_keeps_ends() {
        let g = PlanGrid::new(40, 40, 0.2, (0.0, 0.0));
        let path = Planner::new()
            .plan(&g, CellXY::new(0, 0), CellXY::new(39, 13))
            .unwrap();
        let raw = cells_to_polyline(&g, &path.cells);
        let smooth = smooth_polyline(&g, &raw, 5, 3);
        assert_eq!(smooth.len(), raw.len());
        assert_eq!(smooth.first(), raw.first());
        assert_eq!(smooth.last(), raw.last());
        assert!(polyline_length_m(&smooth) < polyline_length_m(&raw) - 1e-3);
    }

    #[test]
    fn smoothing_never_enters_blocked_cells() {
        // A tight L-shaped corridor one cell wide: averaging would cut the inner corner.
        let mut g = PlanGrid::new(20, 20, 0.2, (0.0, 0.0));
        for y in 0..20 {
            for x in 0..20 {
                let corridor = (y == 2 && x <= 15) || (x == 15 && y >= 2);
                if !corridor {
                    g.set_blocked(x, y);
                }
            }
        }
        let path = Planner::new()
            .plan(&g, CellXY::new(0, 2), CellXY::new(15, 19))
            .unwrap();
        let raw = cells_to_polyline(&g, &path.cells);
        for window in [3, 5, 9] {
            let smooth = smooth_polyline(&g, &raw, window, 4);
            for w in smooth.windows(2) {
                assert!(
                    segment_free(&g, w[0], w[1]),
                    "window {window}: {:?} -> {:?}",
                    w[0],
                    w[1]
                );
            }
        }
        // Smoothing did move the straight parts' neighbours of the corner only where free.
        assert!(!segment_free(&g, raw[10], raw[raw.len() - 10]));
    }

    #[test]
    fn degenerate_inputs() {
        let g = PlanGrid::new(5, 5, 1.0, (0.0, 0.0));
        assert!(smooth_polyline(&g, &[], 5, 2).is_empty());
        assert_eq!(
            smooth_polyline(&g, &[(0.5, 0.5), (1.5, 1.5)], 5, 2).len(),
            2
        );
        assert_eq!(
            smooth_polyline(&g, &[(0.5, 0.5), (1.5, 0.5), (2.5, 1.5)], 1, 2)[1],
            (1.5, 0.5)
        );
    }
}

//! Reachability floods (docs/algorithms.md §5.3): does a path exist, may one exist beyond the map,
//! or none?
//!
//! Two floods on the 8-connected grid (no corner cutting, as A* moves):
//! - from the start over *traversable* cells (enterable and observed), noting frontier cells
//!   (traversable next to an unknown cell) and grid-edge cells;
//! - from the goal over every cell that is not non-traversable (enterable or unknown).
//!
//! A path exists if the goal flood meets the start flood (which includes reaching a start-side
//! frontier through unknown cells); it may exist beyond the map if both floods reach the grid
//! edge; otherwise there is none.

use std::collections::VecDeque;

use crate::grid::{CellXY, PlanGrid, BLOCKED};

/// Outcome of the floods.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Reachability {
    /// The floods meet: a path exists in the window (possibly through unknown cells).
    Reachable,
    /// They do not meet, but both reach the window's edge: a path may exist outside it.
    MayExistBeyondMap,
    /// Neither: the goal is cut off.
    NoPath,
}

/// The floods' result with what they saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReachReport {
    /// The verdict.
    pub reachability: Reachability,
    /// Cells in the start flood.
    pub start_cells: usize,
    /// Frontier cells (traversable next to unknown) in the start flood.
    pub frontier_cells: usize,
    /// Whether the start flood reached the window edge.
    pub start_reaches_edge: bool,
    /// Whether the goal flood reached the window edge (false when it stopped early on meeting).
    pub goal_reaches_edge: bool,
}

/// Flood buffers, kept between calls.
#[derive(Debug, Default)]
pub struct Floods {
    start_mark: Vec<u32>,
    goal_mark: Vec<u32>,
    generation: u32,
    queue: VecDeque<usize>,
}

impl Floods {
    /// Empty buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Runs both floods. Start or goal outside the grid, or a start that is not traversable,
    /// give [`Reachability::NoPath`] with empty counts.
    pub fn check(&mut self, grid: &PlanGrid, start: CellXY, goal: CellXY) -> ReachReport {
        let mut report = ReachReport {
            reachability: Reachability::NoPath,
            start_cells: 0,
            frontier_cells: 0,
            start_reaches_edge: false,
            goal_reaches_edge: false,
        };
        let inside = |c: CellXY| grid.contains(i64::from(c.x), i64::from(c.y));
        if !inside(start) || !inside(goal) {
            return report;
        }
        let n = grid.padded_len();
        if self.start_mark.len() < n {
            self.start_mark.resize(n, 0);
            self.goal_mark.resize(n, 0);
        }
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.start_mark.iter_mut().for_each(|v| *v = 0);
            self.goal_mark.iter_mut().for_each(|v| *v = 0);
            self.generation = 1;
        }
        let gen = self.generation;
        let pen = grid.penalties();
        let unknown = grid.unknown_flags();
        let stride = grid.stride();
        let (w, h) = (grid.width(), grid.height());
        let traversable = |i: usize| pen[i] != BLOCKED && !unknown[i];
        // The padded border is blocked and known, so it is neither traversable nor passable.
        let passable = |i: usize| pen[i] != BLOCKED || unknown[i];
        let on_edge = |i: usize| {
            let c = grid.cell_of_index(i);
            c.x == 0 || c.y == 0 || c.x == w - 1 || c.y == h - 1
        };
        let offsets = neighbour_offsets(stride);

        let si = grid.index(start);
        if traversable(si) {
            self.start_mark[si] = gen;
            self.queue.clear();
            self.queue.push_back(si);
            while let Some(i) = self.queue.pop_front() {
                report.start_cells += 1;
                report.start_reaches_edge |= on_edge(i);
                if offsets
                    .iter()
                    .any(|&(o, _, _)| unknown[(i as isize + o) as usize])
                {
                    report.frontier_cells += 1;
                }
                for &(o, a, b) in &offsets {
                    let j = (i as isize + o) as usize;
                    if self.start_mark[j] == gen || !traversable(j) {
                        continue;
                    }
                    if a != 0
                        && (!traversable((i as isize + a) as usize)
                            || !traversable((i as isize + b) as usize))
                    {
                        continue;
                    }
                    self.start_mark[j] = gen;
                    self.queue.push_back(j);
                }
            }
        } else {
            return report;
        }

        let gi = grid.index(goal);
        if !passable(gi) {
            return report;
        }
        self.goal_mark[gi] = gen;
        self.queue.clear();
        self.queue.push_back(gi);
        while let Some(i) = self.queue.pop_front() {
            if self.start_mark[i] == gen {
                report.reachability = Reachability::Reachable;
                return report;
            }
            report.goal_reaches_edge |= on_edge(i);
            for &(o, a, b) in &offsets {
                let j = (i as isize + o) as usize;
                if self.goal_mark[j] == gen || !passable(j) {
                    continue;
                }
                if a != 0
                    && (!passable((i as isize + a) as usize)
                        || !passable((i as isize + b) as usize))
                {
                    continue;
                }
                self.goal_mark[j] = gen;
                self.queue.push_back(j);
            }
        }
        if report.start_reaches_edge && report.goal_reaches_edge {
            report.reachability = Reachability::MayExistBeyondMap;
        }
        report
    }
}

/// The 8 neighbour offsets of a padded index; diagonals carry the two orthogonal offsets that
/// must be passable (0, 0 for orthogonal moves).
fn neighbour_offsets(stride: usize) -> [(isize, isize, isize); 8] {
    let s = stride as isize;
    [
        (1, 0, 0),
        (-1, 0, 0),
        (s, 0, 0),
        (-s, 0, 0),
        (s + 1, 1, s),
        (s - 1, -1, s),
        (-s + 1, 1, -s),
        (-s - 1, -1, -s),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall(g: &mut PlanGrid, x: i64, y0: i64, y1: i64, unknown: bool) {
        for y in y0..y1 {
            if unknown {
                g.set(x, y, 0.1, true);
            } else {
                g.set_blocked(x, y);
            }
        }
    }

    #[test]
    fn open_grid_is_reachable() {
        let g = PlanGrid::new(10, 10, 0.2, (0.0, 0.0));
        let r = Floods::new().check(&g, CellXY::new(1, 1), CellXY::new(8, 8));
        assert_eq!(r.reachability, Reachability::Reachable);
        assert_eq!(r.start_cells, 100);
        assert_eq!(r.frontier_cells, 0);
    }

    #[test]
    fn wall_across_the_window_means_beyond_map() {
        let mut g = PlanGrid::new(10, 10, 0.2, (0.0, 0.0));
        wall(&mut g, 5, 0, 10, false);
        let r = Floods::new().check(&g, CellXY::new(1, 1), CellXY::new(8, 8));
        assert_eq!(r.reachability, Reachability::MayExistBeyondMap);
    }

    #[test]
    fn enclosed_goal_means_no_path() {
        let mut g = PlanGrid::new(12, 12, 0.2, (0.0, 0.0));
        // A ring of blocked cells at Chebyshev distance 2 around the goal (7, 7).
        for y in 5..=9i64 {
            for x in 5..=9i64 {
                if (x - 7).abs().max((y - 7).abs()) == 2 {
                    g.set_blocked(x, y);
                }
            }
        }
        let mut f = Floods::new();
        let r = f.check(&g, CellXY::new(1, 1), CellXY::new(7, 7));
        assert_eq!(r.reachability, Reachability::NoPath, "{r:?}");
        // Opening the ring's corner leaves only a diagonal squeeze: still closed.
        g.set(5, 5, 0.0, false);
        assert_eq!(
            f.check(&g, CellXY::new(1, 1), CellXY::new(7, 7))
                .reachability,
            Reachability::NoPath
        );
        // Opening a side cell lets the floods meet.
        g.set(7, 5, 0.0, false);
        assert_eq!(
            f.check(&g, CellXY::new(1, 1), CellXY::new(7, 7))
                .reachability,
            Reachability::Reachable
        );
    }

    #[test]
    fn unknown_gap_meets_start_frontier() {
        let mut g = PlanGrid::new(10, 10, 0.2, (0.0, 0.0));
        wall(&mut g, 5, 0, 10, false);
        wall(&mut g, 5, 3, 5, true); // an unobserved gap in the wall
        let mut f = Floods::new();
        let r = f.check(&g, CellXY::new(1, 1), CellXY::new(8, 8));
        assert_eq!(r.reachability, Reachability::Reachable);
        assert!(r.frontier_cells > 0);
        // A walled window split by a band of unobserved cells: only the goal flood crosses it,
        // meeting the start flood at its frontier; the start flood never touches the edge.
        let mut g = PlanGrid::new(12, 12, 0.2, (0.0, 0.0));
        for i in 0..12 {
            for j in [0, 11] {
                g.set_blocked(i, j);
                g.set_blocked(j, i);
            }
        }
        wall(&mut g, 6, 1, 11, true);
        let r = f.check(&g, CellXY::new(3, 3), CellXY::new(8, 8));
        assert_eq!(r.reachability, Reachability::Reachable);
        assert!(!r.start_reaches_edge);
        // Goal cell itself blocked: nothing to flood from.
        g.set_blocked(8, 8);
        assert_eq!(
            f.check(&g, CellXY::new(3, 3), CellXY::new(8, 8))
                .reachability,
            Reachability::NoPath
        );
    }
}

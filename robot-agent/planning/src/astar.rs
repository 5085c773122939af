//! A* on the 8-connected planning grid (docs/algorithms.md §5.4).
//!
//! `f = g + h` with the octile heuristic `h = s (dx + dy + (sqrt2 - 2) min(dx, dy))` (s = cell
//! size); a step costs its length (`s` or `s sqrt2`) plus the step penalty of the cell entered.
//! A diagonal step needs both orthogonal neighbours enterable, so a path never cuts the corner of
//! a blocked cell. Penalties are non-negative, so the heuristic is consistent and every cell is
//! expanded at most once: the path found is optimal.
//!
//! Speed comes from layout, not cleverness: flat arrays indexed by cell (padded with a blocked
//! border, so no bounds checks), a binary heap of plain integers, generation stamps instead of
//! clearing arrays between searches, and buffers kept by [`Planner`] between calls.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use crate::grid::{CellXY, PlanGrid, BLOCKED};

/// Why no path was returned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// A start or goal cell is outside the grid.
    #[error("cell ({x}, {y}) is outside the {width} x {height} grid")]
    OutOfBounds {
        /// Column asked for.
        x: u32,
        /// Row asked for.
        y: u32,
        /// Grid width.
        width: u32,
        /// Grid height.
        height: u32,
    },
    /// The start cell may not be entered (the robot stands on an obstacle or inflated cell).
    #[error("start cell ({}, {}) is blocked", .0.x, .0.y)]
    StartBlocked(CellXY),
    /// The goal cell may not be entered.
    #[error("goal cell ({}, {}) is blocked", .0.x, .0.y)]
    GoalBlocked(CellXY),
    /// The search exhausted every reachable cell.
    #[error("no path after expanding {expansions} cells")]
    NoPath {
        /// Cells expanded.
        expansions: usize,
    },
    /// The expansion budget ran out first.
    #[error("expansion budget of {max_expansions} exceeded")]
    BudgetExceeded {
        /// The budget.
        max_expansions: usize,
    },
    /// The cancel check asked to stop.
    #[error("cancelled after {expansions} expansions")]
    Cancelled {
        /// Cells expanded.
        expansions: usize,
    },
}

/// Limits on one search.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SearchLimits {
    /// Stop with [`PlanError::BudgetExceeded`] after this many expansions (None = no limit).
    pub max_expansions: Option<usize>,
}

/// A path found by [`Planner::plan`].
#[derive(Clone, Debug, PartialEq)]
pub struct GridPath {
    /// Cells from start to goal, both included.
    pub cells: Vec<CellXY>,
    /// Total cost: length in metres plus the penalties of the cells entered.
    pub cost_m: f64,
    /// Geometric length, metres (cost without penalties).
    pub length_m: f64,
    /// Cells expanded by the search.
    pub expansions: usize,
}

/// Open-list entry. Integers only: non-negative f64 compare like their bit patterns, so the heap
/// never touches floating-point comparisons.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Open {
    f_bits: u64,
    g_bits: u64,
    idx: u32,
}

impl Ord for Open {
    /// Max-heap order: smallest f first; among equal f the deepest (largest g, which finishes
    /// sooner); then the smallest cell index, so ties never depend on insertion order.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .f_bits
            .cmp(&self.f_bits)
            .then(self.g_bits.cmp(&other.g_bits))
            .then(other.idx.cmp(&self.idx))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// How often (in expansions) the cancel check is polled.
const CANCEL_POLL: usize = 1024;

/// Per-cell search state, one cache line access per neighbour.
#[derive(Clone, Copy, Debug, Default)]
struct Node {
    /// Cost from the start, valid when `stamp` is this search's open or closed tag.
    g_m: f64,
    /// Predecessor (padded index), valid with `g_m`.
    parent: u32,
    /// `generation << 1` once reached, `| 1` once expanded; older values mean "untouched".
    stamp: u32,
}

/// An A* planner that keeps its buffers between searches.
#[derive(Debug, Default)]
pub struct Planner {
    nodes: Vec<Node>,
    generation: u32,
    heap: BinaryHeap<Open>,
}

impl Planner {
    /// A planner with empty buffers (they grow to the grid size on first use).
    pub fn new() -> Self {
        Self::default()
    }

    /// Shortest path from `start` to `goal` with no limits.
    pub fn plan(
        &mut self,
        grid: &PlanGrid,
        start: CellXY,
        goal: CellXY,
    ) -> Result<GridPath, PlanError> {
        self.plan_with(grid, start, goal, SearchLimits::default(), &mut || false)
    }

    /// Shortest path from `start` to `goal`, giving up when `limits` are hit or `cancel` returns
    /// true (polled every 1024 expansions).
    pub fn plan_with(
        &mut self,
        grid: &PlanGrid,
        start: CellXY,
        goal: CellXY,
        limits: SearchLimits,
        cancel: &mut dyn FnMut() -> bool,
    ) -> Result<GridPath, PlanError> {
        for c in [start, goal] {
            if !grid.contains(i64::from(c.x), i64::from(c.y)) {
                return Err(PlanError::OutOfBounds {
                    x: c.x,
                    y: c.y,
                    width: grid.width(),
                    height: grid.height(),
                });
            }
        }
        let pen = grid.penalties();
        let (si, gi) = (grid.index(start), grid.index(goal));
        if pen[si] == BLOCKED {
            return Err(PlanError::StartBlocked(start));
        }
        if pen[gi] == BLOCKED {
            return Err(PlanError::GoalBlocked(goal));
        }
        self.prepare(grid.padded_len());
        let open_tag = self.generation << 1;
        let closed_tag = open_tag | 1;

        let s = grid.cell_size_m();
        let diag = s * std::f64::consts::SQRT_2;
        let stride = grid.stride();
        let st = stride as isize;
        // Orthogonal moves: (offset, dx, dy). Diagonals also carry the two orthogonal offsets
        // whose cells must be enterable.
        let ortho: [(isize, i64, i64); 4] = [(1, 1, 0), (-1, -1, 0), (st, 0, 1), (-st, 0, -1)];
        let diagonals: [(isize, i64, i64, isize, isize); 4] = [
            (st + 1, 1, 1, 1, st),
            (st - 1, -1, 1, -1, st),
            (-st + 1, 1, -1, 1, -st),
            (-st - 1, -1, -1, -1, -st),
        ];
        // Padded coordinates throughout: differences are what matter.
        let (gx, gy) = (i64::from(goal.x) + 1, i64::from(goal.y) + 1);
        let heuristic = |x: i64, y: i64| -> f64 {
            let dx = (x - gx).unsigned_abs() as f64;
            let dy = (y - gy).unsigned_abs() as f64;
            s * (dx + dy + (std::f64::consts::SQRT_2 - 2.0) * dx.min(dy))
        };

        self.nodes[si] = Node {
            g_m: 0.0,
            parent: si as u32,
            stamp: open_tag,
        };
        self.heap.push(Open {
            f_bits: heuristic(i64::from(start.x) + 1, i64::from(start.y) + 1).to_bits(),
            g_bits: 0f64.to_bits(),
            idx: si as u32,
        });
        let max_expansions = limits.max_expansions.unwrap_or(usize::MAX);
        let mut expansions = 0usize;

        // Offers neighbour `n` at (nx, ny) the cost `g_new` via `from`. Blocked cells cost
        // infinity and never win.
        macro_rules! relax {
            ($n:expr, $nx:expr, $ny:expr, $from:expr, $g_new:expr) => {{
                let (n, g_new) = ($n, $g_new);
                let node = &mut self.nodes[n];
                let fresh = node.stamp != open_tag && node.stamp != closed_tag;
                if g_new != f64::INFINITY && (fresh || (node.stamp == open_tag && g_new < node.g_m))
                {
                    *node = Node {
                        g_m: g_new,
                        parent: $from as u32,
                        stamp: open_tag,
                    };
                    self.heap.push(Open {
                        f_bits: (g_new + heuristic($nx, $ny)).to_bits(),
                        g_bits: g_new.to_bits(),
                        idx: n as u32,
                    });
                }
            }};
        }

        while let Some(Open { idx, g_bits, .. }) = self.heap.pop() {
            let i = idx as usize;
            let node = self.nodes[i];
            if node.stamp == closed_tag || f64::from_bits(g_bits) > node.g_m {
                continue; // stale entry: the cell was reached more cheaply later
            }
            if i == gi {
                return Ok(self.trace(grid, si, gi, expansions));
            }
            self.nodes[i].stamp = closed_tag;
            expansions += 1;
            if expansions > max_expansions {
                return Err(PlanError::BudgetExceeded { max_expansions });
            }
            if expansions.is_multiple_of(CANCEL_POLL) && cancel() {
                return Err(PlanError::Cancelled { expansions });
            }
            let g_i = node.g_m;
            let (x, y) = ((i % stride) as i64, (i / stride) as i64);
            let ii = i as isize;
            for &(o, dx, dy) in &ortho {
                let n = (ii + o) as usize;
                relax!(n, x + dx, y + dy, i, g_i + s + f64::from(pen[n]));
            }
            for &(o, dx, dy, a, b) in &diagonals {
                // No corner cutting: both cells beside the diagonal must be enterable.
                if pen[(ii + a) as usize] == BLOCKED || pen[(ii + b) as usize] == BLOCKED {
                    continue;
                }
                let n = (ii + o) as usize;
                relax!(n, x + dx, y + dy, i, g_i + diag + f64::from(pen[n]));
            }
        }
        Err(PlanError::NoPath { expansions })
    }

    /// Grows the buffers to `n` cells and starts a new generation.
    fn prepare(&mut self, n: usize) {
        if self.nodes.len() < n {
            self.nodes.resize(n, Node::default());
        }
        self.heap.clear();
        self.generation += 1;
        if self.generation >= 1 << 31 {
            // Tags are `generation << 1`: after 2^31 searches start from a clean slate once.
            self.nodes.iter_mut().for_each(|v| v.stamp = 0);
            self.generation = 1;
        }
    }

    fn trace(&self, grid: &PlanGrid, si: usize, gi: usize, expansions: usize) -> GridPath {
        let mut cells = Vec::new();
        let mut i = gi;
        loop {
            cells.push(grid.cell_of_index(i));
            if i == si {
                break;
            }
            i = self.nodes[i].parent as usize;
        }
        cells.reverse();
        let s = grid.cell_size_m();
        let length_m = cells
            .windows(2)
            .map(|w| {
                if w[0].x != w[1].x && w[0].y != w[1].y {
                    s * std::f64::consts::SQRT_2
                } else {
                    s
                }
            })
            .sum();
        GridPath {
            cells,
            cost_m: self.nodes[gi].g_m,
            length_m,
            expansions,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_from(rows: &[&str]) -> PlanGrid {
        // rows[0] is the top (northmost) row, as drawn.
        let h = rows.len() as u32;
        let w = rows[0].len() as u32;
        let mut g = PlanGrid::new(w, h, 1.0, (0.0, 0.0));
        for (r, line) in rows.iter().enumerate() {
            for (x, ch) in line.chars().enumerate() {
                let y = i64::from(h) - 1 - r as i64;
                match ch {
                    '#' => g.set_blocked(x as i64, y),
                    '5' => g.set(x as i64, y, 5.0, false),
                    _ => {}
                }
            }
        }
        g
    }

    #[test]
    fn straight_and_diagonal_lengths() {
        let g = PlanGrid::new(20, 20, 0.5, (0.0, 0.0));
        let mut p = Planner::new();
        let path = p.plan(&g, CellXY::new(0, 0), CellXY::new(10, 0)).unwrap();
        assert!((path.length_m - 5.0).abs() < 1e-12);
        let path = p.plan(&g, CellXY::new(0, 0), CellXY::new(10, 4)).unwrap();
        let want = 0.5 * (6.0 + 4.0 * std::f64::consts::SQRT_2);
        assert!((path.cost_m - want).abs() < 1e-12, "{}", path.cost_m);
        assert_eq!(path.cells.first(), Some(&CellXY::new(0, 0)));
        assert_eq!(path.cells.last(), Some(&CellXY::new(10, 4)));
    }

    #[test]
    fn no_corner_cutting() {
        // The only gap is a diagonal squeeze between two blocked cells: forbidden.
        let g = grid_from(&["..#", ".#.", "..."]);
        let mut p = Planner::new();
        // From top-left (0,2) to right-middle (2,1): around the bottom, not through the corner.
        let path = p.plan(&g, CellXY::new(0, 2), CellXY::new(2, 1)).unwrap();
        for w in path.cells.windows(2) {
            let (a, b) = (w[0], w[1]);
            if a.x != b.x && a.y != b.y {
                assert!(
                    g.is_free(i64::from(b.x), i64::from(a.y))
                        && g.is_free(i64::from(a.x), i64::from(b.y))
                );
            }
        }
        // Every diagonal touches the blocked centre, so only straight steps remain: 5 of them.
        assert!((path.length_m - 5.0).abs() < 1e-12, "{}", path.length_m);
        // A fully closed diagonal squeeze means no path.
        let g = grid_from(&[".#", "#."]);
        assert!(matches!(
            p.plan(&g, CellXY::new(0, 1), CellXY::new(1, 0)),
            Err(PlanError::NoPath { .. })
        ));
    }

    #[test]
    fn penalties_bend_the_path() {
        let g = grid_from(&[".....", ".555.", "....."]);
        let mut p = Planner::new();
        let path = p.plan(&g, CellXY::new(0, 1), CellXY::new(4, 1)).unwrap();
        assert!(path
            .cells
            .iter()
            .all(|c| !(c.y == 1 && (1..=3).contains(&c.x))));
        assert!((path.cost_m - path.length_m).abs() < 1e-12);
    }

    #[test]
    fn typed_errors() {
        let g = grid_from(&["#..", "...", "..#"]);
        let mut p = Planner::new();
        assert_eq!(
            p.plan(&g, CellXY::new(0, 2), CellXY::new(1, 1)),
            Err(PlanError::StartBlocked(CellXY::new(0, 2)))
        );
        assert_eq!(
            p.plan(&g, CellXY::new(1, 1), CellXY::new(2, 0)),
            Err(PlanError::GoalBlocked(CellXY::new(2, 0)))
        );
        assert!(matches!(
            p.plan(&g, CellXY::new(3, 1), CellXY::new(1, 1)),
            Err(PlanError::OutOfBounds { .. })
        ));
        let big = PlanGrid::new(100, 100, 1.0, (0.0, 0.0));
        let limited = p.plan_with(
            &big,
            CellXY::new(0, 0),
            CellXY::new(99, 99),
            SearchLimits {
                max_expansions: Some(10),
            },
            &mut || false,
        );
        assert_eq!(
            limited,
            Err(PlanError::BudgetExceeded { max_expansions: 10 })
        );
        let mut walled = big.clone();
        for y in 0..100 {
            walled.set_blocked(50, y);
        }
        let cancelled = p.plan_with(
            &walled,
            CellXY::new(0, 0),
            CellXY::new(99, 99),
            SearchLimits::default(),
            &mut || true,
        );
        assert!(matches!(cancelled, Err(PlanError::Cancelled { .. })));
        assert!(matches!(
            p.plan(&walled, CellXY::new(0, 0), CellXY::new(99, 99)),
            Err(PlanError::NoPath { .. })
        ));
        // Buffers are reused: a later search on a smaller grid still works.
        let small = PlanGrid::new(3, 3, 1.0, (0.0, 0.0));
        assert!(p.plan(&small, CellXY::new(0, 0), CellXY::new(2, 2)).is_ok());
    }

    #[test]
    fn deterministic_and_matches_dijkstra() {
        // Pseudo-random obstacles; compare with a plain Dijkstra over the same rules.
        let (w, h) = (40u32, 30u32);
        let mut g = PlanGrid::new(w, h, 0.2, (0.0, 0.0));
        let mut state = 12345u64;
        for y in 0..h {
            for x in 0..w {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let r = (state >> 33) % 100;
                if r < 25 {
                    g.set_blocked(i64::from(x), i64::from(y));
                } else if r < 40 {
                    g.set(i64::from(x), i64::from(y), (r as f32) * 0.01, false);
                }
            }
        }
        g.set(0, 0, 0.0, false);
        g.set(39, 29, 0.0, false);
        let mut p = Planner::new();
        let a = p.plan(&g, CellXY::new(0, 0), CellXY::new(39, 29));
        let b = p.plan(&g, CellXY::new(0, 0), CellXY::new(39, 29));
        assert_eq!(a, b);
        let want = dijkstra(&g, (0, 0), (39, 29));
        match (a, want) {
            (Ok(path), Some(d)) => {
                assert!((path.cost_m - d).abs() < 1e-9, "{} vs {d}", path.cost_m)
            }
            (Err(PlanError::NoPath { .. }), None) => {}
            (a, d) => panic!("A* {a:?} vs Dijkstra {d:?}"),
        }
    }

    fn dijkstra(g: &PlanGrid, s: (i64, i64), t: (i64, i64)) -> Option<f64> {
        let (w, h) = (i64::from(g.width()), i64::from(g.height()));
        let mut dist = vec![f64::INFINITY; (w * h) as usize];
        let mut done = vec![false; (w * h) as usize];
        dist[(s.1 * w + s.0) as usize] = 0.0;
        loop {
            let mut best = None;
            for i in 0..dist.len() {
                if !done[i] && dist[i].is_finite() && best.is_none_or(|b: usize| dist[i] < dist[b])
                {
                    best = Some(i);
                }
            }
            let i = best?;
            done[i] = true;
            let (x, y) = (i as i64 % w, i as i64 / w);
            if (x, y) == t {
                return Some(dist[i]);
            }
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let (nx, ny) = (x + dx, y + dy);
                    if (dx == 0 && dy == 0) || !g.is_free(nx, ny) {
                        continue;
                    }
                    if dx != 0 && dy != 0 && (!g.is_free(x + dx, y) || !g.is_free(x, y + dy)) {
                        continue;
                    }
                    let step = if dx != 0 && dy != 0 {
                        std::f64::consts::SQRT_2
                    } else {
                        1.0
                    } * g.cell_size_m();
                    let nd = dist[i] + step + f64::from(g.penalty_m(nx, ny));
                    let j = (ny * w + nx) as usize;
                    if nd < dist[j] {
                        dist[j] = nd;
                    }
                }
            }
        }
    }
}

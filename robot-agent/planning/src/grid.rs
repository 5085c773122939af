//! The planner's view of the traversability grid.
//!
//! A [`PlanGrid`] is a rectangular window of `width` x `height` cells on the fixed map-frame
//! lattice (by default 300 x 300 cells of 0.2 m around the robot, docs/algorithms.md §5.1). Each
//! cell holds one step penalty in metres: the cost added when a path *enters* the cell, or
//! [`BLOCKED`] when it may not be entered; and an "unknown" flag (never observed), which the
//! reachability floods need to find frontiers.
//!
//! Cell (x, y) covers `[ox + x s, ox + (x+1) s) x [oy + y s, oy + (y+1) s)` in the map frame, where
//! `(ox, oy)` is the window origin and `s` the cell size; row 0 is the southmost row, as in
//! `common::grid::Tile`.
//!
//! Internally the arrays carry a one-cell blocked border so that the search can look at all 8
//! neighbours of any inner cell without a bounds check.

use common::grid::{Cell, CellState, Lattice, Tile};
use serde::{Deserialize, Serialize};

use crate::PlannerConfig;

/// Step penalty of a cell that may not be entered.
pub const BLOCKED: f32 = f32::INFINITY;

/// A cell of a [`PlanGrid`], by column and row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct CellXY {
    /// Column, 0 = westmost.
    pub x: u32,
    /// Row, 0 = southmost.
    pub y: u32,
}

impl CellXY {
    /// A cell from its column and row.
    pub const fn new(x: u32, y: u32) -> Self {
        Self { x, y }
    }
}

/// The planning window: a rectangular block of lattice cells.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridWindow {
    /// The lattice the window lives on.
    pub lattice: Lattice,
    /// Global lattice column of the window's cell (0, 0).
    pub min_cx: i64,
    /// Global lattice row of the window's cell (0, 0).
    pub min_cy: i64,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl GridWindow {
    /// A `cells` x `cells` window on `lattice` whose centre cell holds map point (x_m, y_m).
    pub fn centred(lattice: Lattice, x_m: f64, y_m: f64, cells: u32) -> Self {
        let (cx, cy) = lattice.cell_of(x_m, y_m);
        let half = i64::from(cells / 2);
        Self {
            lattice,
            min_cx: cx - half,
            min_cy: cy - half,
            width: cells,
            height: cells,
        }
    }

    /// The window the planner config asks for (`num_of_grid_cells`, `grid_size_m`) around a point.
    pub fn from_config(cfg: &PlannerConfig, x_m: f64, y_m: f64) -> Self {
        let lattice = Lattice {
            cell_size_m: cfg.grid_size_m as f32,
            ..Lattice::default()
        };
        Self::centred(lattice, x_m, y_m, cfg.num_of_grid_cells)
    }
}

/// How lattice cells become step penalties.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CostRule {
    /// Penalty per unit of `Cell::cost` (0..=255), metres per cell entered.
    pub penalty_per_cost_m: f64,
    /// Whether never-observed cells may be entered.
    pub unknown_traversable: bool,
    /// Penalty for entering a never-observed cell, metres (when they may be entered).
    pub unknown_penalty_m: f64,
}

impl CostRule {
    /// The rule the planner config asks for.
    pub fn from_config(cfg: &PlannerConfig) -> Self {
        Self {
            penalty_per_cost_m: cfg.penalty_per_cost_m,
            unknown_traversable: cfg.unknown_traversable,
            unknown_penalty_m: cfg.unknown_penalty_m,
        }
    }

    /// The step penalty of one lattice cell and whether it is unknown.
    /// Obstacle and Inflated cells are never entered: inflation is how the robot's body is kept
    /// clear of obstacles, and the planner treats the robot as a point.
    pub fn penalty_of(&self, cell: &Cell) -> (f32, bool) {
        match cell.state {
            CellState::Obstacle | CellState::Inflated => (BLOCKED, false),
            CellState::Traversable => (
                (f64::from(cell.cost) * self.penalty_per_cost_m) as f32,
                false,
            ),
            CellState::Unknown if self.unknown_traversable => (self.unknown_penalty_m as f32, true),
            CellState::Unknown => (BLOCKED, true),
        }
    }
}

impl Default for CostRule {
    fn default() -> Self {
        Self::from_config(&PlannerConfig::default())
    }
}

/// The planner's grid: per-cell step penalties and unknown flags, with the window's geometry.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanGrid {
    width: u32,
    height: u32,
    cell_size_m: f64,
    origin_m: (f64, f64),
    /// `(width + 2) * (height + 2)` penalties, row-major, with a blocked border.
    penalty_m: Vec<f32>,
    /// Same layout: never observed.
    unknown: Vec<bool>,
}

impl PlanGrid {
    /// An all-free grid (zero penalty, known) of `width` x `height` cells of `cell_size_m`, cell
    /// (0, 0) having its lower-left corner at `origin_m` in the map frame.
    pub fn new(width: u32, height: u32, cell_size_m: f64, origin_m: (f64, f64)) -> Self {
        let n = (width as usize + 2) * (height as usize + 2);
        let mut g = Self {
            width,
            height,
            cell_size_m,
            origin_m,
            penalty_m: vec![0.0; n],
            unknown: vec![false; n],
        };
        let stride = g.stride();
        for y in 0..height as usize + 2 {
            for x in 0..stride {
                if y == 0 || x == 0 || y == height as usize + 1 || x == width as usize + 1 {
                    g.penalty_m[y * stride + x] = BLOCKED;
                }
            }
        }
        g
    }

    /// A grid over `window` filled by `cell_at(global_cx, global_cy)` through `rule`.
    pub fn from_cells(
        window: &GridWindow,
        rule: &CostRule,
        mut cell_at: impl FnMut(i64, i64) -> Cell,
    ) -> Self {
        let s = window.lattice.cell_size_f64();
        let origin = (window.min_cx as f64 * s, window.min_cy as f64 * s);
        let mut g = Self::new(window.width, window.height, s, origin);
        for y in 0..window.height {
            for x in 0..window.width {
                let cell = cell_at(window.min_cx + i64::from(x), window.min_cy + i64::from(y));
                g.fill(CellXY::new(x, y), rule, &cell);
            }
        }
        g
    }

    /// Sets the in-grid cell `c` from a lattice cell through `rule` (its penalty and unknown
    /// flag as they are, no clamping: `rule` gives no negative penalty).
    fn fill(&mut self, c: CellXY, rule: &CostRule, cell: &Cell) {
        let (p, u) = rule.penalty_of(cell);
        let i = self.index(c);
        self.penalty_m[i] = p;
        self.unknown[i] = u;
    }

    /// A grid over `window` in which only the cells a check of the polyline `path` reads (the
    /// samples of [`crate::smooth::segment_free`] on each of its segments) are filled by
    /// `cell_at(global_cx, global_cy)` through `rule`; every other cell is free. The safety
    /// stage checks the path ahead after every sweep: a few hundred cells, where the whole
    /// window is 90 000.
    pub fn along_path(
        window: &GridWindow,
        rule: &CostRule,
        path: &[(f64, f64)],
        mut cell_at: impl FnMut(i64, i64) -> Cell,
    ) -> Self {
        let s = window.lattice.cell_size_f64();
        let origin = (window.min_cx as f64 * s, window.min_cy as f64 * s);
        let mut g = Self::new(window.width, window.height, s, origin);
        let mut last = None;
        for w in path.windows(2) {
            for p in crate::smooth::segment_samples(s, w[0], w[1]) {
                let (x, y) = g.world_to_cell_unbounded(p.0, p.1);
                if last == Some((x, y)) || !g.contains(x, y) {
                    continue;
                }
                last = Some((x, y));
                let cell = cell_at(window.min_cx + x, window.min_cy + y);
                g.fill(CellXY::new(x as u32, y as u32), rule, &cell);
            }
        }
        g
    }

    /// A grid over `window` filled from lattice tiles; cells of absent tiles are unknown.
    /// Tiles on another lattice than the window's are ignored.
    pub fn from_tiles<'a>(
        window: &GridWindow,
        rule: &CostRule,
        tiles: impl IntoIterator<Item = &'a Tile>,
    ) -> Self {
        let mut g = Self::from_cells(window, rule, |_, _| Cell::UNKNOWN);
        let n = i64::from(window.lattice.tile_cells);
        for tile in tiles {
            if tile.lattice != window.lattice || tile.cells.len() != (n * n) as usize {
                continue;
            }
            let (tx0, ty0) = window.lattice.tile_first_cell(tile.index);
            for row in 0..n {
                let wy = ty0 + row - window.min_cy;
                if wy < 0 || wy >= i64::from(window.height) {
                    continue;
                }
                for col in 0..n {
                    let wx = tx0 + col - window.min_cx;
                    if wx < 0 || wx >= i64::from(window.width) {
                        continue;
                    }
                    let cell = &tile.cells[(row * n + col) as usize];
                    g.fill(CellXY::new(wx as u32, wy as u32), rule, cell);
                }
            }
        }
        g
    }

    /// Cells per row.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Cell edge, metres.
    pub fn cell_size_m(&self) -> f64 {
        self.cell_size_m
    }

    /// Map-frame position of the lower-left corner of cell (0, 0), metres.
    pub fn origin_m(&self) -> (f64, f64) {
        self.origin_m
    }

    /// Whether (x, y) is a cell of the grid.
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= 0 && y >= 0 && x < i64::from(self.width) && y < i64::from(self.height)
    }

    /// The cell holding map point (x_m, y_m), or None outside the window.
    pub fn world_to_cell(&self, x_m: f64, y_m: f64) -> Option<CellXY> {
        let (x, y) = self.world_to_cell_unbounded(x_m, y_m);
        self.contains(x, y).then(|| CellXY::new(x as u32, y as u32))
    }

    /// The (possibly out-of-window) cell index holding map point (x_m, y_m).
    pub fn world_to_cell_unbounded(&self, x_m: f64, y_m: f64) -> (i64, i64) {
        (
            ((x_m - self.origin_m.0) / self.cell_size_m).floor() as i64,
            ((y_m - self.origin_m.1) / self.cell_size_m).floor() as i64,
        )
    }

    /// Map-frame centre of a cell, metres.
    pub fn cell_center_m(&self, c: CellXY) -> (f64, f64) {
        (
            self.origin_m.0 + (f64::from(c.x) + 0.5) * self.cell_size_m,
            self.origin_m.1 + (f64::from(c.y) + 0.5) * self.cell_size_m,
        )
    }

    /// Step penalty of a cell, metres ([`BLOCKED`] if it may not be entered).
    /// Cells outside the grid read as blocked.
    pub fn penalty_m(&self, x: i64, y: i64) -> f32 {
        if self.contains(x, y) {
            self.penalty_m[self.index(CellXY::new(x as u32, y as u32))]
        } else {
            BLOCKED
        }
    }

    /// Whether a path may enter the cell (false outside the grid).
    pub fn is_free(&self, x: i64, y: i64) -> bool {
        self.penalty_m(x, y) != BLOCKED
    }

    /// Whether the cell was never observed (false outside the grid).
    pub fn is_unknown(&self, x: i64, y: i64) -> bool {
        self.contains(x, y) && self.unknown[self.index(CellXY::new(x as u32, y as u32))]
    }

    /// Sets one cell; out-of-grid cells are ignored. Negative or NaN penalties become 0 so that
    /// the octile heuristic stays admissible.
    pub fn set(&mut self, x: i64, y: i64, penalty_m: f32, unknown: bool) {
        if self.contains(x, y) {
            let i = self.index(CellXY::new(x as u32, y as u32));
            self.penalty_m[i] = if penalty_m >= 0.0 { penalty_m } else { 0.0 };
            self.unknown[i] = unknown;
        }
    }

    /// Marks a cell as not enterable (known).
    pub fn set_blocked(&mut self, x: i64, y: i64) {
        self.set(x, y, BLOCKED, false);
    }

    /// Row stride of the padded arrays.
    #[inline]
    pub(crate) fn stride(&self) -> usize {
        self.width as usize + 2
    }

    /// Padded index of an in-grid cell.
    #[inline]
    pub(crate) fn index(&self, c: CellXY) -> usize {
        (c.y as usize + 1) * self.stride() + c.x as usize + 1
    }

    /// The cell at a padded index (must be an inner index).
    #[inline]
    pub(crate) fn cell_of_index(&self, i: usize) -> CellXY {
        let s = self.stride();
        CellXY::new((i % s - 1) as u32, (i / s - 1) as u32)
    }

    /// The padded penalty array.
    #[inline]
    pub(crate) fn penalties(&self) -> &[f32] {
        &self.penalty_m
    }

    /// The padded unknown flags.
    #[inline]
    pub(crate) fn unknown_flags(&self) -> &[bool] {
        &self.unknown
    }

    /// Number of entries of the padded arrays.
    #[inline]
    pub(crate) fn padded_len(&self) -> usize {
        self.penalty_m.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::grid::TileIndex;

    #[test]
    fn world_cell_round_trip() {
        let g = PlanGrid::new(10, 8, 0.2, (-1.0, 2.0));
        let c = g.world_to_cell(-0.95, 2.01).unwrap();
        assert_eq!(c, CellXY::new(0, 0));
        let (x, y) = g.cell_center_m(CellXY::new(3, 7));
        assert!((x - (-1.0 + 0.7)).abs() < 1e-12 && (y - (2.0 + 1.5)).abs() < 1e-12);
        assert_eq!(g.world_to_cell(x, y), Some(CellXY::new(3, 7)));
        assert_eq!(g.world_to_cell(-1.01, 2.5), None);
        assert_eq!(
            g.world_to_cell(1.0, 2.5),
            None,
            "x = origin + width * s is outside"
        );
        assert!(!g.is_free(-1, 0) && !g.is_free(10, 0) && g.is_free(9, 7));
    }

    #[test]
    fn states_map_to_penalties() {
        let rule = CostRule {
            penalty_per_cost_m: 0.01,
            unknown_traversable: false,
            unknown_penalty_m: 0.5,
        };
        let cell = |state, cost| Cell {
            state,
            cost,
            ..Cell::UNKNOWN
        };
        assert_eq!(rule.penalty_of(&cell(CellState::Obstacle, 0)).0, BLOCKED);
        assert_eq!(rule.penalty_of(&cell(CellState::Inflated, 0)).0, BLOCKED);
        assert_eq!(
            rule.penalty_of(&cell(CellState::Unknown, 0)),
            (BLOCKED, true)
        );
        let (p, u) = rule.penalty_of(&cell(CellState::Traversable, 100));
        assert!((p - 1.0).abs() < 1e-6 && !u);
        let open = CostRule {
            unknown_traversable: true,
            ..rule
        };
        assert_eq!(open.penalty_of(&cell(CellState::Unknown, 0)), (0.5, true));
    }

    #[test]
    fn tiles_fill_the_window() {
        let lattice = Lattice {
            cell_size_m: 0.2,
            tile_cells: 4,
        };
        let mut tile = Tile::new(TileIndex { tx: 0, ty: 0 }, lattice);
        for c in tile.cells.iter_mut() {
            c.state = CellState::Traversable;
        }
        tile.get_mut(1, 2).state = CellState::Obstacle;
        // Window of 6 x 6 cells starting at global cell (-1, -1): tile (0,0) covers window 1..5.
        let window = GridWindow {
            lattice,
            min_cx: -1,
            min_cy: -1,
            width: 6,
            height: 6,
        };
        let g = PlanGrid::from_tiles(&window, &CostRule::default(), [&tile]);
        assert!(g.is_unknown(0, 0));
        assert!(!g.is_unknown(1, 1) && g.is_free(1, 1));
        assert!(!g.is_free(2, 3), "tile cell (1, 2) is window cell (2, 3)");
        assert!(g.is_unknown(5, 5));
        assert!((g.origin_m().0 + 0.2).abs() < 1e-12);
    }

    proptest::proptest! {
        /// The path check reads only the cells along the path, so a grid filled only there must
        /// answer every segment of it as the whole window does: paths through cluttered
        /// windows, leaving them, and with segments ending exactly on cell boundaries.
        #[test]
        fn a_grid_along_a_path_checks_it_as_the_whole_window_does(
            seed in 0u64..u64::MAX,
            pts in proptest::collection::vec((-40i32..40, -40i32..40), 2..8),
        ) {
            let window = GridWindow::centred(Lattice::default(), 0.3, -0.1, 60);
            let state = |cx: i64, cy: i64| {
                let h = (cx.wrapping_mul(73_856_093) ^ cy.wrapping_mul(19_349_663)) as u64 ^ seed;
                match h.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 61 {
                    0 => CellState::Obstacle,
                    1 => CellState::Unknown,
                    _ => CellState::Traversable,
                }
            };
            let cell = |cx, cy| Cell { state: state(cx, cy), ..Cell::UNKNOWN };
            let rule = CostRule::default();
            // Tenths of a metre: half of the points land on cell edges.
            let path: Vec<(f64, f64)> =
                pts.iter().map(|&(x, y)| (f64::from(x) * 0.1, f64::from(y) * 0.1)).collect();
            let whole = PlanGrid::from_cells(&window, &rule, cell);
            let along = PlanGrid::along_path(&window, &rule, &path, cell);
            for w in path.windows(2) {
                proptest::prop_assert_eq!(
                    crate::smooth::segment_free(&whole, w[0], w[1]),
                    crate::smooth::segment_free(&along, w[0], w[1])
                );
            }
        }
    }

    #[test]
    fn centred_window_holds_the_point_in_its_middle() {
        let w = GridWindow::centred(Lattice::default(), 10.05, -3.3, 300);
        let g = PlanGrid::from_cells(&w, &CostRule::default(), |_, _| Cell::UNKNOWN);
        assert_eq!(g.world_to_cell(10.05, -3.3), Some(CellXY::new(150, 150)));
    }
}

//! The public reads of the output cells: every tile, one tile, and windows of final cells (the
//! planner's view).

use super::Mapper;
use common::grid::{Cell, Lattice, Tile, TileIndex};

/// The planner's view: a window of final cells around the robot, row-major, row 0 southmost.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannerView {
    /// The lattice.
    pub lattice: Lattice,
    /// Global lattice column of the window's cell (0, 0).
    pub min_cx: i64,
    /// Global lattice row of the window's cell (0, 0).
    pub min_cy: i64,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width * height` cells (state, cost, height, evidence).
    pub cells: Vec<Cell>,
}

impl PlannerView {
    /// The cell at a global lattice index; unknown outside the window.
    pub fn get(&self, cx: i64, cy: i64) -> Cell {
        let (x, y) = (cx - self.min_cx, cy - self.min_cy);
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return Cell::UNKNOWN;
        }
        self.cells[y as usize * self.width as usize + x as usize]
    }
}

impl Mapper {
    /// The current content of every tile held, sorted (version 0: versions count publications,
    /// which the publisher does).
    pub fn tiles(&self) -> Vec<Tile> {
        let mut v: Vec<Tile> = self
            .slots
            .iter()
            .map(|s| Tile {
                index: s.index,
                lattice: self.lattice,
                version: 0,
                cells: s.live.clone(),
            })
            .collect();
        v.sort_by_key(|t| t.index);
        v
    }

    /// Tiles held.
    pub fn tile_count(&self) -> usize {
        self.slots.len()
    }

    /// The current output cells of one tile (row-major, row 0 southmost), if the tile is held.
    pub fn tile_cells(&self, index: TileIndex) -> Option<&[Cell]> {
        self.slot(index).map(|s| self.slots[s].live.as_slice())
    }

    /// The planner's window (`num_of_grid_cells` square) centred on the last robot pose.
    pub fn planner_view(&self) -> PlannerView {
        let w = self.cfg.num_of_grid_cells;
        let r = self.robot.unwrap_or_default();
        let (cx, cy) = self.lattice.cell_of(r.x_m, r.y_m);
        self.view(cx - i64::from(w / 2), cy - i64::from(w / 2), w, w)
    }

    /// Any window of final cells.
    pub fn view(&self, min_cx: i64, min_cy: i64, width: u32, height: u32) -> PlannerView {
        let mut cells = Vec::with_capacity(width as usize * height as usize);
        let n = i64::from(self.lattice.tile_cells);
        let max_cx = min_cx + i64::from(width);
        for y in 0..i64::from(height) {
            // Each row is copied in runs, one per tile it crosses: a window is read for every
            // plan and every sweep's grids, ~90 000 cells, and a lookup per cell cost more
            // than the copy.
            let cy = min_cy + y;
            let mut cx = min_cx;
            while cx < max_cx {
                let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
                let run = (n - i64::from(c)).min(max_cx - cx) as usize;
                match self.slot(t) {
                    Some(s) => {
                        let k = r as usize * n as usize + c as usize;
                        cells.extend_from_slice(&self.slots[s].live[k..k + run]);
                    }
                    None => cells.extend(std::iter::repeat_n(Cell::UNKNOWN, run)),
                }
                cx += run as i64;
            }
        }
        PlannerView {
            lattice: self.lattice,
            min_cx,
            min_cy,
            width,
            height,
            cells,
        }
    }

    /// Global cell index bounds (min, max inclusive) of all tiles held, if any.
    pub fn bounds(&self) -> Option<((i64, i64), (i64, i64))> {
        let n = i64::from(self.lattice.tile_cells);
        let mut it = self
            .slots
            .iter()
            .map(|s| self.lattice.tile_first_cell(s.index));
        let first = it.next()?;
        let (mut lo, mut hi) = (first, first);
        for (x, y) in it {
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        Some((lo, (hi.0 + n - 1, hi.1 + n - 1)))
    }
}

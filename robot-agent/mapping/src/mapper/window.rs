//! Scratch arrays over a square window of cells around the robot, reused between updates: the
//! sweep's binned points and ceilings, its free space, de-duplication marks and the rules' stats
//! cache. Flat arrays indexed by window cell, so the per-point and per-beam loops never hash.

use super::cell_data::Moments;
use super::free_space::Pass;
use crate::classify::CellStats;

/// See the module docs. The window is centred on the robot's cell (`cx0`, `cy0`) each update.
pub(super) struct Window {
    pub(super) half: i64,
    pub(super) side: usize,
    pub(super) cx0: i64,
    pub(super) cy0: i64,
    /// The sweep's lowest return per cell.
    pub(super) zmin: Vec<f32>,
    /// The ceiling `h_max2` per cell.
    pub(super) ceiling: Vec<f32>,
    /// The sweep's points per cell: near the ground, and high enough to wait for a second scan.
    pub(super) low: Vec<Moments>,
    pub(super) high: Vec<Moments>,
    /// Cells holding points of this sweep.
    pub(super) touched: Vec<usize>,
    pub(super) mark: Vec<u32>,
    pub(super) generation: u32,
    /// Free space of this sweep per cell, all a beam step needs in one place.
    pub(super) pass: Vec<Pass>,
    /// Stored ground per cell for the ceilings (NaN: not looked up; reset after each use).
    pub(super) stored_ground: Vec<f32>,
    pub(super) pass_touched: Vec<usize>,
    /// Per-cell stats as the rules see them, cached during `reclassify` (generation, stats).
    pub(super) stats: Vec<std::cell::Cell<(u32, CellStats)>>,
    pub(super) stats_generation: u32,
    /// Whether `stats` may be used: only while evidence stands still.
    pub(super) stats_on: bool,
}

impl Window {
    /// A window reaching `half` cells either side of its centre.
    pub(super) fn new(half: i64) -> Self {
        let side = (2 * half + 1) as usize;
        let n = side * side;
        Self {
            half,
            side,
            cx0: 0,
            cy0: 0,
            zmin: vec![f32::INFINITY; n],
            ceiling: vec![f32::INFINITY; n],
            low: vec![Moments::default(); n],
            high: vec![Moments::default(); n],
            touched: Vec::new(),
            mark: vec![0; n],
            generation: 0,
            pass: vec![Pass::default(); n],
            stored_ground: vec![f32::NAN; n],
            pass_touched: Vec::new(),
            stats: vec![std::cell::Cell::new((0, CellStats::default())); n],
            stats_generation: 0,
            stats_on: false,
        }
    }

    /// The window index of a global cell, if inside.
    #[inline]
    pub(super) fn local(&self, cx: i64, cy: i64) -> Option<usize> {
        let (x, y) = (cx - self.cx0 + self.half, cy - self.cy0 + self.half);
        (x >= 0 && y >= 0 && (x as usize) < self.side && (y as usize) < self.side)
            .then(|| y as usize * self.side + x as usize)
    }

    /// The global cell of a window index.
    #[inline]
    pub(super) fn global(&self, i: usize) -> (i64, i64) {
        (
            (i % self.side) as i64 - self.half + self.cx0,
            (i / self.side) as i64 - self.half + self.cy0,
        )
    }

    /// Resets what the last sweep wrote (only the cells it touched).
    pub(super) fn clear(&mut self) {
        for &i in &self.touched {
            self.zmin[i] = f32::INFINITY;
            self.ceiling[i] = f32::INFINITY;
            self.low[i] = Moments::default();
            self.high[i] = Moments::default();
        }
        self.touched.clear();
        for &i in &self.pass_touched {
            self.pass[i] = Pass::default();
        }
        self.pass_touched.clear();
    }

    /// Starts using the stats cache afresh (evidence will stand still until `end_stats`).
    pub(super) fn begin_stats(&mut self) {
        self.stats_generation = self.stats_generation.wrapping_add(1);
        if self.stats_generation == 0 {
            self.stats
                .iter_mut()
                .for_each(|c| *c.get_mut() = (0, CellStats::default()));
            self.stats_generation = 1;
        }
        self.stats_on = true;
    }

    /// Evidence may change again: the stats cache is off.
    pub(super) fn end_stats(&mut self) {
        self.stats_on = false;
    }

    /// Starts a new de-duplication generation for `mark`.
    pub(super) fn next_generation(&mut self) -> u32 {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.generation = 1;
        }
        self.generation
    }
}

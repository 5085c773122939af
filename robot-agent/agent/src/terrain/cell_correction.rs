//! What a pose-graph correction does to the live map's cells (docs/algorithms.md §3.7): which
//! of them a rebuild must replace, and how far the others' heights move.
//!
//! A rebuilt map is made from one kept sweep every `map_rebuild_spacing_m`, not from all of
//! them, and renders obstacles less well than the live map where nothing moved. So a cell of a
//! stale tile is replaced only when the correction moved its evidence: when it lies within
//! `grow` cells of a kept return (at the pose the live map has it, or at its corrected one)
//! that moves horizontally by more than the tolerance, or of a cell whose returns move
//! vertically by amounts more than the tolerance apart (sweeps set against each other in
//! height). The tolerance is `map_rebuild_min_move_m` or a cell, the larger: a return moved by
//! less than a cell stays in its cell or the next, and on `loop` the thinned rebuild's
//! rendering cost more than that (with half a cell the second swap put trees 0.2-0.5 m off).
//! Inside that mask (grown by `grow` cells, the neighbourhoods the step rule and the costs
//! read) a cell is the rebuilt map's only where a kept return moved by more than the tolerance
//! left or reached it, or its returns moved apart vertically by more than it (or, for a cell no
//! kept return fell in, where that holds within two cells; [`CellCorrection::is_rebuilt`]). Every
//! other cell keeps the live map's evidence (every sweep, not one in six), raised or lowered by
//! the mean vertical move of its returns, so that it meets the rebuilt cells without a step. A
//! cell's returns and its neighbours' come from the same sweeps and move alike, so a kept
//! cell's verdict still agrees with its rebuilt neighbours.
//!
//! The moves are gathered sweep by sweep as the rebuild feeds them ([`CellMoves::add`], a few a
//! tick like the rebuild itself: the whole store at once took 0.65 s in one sweep on `loop`)
//! and settled for the stale tiles at the swap ([`CellMoves::finish`]).

use super::cell_mask::CellMask;
use super::rebuild::Remap;
use common::grid::{Lattice, TileIndex};
use nalgebra::{Isometry3, Point3};
use std::collections::{HashMap, HashSet};

/// The moves of the returns that fell in one cell: vertical, and the largest sideways.
#[derive(Clone, Copy)]
struct DzAcc {
    min: f32,
    max: f32,
    sum: f32,
    n: u32,
    /// Largest sideways move, metres.
    side: f32,
}

impl DzAcc {
    const EMPTY: DzAcc = DzAcc {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
        sum: 0.0,
        n: 0,
        side: 0.0,
    };

    fn add(&mut self, dz: f32, side: f32) {
        self.side = self.side.max(side);
        self.min = self.min.min(dz);
        self.max = self.max.max(dz);
        self.sum += dz;
        self.n += 1;
    }

    /// The mean vertical move (NaN: no return).
    fn mean(&self) -> f32 {
        if self.n == 0 {
            f32::NAN
        } else {
            self.sum / self.n as f32
        }
    }
}

/// The moves of the kept returns fed so far, per cell (see the module docs).
pub struct CellMoves {
    lattice: Lattice,
    /// Sideways move, and spread of one cell's vertical moves, over which cells are rebuilt,
    /// metres.
    tol_m: f64,
    near_m: f32,
    /// Per tile a return fell in, row-major.
    acc: HashMap<TileIndex, Vec<DzAcc>>,
    /// Cells a return moved sideways by more than the tolerance left or reached.
    seeds: HashSet<(i64, i64)>,
}

impl CellMoves {
    /// Nothing gathered yet. `min_move_m`: `map_rebuild_min_move_m`; `near_m`: returns farther
    /// from the sensor are beam directions only (see [`super::rebuild::SweepStore`]) and are
    /// left out.
    pub fn new(lattice: Lattice, min_move_m: f64, near_m: f64) -> Self {
        Self {
            lattice,
            tol_m: min_move_m.max(lattice.cell_size_f64()),
            near_m: near_m as f32,
            acc: HashMap::new(),
            seeds: HashSet::new(),
        }
    }

    /// Gathers how a kept sweep's returns move from where the live map has them to where the
    /// rebuild puts them.
    pub fn add(&mut self, r: &Remap, base_from_lidar: &Isometry3<f64>) {
        let delta = (r.map_from_base * r.live_from_base.inverse()).cast::<f32>();
        let map_from_lidar = (r.live_from_base * base_from_lidar).cast::<f32>();
        let tol2 = (self.tol_m * self.tol_m) as f32;
        let near2 = self.near_m * self.near_m;
        let n = self.lattice.tile_cells as usize;
        // Returns in sweep order are mostly in the tile of the one before.
        let mut last: Option<(TileIndex, usize)> = None;
        let mut last_seed: Option<(i64, i64)> = None;
        let mut tiles: Vec<(TileIndex, Vec<DzAcc>)> = Vec::new();
        for q in &r.points {
            if q[0] * q[0] + q[1] * q[1] + q[2] * q[2] > near2 {
                continue;
            }
            let p = map_from_lidar * Point3::new(q[0], q[1], q[2]);
            let d = delta * p - p;
            let c = self.lattice.cell_of(f64::from(p.x), f64::from(p.y));
            if d.xy().norm_squared() > tol2 {
                let m = p + d;
                // Returns in sweep order mostly fall in the cell of the one before.
                for cell in [c, self.lattice.cell_of(f64::from(m.x), f64::from(m.y))] {
                    if last_seed != Some(cell) {
                        self.seeds.insert(cell);
                        last_seed = Some(cell);
                    }
                }
            }
            let (t, (col, row)) = self.lattice.tile_of_cell(c.0, c.1);
            let i = match last {
                Some((lt, i)) if lt == t => i,
                _ => {
                    let i = match tiles.iter().position(|(x, _)| *x == t) {
                        Some(i) => i,
                        None => {
                            let v = self
                                .acc
                                .remove(&t)
                                .unwrap_or_else(|| vec![DzAcc::EMPTY; n * n]);
                            tiles.push((t, v));
                            tiles.len() - 1
                        }
                    };
                    last = Some((t, i));
                    i
                }
            };
            tiles[i].1[row as usize * n + col as usize].add(d.z, d.xy().norm());
        }
        self.acc.extend(tiles);
    }

    /// The correction for the stale `tiles`: the cells to rebuild, grown by `grow` cells, and
    /// the kept cells' vertical moves. Past `max_cells` cells in the rebuilt cells' bounding
    /// box every cell of `tiles` is rebuilt.
    pub fn finish(
        mut self,
        tiles: &HashSet<TileIndex>,
        grow: i64,
        max_cells: usize,
    ) -> CellCorrection {
        let n = self.lattice.tile_cells as usize;
        let mut dz = HashMap::with_capacity(tiles.len());
        for (t, acc) in self.acc.drain().filter(|(t, _)| tiles.contains(t)) {
            let (cx0, cy0) = self.lattice.tile_first_cell(t);
            for (k, a) in acc.iter().enumerate() {
                if a.n > 0 && f64::from(a.max - a.min) > self.tol_m {
                    self.seeds
                        .insert((cx0 + (k % n) as i64, cy0 + (k / n) as i64));
                }
            }
            let (sum, count) = acc
                .iter()
                .filter(|a| a.n > 0)
                .fold((0.0f64, 0u32), |(s, c), a| (s + f64::from(a.mean()), c + 1));
            let mean = if count == 0 {
                0.0
            } else {
                (sum / f64::from(count)) as f32
            };
            let side_max = acc.iter().map(|a| a.side).fold(0.0, f32::max);
            dz.insert(
                t,
                TileMoves {
                    dz: acc.iter().map(DzAcc::mean).collect(),
                    dz_mean: mean,
                    side_max,
                },
            );
        }
        let list: Vec<(i64, i64)> = self.seeds.iter().copied().collect();
        CellCorrection {
            stale: CellMask::grown(&list, grow, max_cells),
            seeds: self.seeds,
            dz,
            lattice: self.lattice,
            tol_m: self.tol_m,
        }
    }
}

/// What a correction does to the live map's cells ([`CellMoves::finish`]).
pub struct CellCorrection {
    /// The cells within reach of a move (None: every cell of the stale tiles).
    stale: Option<CellMask>,
    /// The cells a return moved sideways by more than the tolerance left or reached, and those
    /// whose returns moved apart vertically by more than it.
    seeds: HashSet<(i64, i64)>,
    /// Per stale tile, the moves of its cells' kept returns.
    dz: HashMap<TileIndex, TileMoves>,
    lattice: Lattice,
    /// A cell whose returns moved by more than this is the rebuilt map's, metres.
    tol_m: f64,
}

/// The moves of one stale tile's kept returns, per cell row-major, metres (NaN: no return fell
/// in the cell).
struct TileMoves {
    /// Mean vertical move.
    dz: Vec<f32>,
    /// The mean of `dz` over the cells that have one.
    dz_mean: f32,
    /// The largest sideways move of its returns.
    side_max: f32,
}

/// How far a cell without kept returns looks for cells that have some, cells: the step rule's
/// neighbourhood (it is set against those).
const DZ_REACH: i64 = 2;

impl CellCorrection {
    /// The cell is to be rebuilt.
    pub fn is_stale(&self, cx: i64, cy: i64) -> bool {
        self.stale.as_ref().is_none_or(|m| m.contains(cx, cy))
    }

    /// Cells to rebuild (None: all of the stale tiles).
    pub fn stale_cells(&self) -> Option<usize> {
        self.stale.as_ref().map(CellMask::len)
    }

    /// How far a kept cell's heights move, metres: the mean vertical move of its kept returns,
    /// or of those of the cells within [`DZ_REACH`] of it when none fell in it (its evidence
    /// came from the sweeps between kept ones), or of its tile's, or 0 outside the stale tiles.
    pub fn dz_m(&self, cx: i64, cy: i64) -> f64 {
        let Some(t) = self.tile(cx, cy) else {
            return 0.0;
        };
        let (mut sum, mut count) = (0.0f64, 0u32);
        for reach in [0, DZ_REACH] {
            self.around(
                cx,
                cy,
                reach,
                |m, k| m.dz[k],
                |z| {
                    sum += f64::from(z);
                    count += 1;
                },
            );
            if count > 0 {
                return sum / f64::from(count);
            }
        }
        f64::from(t.dz_mean)
    }

    /// The cell takes the rebuilt map's at the swap: within reach of a move
    /// ([`Self::is_stale`]), where a return moved by more than the tolerance left or reached
    /// the cell or its returns moved apart vertically by more than it, or, for a cell no kept
    /// return fell in, where that holds within [`DZ_REACH`] of it (or, none there either,
    /// anywhere in its tile). Every other cell is the live map's, its heights moved by
    /// [`Self::dz_m`].
    pub fn is_rebuilt(&self, cx: i64, cy: i64) -> bool {
        if !self.is_stale(cx, cy) {
            return false;
        }
        if self.seeds.contains(&(cx, cy)) {
            return true;
        }
        let Some(t) = self.tile(cx, cy) else {
            return true;
        };
        let mut own = false;
        self.around(cx, cy, 0, |m, k| m.dz[k], |_| own = true);
        if own {
            return false;
        }
        let mut near = false;
        self.around(cx, cy, DZ_REACH, |m, k| m.dz[k], |_| near = true);
        if near {
            (-DZ_REACH..=DZ_REACH)
                .any(|dy| (-DZ_REACH..=DZ_REACH).any(|dx| self.seeds.contains(&(cx + dx, cy + dy))))
        } else {
            f64::from(t.side_max) > self.tol_m
        }
    }

    fn tile(&self, cx: i64, cy: i64) -> Option<&TileMoves> {
        self.dz.get(&self.lattice.tile_of_cell(cx, cy).0)
    }

    /// Calls `f` with `get`'s finite values over the cells within `reach` of (cx, cy) (those
    /// of neighbouring tiles looked up there).
    fn around(
        &self,
        cx: i64,
        cy: i64,
        reach: i64,
        get: impl Fn(&TileMoves, usize) -> f32,
        mut f: impl FnMut(f32),
    ) {
        let n = self.lattice.tile_cells as i64;
        let (t, (c, r)) = self.lattice.tile_of_cell(cx, cy);
        let home = self.dz.get(&t);
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (nc, nr) = (i64::from(c) + dx, i64::from(r) + dy);
                // Neighbours in the same tile read its row; the others look theirs up.
                let v = if (0..n).contains(&nc) && (0..n).contains(&nr) {
                    home.map_or(f32::NAN, |m| get(m, (nr * n + nc) as usize))
                } else {
                    let (t, (c, r)) = self.lattice.tile_of_cell(cx + dx, cy + dy);
                    self.dz
                        .get(&t)
                        .map_or(f32::NAN, |m| get(m, r as usize * n as usize + c as usize))
                };
                if v.is_finite() {
                    f(v);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::rebuild::tests::pt;
    use super::super::rebuild::{Correction, SweepStore};
    use super::*;
    use slam::se3;

    const LATTICE: Lattice = Lattice {
        cell_size_m: 0.2,
        tile_cells: 64,
    };

    /// The tiles of the lattice within 40 m of the x axis from x = -40 to 240 m.
    fn all_tiles() -> HashSet<TileIndex> {
        let (c0, r0) = LATTICE.cell_of(-40.0, -40.0);
        let (c1, r1) = LATTICE.cell_of(240.0, 40.0);
        let (t0, t1) = (
            LATTICE.tile_of_cell(c0, r0).0,
            LATTICE.tile_of_cell(c1, r1).0,
        );
        (t0.ty..=t1.ty)
            .flat_map(|ty| (t0.tx..=t1.tx).map(move |tx| TileIndex { tx, ty }))
            .collect()
    }

    /// The store's correction as a rebuild feeding every kept sweep gathers it.
    fn correction(
        st: &SweepStore,
        blf: &Isometry3<f64>,
        grow: i64,
        max_cells: usize,
    ) -> CellCorrection {
        let mut m = CellMoves::new(LATTICE, st.min_move_m(), st.near_range_m());
        for r in st.after(None, usize::MAX) {
            m.add(&r, blf);
        }
        m.finish(&all_tiles(), grow, max_cells)
    }

    #[test]
    fn the_stale_cells_are_around_the_returns_a_correction_moved_sideways() {
        let blf = se3::from_xyz_rpy([0.0, 0.0, 0.7], [0.0; 3]);
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 100.0);
        for i in 0..3 {
            // Sweeps at x = 0, 100, 200 m, each with returns 1.1 m and 25.1 m ahead (off the
            // cell edges, which the millimetre quantisation could cross) and one beyond the
            // range (a beam direction, left out).
            let p = se3::from_xyz_rpy([100.0 * f64::from(i), 0.0, 0.0], [0.0; 3]);
            st.offer(f64::from(i), &p, &p, &[pt(1.1), pt(25.1), pt(50.1)], false);
        }
        let cells = correction(&st, &blf, 2, 1 << 20);
        assert_eq!(cells.stale_cells(), Some(0), "nothing moved yet");
        // The middle sweep moves 0.3 m sideways.
        let mid = se3::from_xyz_rpy([0.0, 0.3, 0.0], [0.0; 3]);
        let c = st.correct(
            |t| Some(if t == 1.0 { mid } else { Isometry3::identity() }),
            None,
        );
        assert_eq!(c, Correction::Restart);
        let cells = correction(&st, &blf, 2, 1 << 20);
        let has = |x: f64, y: f64| {
            let (cx, cy) = LATTICE.cell_of(x, y);
            cells.is_stale(cx, cy)
        };
        // Where the live map has its returns, where the rebuild puts them, and two cells on.
        assert!(has(101.1, 0.0) && has(101.1, 0.3) && has(125.1, 0.0) && has(125.1, 0.3));
        assert!(has(101.1, 0.65) && has(100.65, 0.0));
        assert!(!has(101.1, 0.9) && !has(113.0, 0.0), "beyond the growth");
        assert!(
            !has(1.1, 0.0) && !has(201.1, 0.0),
            "sweeps that did not move"
        );
        assert_eq!(cells.stale_cells(), Some(2 * 5 * 6), "two 5 x 6 blocks");
        st.swapped();
        // A turn of 0.5 deg about the first sweep moves its return 1.1 m out by 10 mm, the one
        // 25.1 m out by 0.22 m: only the far one's cells are stale.
        let turn = se3::from_xyz_rpy([0.0; 3], [0.0, 0.0, 0.5_f64.to_radians()]);
        st.correct(|t| Some(if t == 0.0 { turn } else { mid }), None);
        let cells = correction(&st, &blf, 0, 1 << 20);
        let has = |x: f64, y: f64| {
            let (cx, cy) = LATTICE.cell_of(x, y);
            cells.is_stale(cx, cy)
        };
        assert!(has(25.1, 0.0) && has(25.09, 0.21) && !has(1.1, 0.0));
        // A mask too large to hold: every cell of the stale tiles is rebuilt.
        let all = correction(&st, &blf, 0, 10);
        assert_eq!(all.stale_cells(), None);
        assert!(all.is_stale(0, 0));
    }

    #[test]
    fn inside_the_mask_only_cells_whose_returns_moved_by_more_than_a_cell_are_rebuilt() {
        let blf = Isometry3::identity();
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 100.0);
        let p = |x: f64| se3::from_xyz_rpy([x, 0.0, 0.0], [0.0; 3]);
        // Returns at x = 5.1 m (first sweep) and 5.5 m (second), two cells apart.
        st.offer(0.0, &p(0.0), &p(0.0), &[pt(5.1)], false);
        st.offer(1.0, &p(1.0), &p(1.0), &[pt(4.5)], false);
        // The first moves 0.15 m sideways (under a cell), the second 0.3 m, both 4 cm up.
        let small = se3::from_xyz_rpy([0.0, 0.15, 0.04], [0.0; 3]);
        let large = se3::from_xyz_rpy([0.0, 0.3, 0.04], [0.0; 3]);
        st.correct(|t| Some(if t == 0.0 { small } else { large }), None);
        let cells = correction(&st, &blf, 2, 1 << 20);
        let at = |x: f64| {
            let (cx, cy) = LATTICE.cell_of(x, 0.0);
            (cells.is_stale(cx, cy), cells.is_rebuilt(cx, cy))
        };
        assert_eq!(
            at(5.1),
            (true, false),
            "two cells from a return moved by more than a cell, its own moved by under one: live"
        );
        let (cx, cy) = LATTICE.cell_of(5.1, 0.0);
        assert!((cells.dz_m(cx, cy) - 0.04).abs() < 1e-4, "4 cm up");
        assert_eq!(at(5.5), (true, true), "moved 1.5 cells");
        assert_eq!(
            at(5.3),
            (true, true),
            "no return of its own, one beside it moved 1.5 cells"
        );
        assert_eq!(at(4.3), (false, false));
    }

    #[test]
    fn cells_a_correction_lifts_alike_keep_their_evidence_and_move_up() {
        let blf = Isometry3::identity();
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 100.0);
        // Two sweeps 0.6 m apart whose returns fall in the same cell at x = 5.1 m, and a
        // return each of their own at 10.1 and 10.7 m.
        let a = se3::from_xyz_rpy([0.0; 3], [0.0; 3]);
        let b = se3::from_xyz_rpy([0.6, 0.0, 0.0], [0.0; 3]);
        st.offer(0.0, &a, &a, &[pt(5.1), pt(10.1)], false);
        st.offer(1.0, &b, &b, &[pt(4.5), pt(10.1)], false);
        // Both lifted by 8 cm: nothing to rebuild, every cell 8 cm up.
        let up = se3::from_xyz_rpy([0.0, 0.0, 0.08], [0.0; 3]);
        st.correct(|_| Some(up), None);
        let cells = correction(&st, &blf, 2, 1 << 20);
        assert_eq!(cells.stale_cells(), Some(0));
        let dz = |x: f64| {
            let (cx, cy) = LATTICE.cell_of(x, 0.0);
            cells.dz_m(cx, cy)
        };
        assert!((dz(5.1) - 0.08).abs() < 1e-4 && (dz(10.7) - 0.08).abs() < 1e-4);
        assert!(
            (dz(5.4) - 0.08).abs() < 1e-4,
            "a cell with no return of its own, beside some"
        );
        assert!(
            (dz(12.1) - 0.08).abs() < 1e-4,
            "no return within two cells: its tile's mean"
        );
        assert_eq!(dz(20.0), 0.0, "a tile no return fell in");
        st.swapped();
        // The second lifted 25 cm more than the first: the shared cell's returns move apart by
        // more than a cell.
        let up2 = se3::from_xyz_rpy([0.0, 0.0, 0.33], [0.0; 3]);
        st.correct(|t| Some(if t == 1.0 { up2 } else { up }), None);
        let cells = correction(&st, &blf, 0, 1 << 20);
        let stale = |x: f64| {
            let (cx, cy) = LATTICE.cell_of(x, 0.0);
            cells.is_stale(cx, cy)
        };
        assert!(stale(5.1), "sweeps set against each other in height");
        assert!(
            !stale(10.1) && !stale(10.7),
            "a cell one sweep saw moves with it"
        );
        let (cx, cy) = LATTICE.cell_of(10.7, 0.0);
        assert!((cells.dz_m(cx, cy) - 0.25).abs() < 1e-4);
        // 8 cm apart is within the tolerance: kept, at their mean move.
        st.correct(|t| Some(if t == 1.0 { up * up } else { up }), None);
        let cells = correction(&st, &blf, 0, 1 << 20);
        let (cx, cy) = LATTICE.cell_of(5.1, 0.0);
        assert!(!cells.is_stale(cx, cy));
        assert!((cells.dz_m(cx, cy) - 0.04).abs() < 1e-4);
    }
}

//! Replacing the whole map by one rebuilt from the same sweeps at corrected poses (a pose graph
//! moved the trajectory: a loop closed, or RTK came back after an outage; docs/algorithms.md
//! §3.7). The rebuilt map is made by the caller with a fresh [`Mapper`]; this swaps it in and
//! says which tiles a station must be sent again.

use super::{Mapper, TileSlot};
use crate::classify::Class;
use common::grid::{Cell, CellState, TileIndex};
use std::collections::HashMap;

impl Mapper {
    /// Replaces this map by `rebuilt` (same configuration, fed the kept sweeps at their
    /// corrected poses) and returns every tile to publish again, sorted: all tiles of the
    /// rebuilt map, and the tiles only this map held, which stay as unknown cells so that a
    /// station replaces what it was sent of them (the drifted copy of an obstacle must go).
    /// Counters and the time stay monotonic: the later of the two maps' last update is kept.
    ///
    /// Every observed cell of the rebuilt map is stamped `t_s`, the time of the correction: a
    /// station keeps, per cell, the evidence with the newest stamp (docs/algorithms.md §8.3), and
    /// the sweeps behind a rebuilt cell are older than what it was sent of that cell before, yet
    /// where they put things is newer knowledge.
    pub fn replace_with(&mut self, rebuilt: Mapper, t_s: f64) -> Vec<TileIndex> {
        self.replace_tiles_with(rebuilt, t_s, |_| true)
    }

    /// [`Mapper::replace_with`] for the tiles `stale` says a correction moved only: the others
    /// keep this map's cells (the same sweeps at the same poses, all of them where the rebuild
    /// has only the kept ones, so more evidence) and stamps, and are not published again. A
    /// stale tile the rebuilt map does not hold stays as unknown cells, as above.
    pub fn replace_tiles_with(
        &mut self,
        rebuilt: Mapper,
        t_s: f64,
        stale: impl Fn(TileIndex) -> bool,
    ) -> Vec<TileIndex> {
        self.replace_cells_with(rebuilt, t_s, stale, |_, _| true, |_, _| 0.0)
            .tiles
    }

    /// [`Mapper::replace_tiles_with`] where, inside a stale tile, only the cells `rebuilt_cell`
    /// says (global cell indices) are the rebuilt map's: the others keep this map's evidence,
    /// verdicts and stamps, their heights moved onto the rebuilt map's ground: by the median
    /// height difference of the ground both maps hold as traversable in each stale tile,
    /// interpolated between tile centres ([`ground_offset`]), or by `dz_of` metres (the vertical
    /// part of the correction there, from the poses) where no tile nearby has such ground. The
    /// poses alone do not say where this map's heights are: they also followed frame shifts
    /// and revisits since the sweeps were mapped (on `loop` the return of RTK after the outage
    /// lifted the outage's kept cells 0.2 m above their rebuilt neighbours). The tile is still
    /// published again. A kept cell's verdict and cost were
    /// made with this map's neighbours: the caller keeps a cell only where the correction moved
    /// its evidence and its neighbours' so little that the rebuilt neighbours agree with them.
    pub fn replace_cells_with(
        &mut self,
        mut rebuilt: Mapper,
        t_s: f64,
        stale: impl Fn(TileIndex) -> bool,
        rebuilt_cell: impl Fn(i64, i64) -> bool,
        dz_of: impl Fn(i64, i64) -> f64,
    ) -> Replaced {
        let min_points = self.rules.min_points();
        let lattice = self.lattice;
        let h_r_m = self.cfg.h_r_m as f32;
        let offsets: HashMap<TileIndex, f32> = rebuilt
            .slots
            .iter()
            .filter(|s| stale(s.index))
            .filter_map(|s| {
                let o = self.slots.get(*self.slot_of.get(&s.index)?)?;
                Some((s.index, ground_offset(s, o)?))
            })
            .collect();
        let dz_at = |cx: i64, cy: i64| {
            interpolated_offset(&offsets, &lattice, cx, cy)
                .map(|o| if o.abs() < OFFSET_NOISE_M { 0.0 } else { o })
                .unwrap_or_else(|| dz_of(cx, cy))
        };
        let keep = |to: &mut TileSlot, from: &TileSlot| {
            keep_cells(to, from, &lattice, &rebuilt_cell, dz_at, min_points, h_r_m)
        };
        let mut rebuilt_cells = 0;
        let mut doubted: Vec<(i64, i64, f32)> = Vec::new();
        let stamp = super::evidence::stamp_of(t_s);
        let n = lattice.tile_cells as usize;
        let mut own: Vec<Option<TileSlot>> = self.slots.drain(..).map(Some).collect();
        let mut slots: Vec<TileSlot> = Vec::with_capacity(rebuilt.slots.len() + own.len());
        for mut s in rebuilt.slots.drain(..) {
            if !stale(s.index) {
                continue;
            }
            for d in &mut s.data {
                d.stamp_s = d.stamp_s.max(stamp);
            }
            for c in s.live.iter_mut().filter(|c| c.state != CellState::Unknown) {
                c.stamp_s = c.stamp_s.max(stamp);
            }
            match self.slot_of.get(&s.index).and_then(|&i| own[i].take()) {
                Some(o) => {
                    rebuilt_cells += keep(&mut s, &o);
                    doubted.extend(obstacles_only_rebuilt(&s, &o, &lattice, &rebuilt_cell));
                }
                None => rebuilt_cells += n * n,
            }
            slots.push(s);
        }
        let mut tiles: Vec<TileIndex> = slots.iter().map(|s| s.index).collect();
        for s in own.into_iter().flatten() {
            if !stale(s.index) {
                slots.push(s);
            } else {
                // Stale, and the rebuilt map does not hold it: unknown but for the kept cells.
                tiles.push(s.index);
                let mut fresh = TileSlot {
                    index: s.index,
                    data: vec![Default::default(); n * n],
                    ground: vec![f32::INFINITY; n * n],
                    live: vec![Cell::UNKNOWN; n * n],
                    held: vec![0; (n * n).div_ceil(64)],
                    changed: false,
                };
                rebuilt_cells += keep(&mut fresh, &s);
                slots.push(fresh);
            }
        }
        for s in &mut slots {
            s.changed = false;
        }
        rebuilt.slot_of = slots
            .iter()
            .enumerate()
            .map(|(i, s)| (s.index, i))
            .collect();
        rebuilt.slots = slots;
        // Cells this map kept that wait to be classified wait on.
        rebuilt.pending.extend(
            self.pending.iter().filter(|&&(cx, cy)| {
                !stale(lattice.tile_of_cell(cx, cy).0) || !rebuilt_cell(cx, cy)
            }),
        );
        rebuilt.last_t_s = match (self.last_t_s, rebuilt.last_t_s) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        };
        rebuilt.full = self.full;
        rebuilt.scan_id = rebuilt.scan_id.max(self.scan_id);
        rebuilt
            .last_slot
            .set((TileIndex { tx: 0, ty: 0 }, usize::MAX));
        tiles.sort_unstable();
        *self = rebuilt;
        let thinned_cleared = self.rejudge_thinned(&doubted);
        Replaced {
            tiles,
            rebuilt_cells,
            thinned_cleared,
        }
    }
}

impl Mapper {
    /// Judges again the rebuilt obstacles that the live map, made from every sweep, held
    /// traversable (`doubted`: cell and the distance the live verdict was made from): the
    /// rebuild sees one sweep in `map_rebuild_spacing_m`'s worth, and a verdict it made on a few
    /// returns is kept only if the rules still find an obstacle on the merged map's evidence
    /// (rebuilt cells beside the live cells the swap kept). Towards traversable, overhung or
    /// unknown only, as the far rules ([`Mapper::cleared_class`]); the outputs around a cleared
    /// cell are written at once, wherever the robot is. Returns how many it cleared.
    fn rejudge_thinned(&mut self, doubted: &[(i64, i64, f32)]) -> usize {
        let mut cleared: Vec<(i64, i64)> = Vec::new();
        for &(cx, cy, live_range_m) in doubted {
            let Some(d) = self.data(cx, cy).copied() else {
                continue;
            };
            if d.class != Class::Obstacle || d.far_wiped {
                continue;
            }
            if let Some(new) = self.cleared_class(cx, cy, d.headroom) {
                let dm = self.data_mut(cx, cy);
                dm.class = new;
                dm.class_range_m = live_range_m;
                cleared.push((cx, cy));
            }
        }
        let rc = (self.cfg.cost_distance_m / self.cfg.grid_size_m).ceil() as i64;
        let mut around: Vec<(i64, i64)> = cleared
            .iter()
            .flat_map(|&(cx, cy)| {
                (-rc..=rc).flat_map(move |dy| (-rc..=rc).map(move |dx| (cx + dx, cy + dy)))
            })
            .collect();
        around.sort_unstable();
        around.dedup();
        for (cx, cy) in around {
            if self.data(cx, cy).is_some() {
                let cell = self.output_cell(cx, cy, None);
                self.write_live(cx, cy, cell);
            }
        }
        cleared.len()
    }
}

/// The cells of a stale tile the rebuilt map (`to`) claims and holds as obstacles where this
/// map (`from`, every sweep) held them traversable, with the distance that verdict was made
/// from.
fn obstacles_only_rebuilt(
    to: &TileSlot,
    from: &TileSlot,
    lattice: &common::grid::Lattice,
    rebuilt_cell: impl Fn(i64, i64) -> bool,
) -> Vec<(i64, i64, f32)> {
    let n = lattice.tile_cells as usize;
    let (cx0, cy0) = lattice.tile_first_cell(to.index);
    (0..n * n)
        .filter(|&k| {
            to.data[k].class == Class::Obstacle && from.data[k].class == Class::Traversable
        })
        .map(|k| {
            (
                cx0 + (k % n) as i64,
                cy0 + (k / n) as i64,
                from.data[k].class_range_m,
            )
        })
        .filter(|&(cx, cy, _)| rebuilt_cell(cx, cy))
        .collect()
}

/// Cells of a tile both maps hold as traversable ground that the offset between them is
/// measured from; fewer, and the tile gives none.
const OFFSET_MIN_CELLS: usize = 30;

/// Ground offsets smaller than this are the two maps' noise, not a move, metres: the kept
/// cells stay as they are (evidence and outputs).
const OFFSET_NOISE_M: f64 = 0.005;

/// How far the rebuilt map's ground (`to`) stands above this map's (`from`) in one tile: the
/// median over the cells both hold as traversable ground, or None with fewer than
/// [`OFFSET_MIN_CELLS`].
fn ground_offset(to: &TileSlot, from: &TileSlot) -> Option<f32> {
    let mut d: Vec<f64> = to
        .ground
        .iter()
        .zip(&from.ground)
        .zip(to.data.iter().zip(&from.data))
        .filter(|((a, b), (p, q))| {
            a.is_finite()
                && b.is_finite()
                && p.class == Class::Traversable
                && q.class == Class::Traversable
        })
        .map(|((a, b), _)| f64::from(a - b))
        .collect();
    (d.len() >= OFFSET_MIN_CELLS).then(|| super::revisit::median(&mut d) as f32)
}

/// The tiles' ground offsets interpolated bilinearly between tile centres at cell (cx, cy)
/// (over the neighbouring tiles that have one), so kept cells meet their neighbours across
/// tile borders without a step; None where no neighbouring tile has one.
fn interpolated_offset(
    offsets: &HashMap<TileIndex, f32>,
    lattice: &common::grid::Lattice,
    cx: i64,
    cy: i64,
) -> Option<f64> {
    if offsets.is_empty() {
        return None;
    }
    let n = f64::from(lattice.tile_cells);
    let fx = (cx as f64 + 0.5) / n - 0.5;
    let fy = (cy as f64 + 0.5) / n - 0.5;
    let (x0, y0) = (fx.floor(), fy.floor());
    let (ax, ay) = (fx - x0, fy - y0);
    let (mut sum, mut weight) = (0.0, 0.0);
    for (dx, wx) in [(0, 1.0 - ax), (1, ax)] {
        for (dy, wy) in [(0, 1.0 - ay), (1, ay)] {
            let t = TileIndex {
                tx: (x0 as i64 + dx) as i32,
                ty: (y0 as i64 + dy) as i32,
            };
            if let Some(&o) = offsets.get(&t) {
                let w = wx * wy;
                sum += w * f64::from(o);
                weight += w;
            }
        }
    }
    (weight > 1e-6).then(|| sum / weight)
}

/// What [`Mapper::replace_cells_with`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Replaced {
    /// Every tile to publish again, sorted.
    pub tiles: Vec<TileIndex>,
    /// Cells of the stale tiles that are the rebuilt map's.
    pub rebuilt_cells: usize,
    /// Of those, obstacles of the rebuilt map that the live map held traversable and the rules
    /// no longer find on the merged map (cleared; [`Mapper::replace_cells_with`]).
    pub thinned_cleared: usize,
}

/// Copies into `to` (the rebuilt tile) the cells of `from` (this map's, the same tile) that
/// `rebuilt_cell` does not claim, their heights moved by `dz_of`; returns how many it left to
/// the rebuilt map.
fn keep_cells(
    to: &mut TileSlot,
    from: &TileSlot,
    lattice: &common::grid::Lattice,
    rebuilt_cell: impl Fn(i64, i64) -> bool,
    dz_of: impl Fn(i64, i64) -> f64,
    min_points: u32,
    h_r_m: f32,
) -> usize {
    let n = lattice.tile_cells as usize;
    let (cx0, cy0) = lattice.tile_first_cell(to.index);
    let mut rebuilt = 0;
    for k in 0..n * n {
        let (cx, cy) = (cx0 + (k % n) as i64, cy0 + (k / n) as i64);
        // The rebuild sees one sweep in `map_rebuild_spacing_m`'s worth: under a canopy it may
        // keep only the canopy's returns where the live map saw the ground below with headroom.
        let (live, re) = (&from.data[k], &to.data[k]);
        let lost_ground = live.headroom
            && live.class == Class::Traversable
            && re.class == Class::Obstacle
            && from.ground[k].is_finite()
            && to.ground[k].is_finite()
            && to.ground[k] > from.ground[k] + h_r_m;
        if rebuilt_cell(cx, cy) && !lost_ground {
            rebuilt += 1;
            continue;
        }
        to.data[k] = from.data[k];
        to.ground[k] = from.ground[k];
        to.live[k] = from.live[k];
        let bit = 1u64 << (k & 63);
        if from.held[k >> 6] & bit != 0 {
            to.held[k >> 6] |= bit;
            let dz = dz_of(cx, cy);
            if dz != 0.0 && dz.is_finite() {
                let d = &mut to.data[k];
                d.shift_heights(dz);
                to.ground[k] = d.ground(min_points);
                if to.live[k].state != CellState::Unknown {
                    to.live[k].height_cm = super::inflation::output_height_cm(d, min_points);
                }
            }
        } else {
            to.held[k >> 6] &= !bit;
        }
    }
    rebuilt
}

#[cfg(test)]
mod tests {
    use crate::synth::{lattice_points, short_drive};
    use crate::{Class, Config, Mapper, RobotPose};

    /// Flat ground with a 1 m box at (6, 0).
    fn world(x: f64, y: f64) -> f64 {
        if (x - 6.0).abs() < 0.5 && y.abs() < 0.5 {
            1.0
        } else {
            0.0
        }
    }

    /// Maps a drive along y = 0 whose sweeps are placed `offset_y` off (a drifted pose).
    fn mapped(offset_y: f64) -> Mapper {
        mapped_at(offset_y, 0.0)
    }

    /// [`mapped`], the sweeps also placed `offset_z` metres high.
    fn mapped_at(offset_y: f64, offset_z: f64) -> Mapper {
        short_drive(&world, 3, [offset_y, offset_z])
    }

    /// Obstacle cells (class before inflation) with centres in `[x0, x1] x [y0, y1]`.
    fn obstacles_in(m: &Mapper, (x0, x1): (f64, f64), (y0, y1): (f64, f64)) -> usize {
        let l = m.lattice();
        let (c0, r0) = l.cell_of(x0, y0);
        let (c1, r1) = l.cell_of(x1, y1);
        (r0..=r1)
            .flat_map(|r| (c0..=c1).map(move |c| (c, r)))
            .filter(|&(c, r)| m.class(c, r) == Class::Obstacle)
            .count()
    }

    #[test]
    fn a_partial_replace_keeps_the_live_tiles_it_is_not_given() {
        let mut drifted = mapped(1.0);
        let l = drifted.lattice();
        let (bx, by) = l.cell_of(6.0, 1.0);
        let box_tile = l.tile_of_cell(bx, by).0;
        let before: Vec<_> = drifted.tiles();
        // Nothing stale: the live map stays as it was, nothing goes out again.
        let tiles = drifted.replace_tiles_with(mapped(0.0), 17.0, |_| false);
        assert!(tiles.is_empty());
        assert_eq!(drifted.tiles(), before, "cells and stamps unchanged");
        // Only the box's tile stale: it is the rebuilt one, stamped anew; the others stay.
        let tiles = drifted.replace_tiles_with(mapped(0.0), 17.0, |t| t == box_tile);
        assert_eq!(tiles, vec![box_tile]);
        let north = ((5.3, 6.7), (0.9, 1.7));
        assert_eq!(obstacles_in(&drifted, north.0, north.1), 0);
        assert!(obstacles_in(&drifted, (5.3, 6.7), (-0.7, 0.7)) > 0);
        let (sx, sy) = l.cell_of(5.6, 0.2);
        assert_eq!(l.tile_of_cell(sx, sy).0, box_tile);
        assert_eq!(drifted.cell(sx, sy).stamp_s, 17, "a rebuilt cell");
        for t in before.iter().filter(|t| t.index != box_tile) {
            assert_eq!(
                drifted.tile_cells(t.index),
                Some(t.cells.as_slice()),
                "tile {:?} kept",
                t.index
            );
        }
    }

    #[test]
    fn inside_a_stale_tile_only_the_stale_cells_are_the_rebuilt_maps() {
        let mut drifted = mapped(1.0);
        let l = drifted.lattice();
        let (bx, by) = l.cell_of(6.0, 1.0);
        let box_tile = l.tile_of_cell(bx, by).0;
        let before = drifted.tiles();
        let north = ((5.3, 6.7), (0.9, 1.7));
        let south = ((5.3, 6.7), (-0.7, 0.3));
        let drifted_north = obstacles_in(&drifted, north.0, north.1);
        assert!(drifted_north > 0);
        // Stale: the cells south of y = 0.5 m. North of it the drifted box stays; south of it
        // the rebuilt one comes in.
        let (_, split) = l.cell_of(0.0, 0.5);
        // The poses say the kept cells move up 5 cm; the two maps' ground says they stay.
        let r = drifted.replace_cells_with(
            mapped(0.0),
            17.0,
            |t| t == box_tile,
            |_, cy| cy < split,
            |_, _| 0.05,
        );
        assert_eq!(r.tiles, vec![box_tile], "the mixed tile goes out again");
        let n = i64::from(l.tile_cells);
        let rows = (split - l.tile_first_cell(box_tile).1).clamp(0, n);
        assert_eq!(
            r.rebuilt_cells as i64,
            n * rows,
            "the rows south of the split"
        );
        assert_eq!(obstacles_in(&drifted, north.0, north.1), drifted_north);
        assert!(
            obstacles_in(&drifted, south.0, south.1) > 0,
            "the rebuilt box"
        );
        let (nx, ny) = l.cell_of(3.0, 1.1);
        let was = before
            .iter()
            .find(|t| t.index == box_tile)
            .map(|t| {
                *t.get(
                    (nx - l.tile_first_cell(box_tile).0) as u16,
                    (ny - l.tile_first_cell(box_tile).1) as u16,
                )
            })
            .unwrap();
        let now = drifted.cell(nx, ny);
        assert_eq!(
            (now.state, now.stamp_s, now.hits),
            (was.state, was.stamp_s, was.hits),
            "a kept cell keeps its verdict and stamp"
        );
        assert_eq!(
            now.height_cm, was.height_cm,
            "and stays on the rebuilt map's ground, which stands where it stood"
        );
        let (sx, sy) = l.cell_of(3.0, 0.1);
        assert_eq!(drifted.cell(sx, sy).stamp_s, 17, "a rebuilt cell");
    }

    #[test]
    fn kept_cells_move_onto_the_rebuilt_ground_whatever_the_poses_say() {
        // The rebuilt map stands 10 cm higher than the live one (the live map's heights
        // followed frame shifts and revisits the poses do not know of); the poses say nothing
        // moved. The kept cells must meet their rebuilt neighbours: left where they were, the
        // border between the two is a 10 cm step the rules read as obstacles.
        let mut live = mapped(0.0);
        let l = live.lattice();
        let (_, split) = l.cell_of(0.0, 0.5);
        let (kx, ky) = l.cell_of(3.0, 4.0);
        let before = live.height_m(kx, ky).expect("observed");
        let all = |_| true;
        let _ = live.replace_cells_with(
            mapped_at(0.0, 0.1),
            17.0,
            all,
            |_, cy| cy < split,
            |_, _| 0.0,
        );
        let after = live.height_m(kx, ky).expect("observed");
        assert!(
            (after - before - 0.1).abs() < 0.01,
            "a kept cell moved {:.3} m",
            after - before
        );
        // Along the border between kept (north) and rebuilt (south) cells: no step.
        assert_eq!(obstacles_in(&live, (-3.0, 4.5), (-1.0, 2.0)), 0);
        assert!(obstacles_in(&live, (5.3, 6.7), (-0.7, 0.7)) > 0, "the box");
        // With no ground both maps hold as traversable there is no offset to measure, and the
        // kept cells move as the poses say (here not at all).
        let mut live = mapped(0.0);
        let mut rebuilt = mapped_at(0.0, 0.1);
        for s in &mut rebuilt.slots {
            s.data.iter_mut().for_each(|d| d.class = Class::Unknown);
        }
        let _ = live.replace_cells_with(rebuilt, 17.0, all, |_, cy| cy < split, |_, _| 0.0);
        let after = live.height_m(kx, ky).expect("observed");
        assert!(
            (after - before).abs() < 0.01,
            "moved {:.3} m",
            after - before
        );
    }

    #[test]
    fn a_rebuilt_cell_left_with_a_canopy_over_the_live_ground_keeps_the_live_cell() {
        // The thinned rebuild kept only a canopy's returns (2.8 m up) in a cell where the live
        // map saw the ground below with headroom: the live cell stays, not an obstacle.
        let mut live = mapped(0.0);
        let mut rebuilt = mapped(0.0);
        let (si, k) = live
            .slots
            .iter()
            .enumerate()
            .find_map(|(i, s)| {
                (0..s.data.len())
                    .find(|&k| s.data[k].class == Class::Traversable && s.ground[k].is_finite())
                    .map(|k| (i, k))
            })
            .expect("ground");
        live.slots[si].data[k].headroom = true;
        let index = live.slots[si].index;
        let ground = live.slots[si].ground[k];
        let rs = rebuilt
            .slots
            .iter_mut()
            .find(|s| s.index == index)
            .expect("the same tile");
        rs.ground[k] = ground + 2.8;
        rs.data[k].class = Class::Obstacle;
        let l = live.lattice();
        let n = l.tile_cells as usize;
        let (cx0, cy0) = l.tile_first_cell(index);
        let (cx, cy) = (cx0 + (k % n) as i64, cy0 + (k / n) as i64);
        let _ = live.replace_cells_with(rebuilt, 17.0, |_| true, |_, _| true, |_, _| 0.0);
        assert_eq!(live.class(cx, cy), Class::Traversable);
        let merged = live.slots.iter().find(|s| s.index == index).expect("tile");
        assert!(
            (merged.ground[k] - ground).abs() < 0.05,
            "the live ground {ground}, not the canopy: {}",
            merged.ground[k]
        );
    }

    #[test]
    fn a_rebuild_under_the_live_map_drops_a_canopy_seen_without_its_ground() {
        // One kept sweep crossed a canopy 2.8 m up over (4, 3) with no ring on the ground
        // below, which the live map, made from every sweep, saw as flat ground.
        let live = mapped(0.0);
        let canopy = lattice_points([3.0, 2.0], 0.07, [30, 30], |_, _| 2.8);
        let robot = RobotPose {
            x_m: 0.0,
            y_m: 0.0,
            z_m: 0.0,
            yaw_rad: 0.0,
        };
        let l = live.lattice();
        let (cx, cy) = l.cell_of(4.0, 3.0);
        assert!(live.height_m(cx, cy).is_some_and(|h| h.abs() < 0.1));
        let mut alone = Mapper::new(Config::default()).unwrap();
        alone
            .update_sweep(canopy.clone(), [0.0, 0.0, 0.7], &robot, 10.0)
            .unwrap();
        assert!(
            alone.height_m(cx, cy).is_some_and(|h| h > 2.5),
            "without the live ground the canopy is the cell's surface: {:?}",
            alone.height_m(cx, cy)
        );
        let mut under = Mapper::new(Config::default()).unwrap();
        let rep = under
            .update_sweep_under(canopy.clone(), [0.0, 0.0, 0.7], &robot, 10.0, &live)
            .unwrap();
        assert_eq!(under.height_m(cx, cy), None);
        let patch = |m: &Mapper| {
            let (c0, r0) = l.cell_of(3.0, 2.0);
            let (c1, r1) = l.cell_of(5.0, 4.0);
            (r0..=r1)
                .flat_map(|r| (c0..=c1).map(move |c| (c, r)))
                .filter(|&(c, r)| m.height_m(c, r).is_some())
                .count()
        };
        assert!(patch(&alone) > 50, "{}", patch(&alone));
        assert_eq!(patch(&under), 0, "no canopy cell under the live ground");
        assert!(rep.dropped_ceiling > canopy.len() / 2);
    }

    #[test]
    fn a_rebuilt_obstacle_the_live_map_held_traversable_stays_only_if_the_rules_still_find_it() {
        use common::grid::CellState;
        // The rebuilt map's own verdicts, planted: an obstacle on open ground at (3, 2) that its
        // evidence (flat ground) no longer supports, as a verdict made on a few returns of one
        // sweep in six and kept since; and one at (3, -2) that the live map has too.
        let mut live = mapped(0.0);
        let l = live.lattice();
        let open = l.cell_of(3.0, 2.0);
        let both = l.cell_of(3.0, -2.0);
        let the_box = ((5.3, 6.7), (-0.7, 0.7));
        let box_cells = obstacles_in(&live, the_box.0, the_box.1);
        assert_eq!(live.class(open.0, open.1), Class::Traversable);
        assert!(box_cells > 0, "the box");
        live.data_mut(both.0, both.1).class = Class::Obstacle;
        let rebuilt = || {
            let mut m = mapped(0.0);
            m.data_mut(open.0, open.1).class = Class::Obstacle;
            m.data_mut(both.0, both.1).class = Class::Obstacle;
            m
        };
        let r = live.replace_cells_with(rebuilt(), 17.0, |_| true, |_, _| true, |_, _| 0.0);
        assert_eq!(
            r.thinned_cleared, 1,
            "only the one the live map did not have"
        );
        assert_eq!(live.class(open.0, open.1), Class::Traversable);
        let c = live.cell(open.0, open.1);
        assert_eq!(
            (c.state, c.cost),
            (CellState::Traversable, 0),
            "its output too"
        );
        let (nx, ny) = (open.0 + 1, open.1);
        assert_eq!(
            live.cell(nx, ny).state,
            CellState::Traversable,
            "no inflation left"
        );
        assert_eq!(
            live.class(both.0, both.1),
            Class::Obstacle,
            "both maps had it"
        );
        assert_eq!(
            obstacles_in(&live, the_box.0, the_box.1),
            box_cells,
            "the rules still find the box"
        );

        // Where the swap keeps the live cell, nothing is judged again.
        let mut live = mapped(0.0);
        live.data_mut(both.0, both.1).class = Class::Obstacle;
        let r = live.replace_cells_with(
            rebuilt(),
            17.0,
            |_| true,
            |cx, cy| (cx, cy) != open,
            |_, _| 0.0,
        );
        assert_eq!(r.thinned_cleared, 0);
        assert_eq!(
            live.class(open.0, open.1),
            Class::Traversable,
            "the live cell"
        );
    }

    #[test]
    fn a_rebuilt_map_replaces_the_drifted_one_and_every_tile_goes_out_again() {
        let mut drifted = mapped(1.0);
        // North of the true box (y > 0.5) only the drifted copy has obstacles.
        let north = ((5.3, 6.7), (0.9, 1.7));
        assert!(
            obstacles_in(&drifted, north.0, north.1) > 0,
            "the box where drift put it"
        );
        let before: Vec<_> = drifted.tiles().iter().map(|t| t.index).collect();
        let tiles = drifted.replace_with(mapped(0.0), 17.0);
        assert!(
            obstacles_in(&drifted, (5.3, 6.7), (-0.7, 0.7)) > 0,
            "the box where it is"
        );
        assert_eq!(
            obstacles_in(&drifted, north.0, north.1),
            0,
            "the drifted copy is gone"
        );
        let l = drifted.lattice();
        let (sx, sy) = l.cell_of(3.0, 0.0);
        assert_eq!(
            drifted.cell(sx, sy).stamp_s,
            17,
            "rebuilt cells carry the correction's time"
        );
        for t in &before {
            assert!(
                tiles.contains(t),
                "tile {t:?} held before is published again"
            );
        }
        assert!(tiles.windows(2).all(|w| w[0] < w[1]));
        // The map goes on: a later sweep is accepted, one an evidence epoch older is not.
        let robot = RobotPose::default();
        assert!(drifted
            .update_sweep(Vec::new(), [0.0, 0.0, 0.7], &robot, 10.6)
            .is_ok());
        assert!(drifted
            .update_sweep(Vec::new(), [0.0, 0.0, 0.7], &robot, 9.0)
            .is_err());
    }
}

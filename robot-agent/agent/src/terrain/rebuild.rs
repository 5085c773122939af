//! Rebuilding the terrain map when the pose graph moves the past (a loop closed, or RTK came
//! back after an outage; docs/algorithms.md §3.7).
//!
//! The cells hold evidence summaries (height statistics per epoch), not the points behind them,
//! and one cell mixes sweeps of many times, so a cell cannot be moved by "its" correction. What
//! is kept instead is a sweep every `map_rebuild_spacing_m` of travel (every sweep while a
//! rebuild runs, [`SweepStore::respace`]; lidar frame, every finite
//! return in order: within 1.1 times the mapper's range each coordinate quantised to an `i16`
//! step of 1.1 range/32000, about a millimetre at 30 m, beyond it only the beam's direction,
//! for the free space it marks) with its SLAM pose; after a correction that moves any of them by more than
//! `map_rebuild_min_move_m`, a shadow mapper is fed the kept sweeps in time order at their
//! corrected poses (`map<-slam` from the graph at each sweep's time), a few per sweep
//! ([`Shadow`]), and replaces the map's stale tiles (those a moved sweep reaches,
//! [`SweepStore::stale_tiles`]) once it has caught up, and in them only the cells the
//! correction moved ([`super::cell_correction`]); the other cells keep the live map's, made
//! from every sweep. The replaced tiles are offered for publication again; the
//! publisher sends those whose cells differ, with newer versions, so stations replace them. The store is capped at `map_rebuild_max_mb`: over it, every second
//! sweep of its oldest half is dropped (the oldest stretch ends up thinnest).

use super::cell_correction::CellMoves;
use common::grid::{Lattice, TileIndex};
use nalgebra::{Isometry3, Point3};
use sensing::Point;
use std::collections::HashSet;

/// Largest quantised coordinate: [`NEAR_RANGE`] times the mapper's range maps to this.
const Q_MAX: f32 = 32000.0;

/// First coordinate of a return beyond the mapper's range: the other two are its beam's
/// azimuth and elevation in steps of pi/32768 (under 3 mm at 25 m), and it is restored at
/// [`FAR_RANGE`] times the range. No return within the range has this coordinate.
const FAR: i16 = i16::MIN;

/// Where a far return is restored along its beam, in mapper ranges: beyond the mapper's range
/// filter and its scratch window (range plus a margin, less than 1.5x on the diagonal), so it
/// only marches the free space it crossed, out to `clear_reach_m`, as the return itself did.
const FAR_RANGE: f32 = 2.0;

/// Returns within this many mapper ranges of the sensor keep their position: the range filter
/// measures from the robot, not the sensor, and the lever arm between them is well under a
/// tenth of the range.
const NEAR_RANGE: f32 = 1.1;

/// One kept sweep.
struct KeptSweep {
    t_s: f64,
    /// `slam<-base_link` (never changed by corrections).
    slam_from_base: Isometry3<f64>,
    /// `map<-base_link` it was last mapped at (by the live map or a rebuild).
    mapped_at: Isometry3<f64>,
    /// `map<-base_link` the live map has it at: where it was mapped live, or by the rebuild
    /// that last replaced the live map's tiles around it.
    live_at: Isometry3<f64>,
    /// Returns in the lidar frame, in steps of the store's `step_m`.
    points: Vec<[i16; 3]>,
}

/// Bytes one kept sweep holds.
fn sweep_bytes(s: &KeptSweep) -> usize {
    std::mem::size_of::<KeptSweep>() + s.points.capacity() * std::mem::size_of::<[i16; 3]>()
}

/// The sweeps kept for rebuilding, oldest first.
pub struct SweepStore {
    spacing_m: f64,
    min_move_m: f64,
    /// The mapper's range, metres: returns farther than [`NEAR_RANGE`] times it from the sensor
    /// are kept as their beam's direction only ([`FAR`]).
    max_range_m: f32,
    /// Quantisation step of the returns, metres.
    step_m: f32,
    max_bytes: usize,
    bytes: usize,
    sweeps: Vec<KeptSweep>,
    /// Sweeps dropped to stay under the cap.
    dropped: u64,
    /// The last correction: largest move of a kept sweep, metres, and sweeps moved by more
    /// than `min_move_m` (what the agent logs).
    last_move: (f64, usize),
}

/// What a correction means for the kept sweeps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Correction {
    /// No sweep moved by more than `min_move_m`: nothing to rebuild.
    None,
    /// Only sweeps newer than the given time moved (those a running rebuild has not fed yet):
    /// it goes on and feeds them at their new poses.
    Retarget,
    /// Some sweep at or before the given time moved (or no rebuild runs): a rebuild from the
    /// first kept sweep.
    Restart,
}

/// A sweep to map again: where, seen from where, what.
pub struct Remap {
    /// The sweep's time, seconds.
    pub t_s: f64,
    /// Corrected `map<-base_link`.
    pub map_from_base: Isometry3<f64>,
    /// `map<-base_link` the live map has it at.
    pub live_from_base: Isometry3<f64>,
    /// Returns in the lidar frame.
    pub points: Vec<[f32; 3]>,
}

impl SweepStore {
    /// An empty store keeping a sweep every `spacing_m` of travel (0: every sweep), at most
    /// `max_mb` megabytes (10^6 bytes). Every finite return is kept, in the sweep's order: the
    /// mapper marches free space along every `beam_stride`-th return, those beyond its
    /// `max_range_m` included (a beam that ends 50 m away proves the first 25 m empty), so
    /// dropping the far ones would both lose that free space and shift which beams are
    /// marched. Returns within 1.1 `max_range_m` keep their position (steps of 1.1
    /// range/32000, about a millimetre at 30 m), those beyond only their beam's direction
    /// ([`FAR`]).
    pub fn new(spacing_m: f64, min_move_m: f64, max_range_m: f64, max_mb: f64) -> Self {
        let max_range_m = (max_range_m as f32).max(1e-3);
        Self {
            spacing_m,
            min_move_m,
            max_range_m,
            step_m: NEAR_RANGE * max_range_m / Q_MAX,
            max_bytes: (max_mb.max(0.0) * 1e6) as usize,
            bytes: 0,
            sweeps: Vec::new(),
            dropped: 0,
            last_move: (0.0, 0),
        }
    }

    /// A kept sweep moving by no more than this is not rebuilt for, metres.
    pub fn min_move_m(&self) -> f64 {
        self.min_move_m
    }

    /// Returns farther than this from the sensor are kept as their beam's direction only, and
    /// restored farther out than it, metres.
    pub fn near_range_m(&self) -> f64 {
        f64::from(NEAR_RANGE * self.max_range_m)
    }

    /// Sweeps kept.
    pub fn len(&self) -> usize {
        self.sweeps.len()
    }

    /// No sweep kept yet.
    pub fn is_empty(&self) -> bool {
        self.sweeps.is_empty()
    }

    /// Returns kept over all sweeps.
    pub fn points(&self) -> usize {
        self.sweeps.iter().map(|s| s.points.len()).sum()
    }

    /// Bytes the kept sweeps hold.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Sweeps dropped so far to stay under `map_rebuild_max_mb`.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// A sweep just mapped at `map_from_base` (its SLAM pose `slam_from_base`): kept when the
    /// robot moved `spacing_m` since the last kept one, or whatever the distance when `every`
    /// (a rebuild runs: see [`SweepStore::respace`]). Returns whether it was kept.
    pub fn offer(
        &mut self,
        t_s: f64,
        slam_from_base: &Isometry3<f64>,
        map_from_base: &Isometry3<f64>,
        points: &[Point],
        every: bool,
    ) -> bool {
        let due = self.sweeps.last().is_none_or(|s| {
            (every
                || (s.slam_from_base.translation.vector - slam_from_base.translation.vector).norm()
                    >= self.spacing_m)
                && t_s > s.t_s
        });
        if !due || !t_s.is_finite() {
            return false;
        }
        let near = NEAR_RANGE * self.max_range_m;
        let r2 = near * near;
        let inv = 1.0 / self.step_m;
        let angle = 32768.0 / std::f32::consts::PI;
        // Within the range every coordinate is at most Q_MAX steps: the casts cannot saturate.
        // The mapper drops non-finite returns before it strides over the beams, so leaving
        // them out keeps the stride on the same beams.
        let mut points: Vec<[i16; 3]> = points
            .iter()
            .filter(|p| p.is_finite())
            .map(|p| {
                if p.x * p.x + p.y * p.y + p.z * p.z <= r2 {
                    [
                        (p.x * inv).round() as i16,
                        (p.y * inv).round() as i16,
                        (p.z * inv).round() as i16,
                    ]
                } else {
                    let az = p.y.atan2(p.x);
                    let el = p.z.atan2(p.x.hypot(p.y));
                    [
                        FAR,
                        (az * angle).round().clamp(-32767.0, 32767.0) as i16,
                        (el * angle).round() as i16,
                    ]
                }
            })
            .collect();
        // Filtering leaves spare capacity; the cap counts what is held.
        points.shrink_to_fit();
        let s = KeptSweep {
            t_s,
            slam_from_base: *slam_from_base,
            mapped_at: *map_from_base,
            live_at: *map_from_base,
            points,
        };
        self.bytes += sweep_bytes(&s);
        self.sweeps.push(s);
        // The sweeps of a catch-up are held on top of the cap until `respace`: thinning the
        // oldest half for them would cost the store its history for good.
        if !every {
            self.enforce_cap();
        }
        true
    }

    /// Back to one sweep every `spacing_m`: a sweep closer than that to the last one kept
    /// before it goes. While a rebuild runs every live sweep is kept, so that the rebuilt map
    /// takes all the live map took meanwhile (the live map mapped those sweeps at corrected
    /// poses, and a cell seen well only then, from close by, would otherwise come back with the
    /// one kept sweep in six); once it is swapped in they are thinned again, and the cap
    /// (which they were held on top of) applies again. Returns the sweeps dropped by the
    /// spacing.
    pub fn respace(&mut self) -> usize {
        let before = self.sweeps.len();
        let mut last: Option<nalgebra::Vector3<f64>> = None;
        let spacing = self.spacing_m;
        let bytes = &mut self.bytes;
        self.sweeps.retain(|s| {
            let p = s.slam_from_base.translation.vector;
            let keep = last.is_none_or(|l| (p - l).norm() >= spacing);
            if keep {
                last = Some(p);
            } else {
                *bytes -= sweep_bytes(s);
            }
            keep
        });
        let thinned = before - self.sweeps.len();
        self.enforce_cap();
        thinned
    }

    /// Over the cap: every second sweep of the oldest half goes, until under it (a single sweep
    /// over the cap goes too). The newest half keeps its spacing: it is what a loop closing
    /// soon moves most, and the oldest stretch was rebuilt at least as often already.
    fn enforce_cap(&mut self) {
        while self.bytes > self.max_bytes && !self.sweeps.is_empty() {
            let half = self.sweeps.len() / 2;
            if half < 2 {
                let s = self.sweeps.remove(0);
                self.bytes -= sweep_bytes(&s);
                self.dropped += 1;
                continue;
            }
            let mut i = 0usize;
            let bytes = &mut self.bytes;
            let dropped = &mut self.dropped;
            self.sweeps.retain(|s| {
                let keep = i >= half || i.is_multiple_of(2);
                i += 1;
                if !keep {
                    *bytes -= sweep_bytes(s);
                    *dropped += 1;
                }
                keep
            });
        }
    }

    /// Applies a correction: the kept sweeps' poses become `map_from_slam_at(t) * slam<-base`
    /// (sweeps the function has no answer for stay where they were mapped). `fed_until`: the
    /// time of the last sweep a running rebuild has fed (None: none runs). A restart moves
    /// every sweep, a retarget only those not fed yet (the fed ones moved by at most
    /// `min_move_m`, the rebuild's tolerance).
    pub fn correct(
        &mut self,
        map_from_slam_at: impl Fn(f64) -> Option<Isometry3<f64>>,
        fed_until: Option<f64>,
    ) -> Correction {
        let poses: Vec<Isometry3<f64>> = self
            .sweeps
            .iter()
            .map(|s| map_from_slam_at(s.t_s).map_or(s.mapped_at, |m| m * s.slam_from_base))
            .collect();
        // How far each kept sweep moves.
        let moves: Vec<f64> = self
            .sweeps
            .iter()
            .zip(&poses)
            .map(|(s, p)| (s.mapped_at.translation.vector - p.translation.vector).norm())
            .collect();
        let moved = |d: f64| d > self.min_move_m;
        self.last_move = (
            moves.iter().copied().fold(0.0, f64::max),
            moves.iter().filter(|&&d| moved(d)).count(),
        );
        if self.last_move.1 == 0 {
            return Correction::None;
        }
        let restart = fed_until.is_none()
            || self
                .sweeps
                .iter()
                .zip(&moves)
                .any(|(s, &d)| fed_until.is_some_and(|f| s.t_s <= f) && moved(d));
        for (s, p) in self.sweeps.iter_mut().zip(&poses) {
            if restart || fed_until.is_none_or(|f| s.t_s > f) {
                s.mapped_at = *p;
            }
        }
        if restart {
            Correction::Restart
        } else {
            Correction::Retarget
        }
    }

    /// The tiles a rebuild that fed every kept sweep must replace in the live map: those
    /// within `reach_m` (what a sweep's returns, free space and costs touch) of a kept sweep
    /// whose rebuilt pose moves some point of the tile by more than `min_move_m` from where
    /// the live map has it. The move is bounded at the tile's corners at the sweep's height
    /// (it is affine in the point, its length convex), so a small rotation marks the far
    /// tiles only. A tile no moved sweep reaches keeps the live map's cells, which hold every
    /// sweep there rather than one kept every `map_rebuild_spacing_m`. Then the live map has
    /// every kept sweep where the rebuild put it ([`SweepStore::swapped`]).
    pub fn stale_tiles(&self, lattice: &Lattice, reach_m: f64) -> HashSet<TileIndex> {
        let mut stale = HashSet::new();
        let edge = lattice.cell_size_f64() * f64::from(lattice.tile_cells);
        for s in &self.sweeps {
            let delta = s.mapped_at * s.live_at.inverse();
            let o = s.live_at.translation.vector;
            let moved = |x: f64, y: f64| {
                let p = Point3::new(x, y, o.z);
                (delta * p - p).norm() > self.min_move_m
            };
            let tile_at = |x: f64, y: f64| {
                let (cx, cy) = lattice.cell_of(x, y);
                lattice.tile_of_cell(cx, cy).0
            };
            let t0 = tile_at(o.x - reach_m, o.y - reach_m);
            let t1 = tile_at(o.x + reach_m, o.y + reach_m);
            for ty in t0.ty..=t1.ty {
                for tx in t0.tx..=t1.tx {
                    let t = TileIndex { tx, ty };
                    if stale.contains(&t) {
                        continue;
                    }
                    let (x0, y0) = lattice.tile_origin_m(t);
                    let (x1, y1) = (x0 + edge, y0 + edge);
                    let near = (o.x.clamp(x0, x1) - o.x).hypot(o.y.clamp(y0, y1) - o.y);
                    if near <= reach_m
                        && [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                            .into_iter()
                            .any(|(x, y)| moved(x, y))
                    {
                        stale.insert(t);
                    }
                }
            }
        }
        stale
    }

    /// A rebuild that fed every kept sweep replaced the live map's stale tiles: the live map
    /// has them where the rebuild put them.
    pub fn swapped(&mut self) {
        for s in &mut self.sweeps {
            s.live_at = s.mapped_at;
        }
    }

    /// Up to `n` kept sweeps after time `after` (all from the first when None), oldest first,
    /// at the poses they were last given, their returns restored to metres.
    pub fn after(&self, after: Option<f64>, n: usize) -> Vec<Remap> {
        let first = after.map_or(0, |t| self.sweeps.partition_point(|s| s.t_s <= t));
        self.sweeps[first..]
            .iter()
            .take(n)
            .map(|s| Remap {
                t_s: s.t_s,
                map_from_base: s.mapped_at,
                live_from_base: s.live_at,
                points: s.points.iter().map(|q| self.restore(q)).collect(),
            })
            .collect()
    }
}

impl SweepStore {
    /// A kept return in metres (a far one at [`FAR_RANGE`] times the range on its beam).
    fn restore(&self, q: &[i16; 3]) -> [f32; 3] {
        if q[0] == FAR {
            let rad = std::f32::consts::PI / 32768.0;
            let (az, el) = (f32::from(q[1]) * rad, f32::from(q[2]) * rad);
            let r = FAR_RANGE * self.max_range_m;
            [
                r * el.cos() * az.cos(),
                r * el.cos() * az.sin(),
                r * el.sin(),
            ]
        } else {
            [
                f32::from(q[0]) * self.step_m,
                f32::from(q[1]) * self.step_m,
                f32::from(q[2]) * self.step_m,
            ]
        }
    }

    /// The last correction: the largest move of a kept sweep, metres, and how many moved by
    /// more than `map_rebuild_min_move_m`.
    pub fn last_move(&self) -> (f64, usize) {
        self.last_move
    }

    /// Time of the newest kept sweep, seconds (None: none kept).
    pub fn newest_t_s(&self) -> Option<f64> {
        self.sweeps.last().map(|s| s.t_s)
    }

    /// Some kept sweep is newer than `after` (any when None).
    pub fn has_after(&self, after: Option<f64>) -> bool {
        self.sweeps
            .last()
            .is_some_and(|s| after.is_none_or(|t| s.t_s > t))
    }
}

/// A rebuild under way: the shadow mapper and how far it got.
pub struct Shadow {
    /// The map being rebuilt.
    pub mapper: mapping::Mapper,
    /// Time of the last kept sweep fed, seconds (None: none yet).
    pub fed_until: Option<f64>,
    /// Kept sweeps fed.
    pub fed: usize,
    /// Time of the live sweep that started it, seconds.
    pub started_s: f64,
    /// Frame shifts the live map took while this rebuild ran, each with the time of the newest
    /// kept sweep when it came, oldest first: the shadow takes each one once it has fed that
    /// sweep, before the next ([`Shadow::follow_frames_before`]).
    pub pending_shifts: Vec<(f64, Isometry3<f64>)>,
    /// How the kept sweeps fed so far moved the live map's cells.
    pub moves: CellMoves,
}

impl Shadow {
    /// A rebuild from the first kept sweep, started by the live sweep at `started_s`,
    /// gathering the cells' moves into `moves`.
    pub fn new(mapper: mapping::Mapper, started_s: f64, moves: CellMoves) -> Self {
        Self {
            mapper,
            fed_until: None,
            fed: 0,
            started_s,
            pending_shifts: Vec::new(),
            moves,
        }
    }

    /// The frame shifts that came before the kept sweep at `t_s` was mapped live are applied
    /// to the shadow now, at the point of its feed where the live map took them: the kept
    /// sweeps fed after a shift were mapped (and kept) in the shifted frame, those fed before
    /// it in the old one, and applying a shift when it comes instead (with the shadow still
    /// feeding sweeps from minutes earlier) would move the heights of sweeps placed in the
    /// graph's frame and set them off against the sweeps fed after, which are not moved.
    pub fn follow_frames_before(&mut self, t_s: f64, radius_m: f64) {
        let n = self.pending_shifts.partition_point(|(t, _)| *t < t_s);
        for (_, shift) in self.pending_shifts.drain(..n) {
            self.mapper.follow_frame(&shift, radius_m);
        }
    }
}

/// A kept sweep's returns in the map frame and the sensor's position there.
pub fn to_map(r: &Remap, base_from_lidar: &Isometry3<f64>) -> (Vec<[f32; 3]>, [f64; 3]) {
    let map_from_lidar = r.map_from_base * base_from_lidar;
    let m = map_from_lidar.cast::<f32>();
    let pts = r
        .points
        .iter()
        .map(|p| {
            let q = m * Point3::new(p[0], p[1], p[2]);
            [q.x, q.y, q.z]
        })
        .collect();
    let o = map_from_lidar.translation.vector;
    (pts, [o.x, o.y, o.z])
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use slam::se3;

    /// A return `x` metres ahead of the lidar.
    pub(in crate::terrain) fn pt(x: f32) -> Point {
        Point {
            x,
            y: 0.0,
            z: 0.0,
            intensity: 0.0,
            ring: 0,
            t_s: 0.0,
        }
    }

    #[test]
    fn keeps_by_spacing_and_rebuilds_only_when_something_moved() {
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 100.0);
        for i in 0..10 {
            let p = se3::from_xyz_rpy([0.2 * f64::from(i), 0.0, 0.0], [0.0; 3]);
            st.offer(
                f64::from(i),
                &p,
                &p,
                &[pt(1.0), pt(100.0), pt(f32::NAN)],
                false,
            );
        }
        // 0, 0.6, 1.2, 1.8 m: every third sweep.
        assert_eq!(st.len(), 4);
        assert_eq!(st.points(), 8, "non-finite returns are not kept");
        // The far return stays on its beam, restored at twice the range (the mapper's range
        // filter drops it there, its free space is the same).
        let far = st.after(None, 1)[0].points[1];
        assert!((far[0] - 60.0).abs() < 0.01 && far[1] == 0.0, "{far:?}");
        let ident = |_| Some(Isometry3::identity());
        assert_eq!(st.correct(ident, None), Correction::None);
        let shift = se3::from_xyz_rpy([0.0, 0.3, 0.0], [0.0; 3]);
        assert_eq!(st.correct(|_| Some(shift), None), Correction::Restart);
        let r = st.after(None, usize::MAX);
        assert_eq!(r.len(), 4);
        assert!((r[1].map_from_base.translation.y - 0.3).abs() < 1e-12);
        let (pts, o) = to_map(&r[1], &Isometry3::identity());
        assert!((pts[0][0] - 1.6).abs() < 1e-3 && (pts[0][1] - 0.3).abs() < 1e-3);
        assert!((o[1] - 0.3).abs() < 1e-12);
        // Mapped there now: the same correction again is nothing to rebuild.
        assert_eq!(st.correct(|_| Some(shift), None), Correction::None);
        // Kept at t = 0, 3, 6, 9. A rebuild that fed up to t = 6 goes on when only the newest
        // sweep moves...
        let late = se3::from_xyz_rpy([0.0, 0.5, 0.0], [0.0; 3]);
        let only_late = |t: f64| Some(if t > 7.0 { late } else { shift });
        assert_eq!(st.correct(only_late, Some(6.0)), Correction::Retarget);
        assert_eq!(st.after(Some(6.0), 9).len(), 1);
        assert!((st.after(Some(6.0), 9)[0].map_from_base.translation.y - 0.5).abs() < 1e-12);
        // ...and starts again when one it fed moved.
        assert_eq!(st.correct(|_| Some(late), Some(6.0)), Correction::Restart);
        assert_eq!(st.after(Some(0.0), 2).len(), 2, "at most n, after the time");
        // While a rebuild runs every sweep is kept; respaced, one every 0.5 m again.
        let bytes = st.bytes();
        for i in 10..20 {
            let p = se3::from_xyz_rpy([0.2 * f64::from(i), 0.0, 0.0], [0.0; 3]);
            assert!(st.offer(f64::from(i), &p, &p, &[pt(1.0)], true));
        }
        assert_eq!(st.len(), 14);
        // Kept at x = 0, 0.6, 1.2, 1.8, then 2.0 ... 3.8: 2.4, 3.0, 3.6 stay of the ten.
        assert_eq!(st.respace(), 7);
        assert_eq!(st.len(), 7);
        let xs: Vec<f64> = st
            .after(None, usize::MAX)
            .iter()
            .map(|r| r.map_from_base.translation.x)
            .collect();
        assert!(
            (xs[4] - 2.4).abs() < 1e-9 && (xs[6] - 3.6).abs() < 1e-9,
            "{xs:?}"
        );
        assert!(
            st.bytes() > bytes && st.bytes() < bytes + 3 * 250,
            "{}",
            st.bytes()
        );
    }

    #[test]
    fn only_tiles_a_moved_sweep_reaches_are_stale() {
        let lattice = Lattice {
            cell_size_m: 0.2,
            tile_cells: 64,
        };
        let edge = 12.8;
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 100.0);
        for i in 0..3 {
            // Sweeps at x = 0, 100, 200 m.
            let p = se3::from_xyz_rpy([100.0 * f64::from(i), 0.0, 0.0], [0.0; 3]);
            st.offer(f64::from(i), &p, &p, &[pt(1.0)], false);
        }
        assert!(
            st.stale_tiles(&lattice, 30.0).is_empty(),
            "nothing moved yet"
        );
        // The middle sweep moves 0.3 m sideways, the others stay.
        let mid = se3::from_xyz_rpy([0.0, 0.3, 0.0], [0.0; 3]);
        let c = st.correct(
            |t| Some(if t == 1.0 { mid } else { Isometry3::identity() }),
            None,
        );
        assert_eq!(c, Correction::Restart);
        let stale = st.stale_tiles(&lattice, 30.0);
        let tile = |x: f64, y: f64| {
            let (cx, cy) = lattice.cell_of(x, y);
            lattice.tile_of_cell(cx, cy).0
        };
        assert!(stale.contains(&tile(100.0, 0.0)));
        assert!(stale.contains(&tile(100.0, 29.0)));
        assert!(!stale.contains(&tile(100.0, 31.0 + edge)), "beyond reach");
        assert!(!stale.contains(&tile(0.0, 0.0)) && !stale.contains(&tile(200.0, 0.0)));
        // Every stale tile is within reach of the moved sweep, and there are not many.
        assert!(stale.len() <= 36, "{}", stale.len());
        st.swapped();
        assert!(
            st.stale_tiles(&lattice, 30.0).is_empty(),
            "the live map has it now"
        );
        // A turn of 0.05 deg about the first sweep moves points 0.05 m at 57 m, the middle
        // sweep moves on (a rebuild): within 30 m of the first nothing is stale, but tiles 60 m
        // out would be.
        let turn = se3::from_xyz_rpy([0.0; 3], [0.0, 0.0, 0.05_f64.to_radians()]);
        let mid2 = se3::from_xyz_rpy([0.0, 0.6, 0.0], [0.0; 3]);
        let c = st.correct(
            |t: f64| {
                Some(match t {
                    0.0 => turn,
                    1.0 => mid2,
                    _ => Isometry3::identity(),
                })
            },
            None,
        );
        assert_eq!(c, Correction::Restart);
        let stale = st.stale_tiles(&lattice, 30.0);
        assert!(stale.contains(&tile(100.0, 0.0)) && !stale.contains(&tile(0.0, 0.0)));
        let far = st.stale_tiles(&lattice, 70.0);
        assert!(far.contains(&tile(-64.0, 0.0)), "{far:?}");
        assert!(!far.contains(&tile(-20.0, 0.0)), "{far:?}");
    }

    #[test]
    fn quantised_returns_stay_within_half_a_step_and_the_cap_thins_the_oldest_half() {
        let step = NEAR_RANGE * 30.0 / Q_MAX;
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 1.0);
        let p0 = Isometry3::identity();
        let q = [0.123_456_f32, -29.99, 7.777];
        st.offer(0.0, &p0, &p0, &[pt(q[0]), pt(q[1]), pt(q[2])], false);
        let back = st.after(None, 1);
        for (k, &x) in q.iter().enumerate() {
            assert!((back[0].points[k][0] - x).abs() <= 0.5 * step + 1e-6);
        }
        assert!(st.bytes() < 250, "6 bytes a return and the three poses");
        // 2000 returns a sweep (12 kB): 1 MB holds about 80.
        let cloud: Vec<Point> = (0..2000).map(|i| pt(0.01 * i as f32)).collect();
        let mut st = SweepStore::new(0.5, 0.05, 30.0, 1.0);
        for i in 0..200 {
            let p = se3::from_xyz_rpy([f64::from(i), 0.0, 0.0], [0.0; 3]);
            assert!(st.offer(f64::from(i), &p, &p, &cloud, false));
            assert!(st.bytes() <= 1_000_000);
        }
        assert!(st.len() > 40 && st.len() < 100, "{}", st.len());
        assert_eq!(st.dropped() as usize + st.len(), 200);
        let kept: Vec<f64> = st.after(None, usize::MAX).iter().map(|r| r.t_s).collect();
        assert_eq!(*kept.last().unwrap(), 199.0, "the newest stays");
        // Spacing grows towards the oldest end.
        let gap = |w: &[f64]| w[1] - w[0];
        assert!(gap(&kept[..2]) >= gap(&kept[kept.len() - 2..]));
        // A catch-up's sweeps are held on top of the cap, which applies again once respaced.
        let (len, dropped) = (st.len(), st.dropped());
        for i in 200..230 {
            let p = se3::from_xyz_rpy([f64::from(i), 0.0, 0.0], [0.0; 3]);
            assert!(st.offer(f64::from(i), &p, &p, &cloud, true));
        }
        assert_eq!((st.len(), st.dropped()), (len + 30, dropped));
        assert!(st.bytes() > 1_000_000);
        assert_eq!(st.respace(), 0, "1 m apart: none too close");
        assert!(st.bytes() <= 1_000_000 && st.dropped() > dropped);
    }
}

//! Revisits (docs/algorithms.md §4.13): ground seen in an earlier visit carries that visit's
//! heights, and by the time the robot is back its frame has moved under them. GNSS and gravity
//! corrections move the stored map with the frame ([`Mapper::follow_frame`]), but rigidly, about
//! wherever the robot was: over a 350 m loop they left the start's ground 8 cm above where the
//! same frame sees it again. New and old evidence then stand apart by that much in neighbouring
//! cells, and the step rules read ring-shaped stripes of false steps into open ground.
//!
//! So each sweep measures the offset itself. A cell belongs to an earlier visit when nothing
//! from within the processing distance reached it for `revisit_gap_s` (far glimpses on the way
//! back do not make it current). The sweep's ground cells within the processing distance that
//! hold such evidence, in epochs that ended before the gap and were seen from within the
//! processing distance, give one height difference each (none beyond 0.3 m: a changed scene),
//! kept for the last few sweeps (the cells come within reach a few at a time), one per cell.
//! Samples that do not agree on one offset (spread over 3 cm, or under three quarters near
//! their median) fit none. A plane through them (robust: the median first,
//! then the cells within three spreads of it) is the old map's offset from the current frame
//! around the robot; its tilt counts only where the cells pin it, else the median
//! alone, and an offset within three standard errors of zero is none. The old epochs of every
//! earlier visit's cell within reach (the processing distance and the rules' neighbourhood) are
//! moved by it before the sweep is merged, and the cell counts as current from then on. The
//! plane stays in use for the cells that come within reach in the next sweeps until
//! `revisit_gap_s` after its last fit, and keeps being refitted along the way: a cell it made
//! current before any sweep sampled it is still sampled once, against its old epochs as they
//! were (`plane_shift_m`), and a refit needs only [`REFIT_MIN_CELLS`]. Cells seen again from
//! close by in the sweeps before the fit (it waits for `revisit_min_cells` samples) are moved by
//! it too, within [`CATCH_UP_S`].
//! Only epochs nearer in time to the sampled visit than to the fit move: a far glimpse taken on
//! the way back is in the current frame already, however long ago.
//! A move places the moved epochs in the frame of the move (`CellData::awaits_offset`): a
//! cell moved without a sight of it counts as an earlier visit's again after the gap, but only
//! a fit measured against epochs from before the move (a later visit) moves it again.

use super::cell_data::Moments;
use super::{largest_at_corners, norm2, Evidence, Mapper, RobotPose, UpdateReport};

/// Offsets smaller than this everywhere within reach are not applied, metres: below what any
/// step test can tell (`grass_sd_min_m` is 8 mm); the cells still count as current.
const MIN_SHIFT_M: f64 = 0.005;

/// A fitted plane steeper than this is not trusted, radians (0.17 deg: twice the robot's
/// usual attitude error, already 3.6 cm at the processing distance).
const MAX_TILT_RAD: f64 = 0.003;

/// Nor one whose slopes' standard error is larger than this, radians (1.2 cm at the
/// processing distance): the cells lie on too narrow a strip to pin a tilt.
const MAX_TILT_SE_RAD: f64 = 0.001;

/// A height difference larger than this is something that changed, not the frame's drift
/// between the visits, metres.
const MAX_SAMPLE_M: f64 = 0.3;

/// The samples' robust spread (1.4826 MAD) above which they measure no one offset, metres: a
/// frame offset moves flat ground alike, so its samples agree to the ground's own roughness.
const MAX_SAMPLE_SPREAD_M: f64 = 0.03;

/// Share of the samples that must agree with their median (within three spreads) for an
/// offset to be fitted.
const MIN_AGREEING: f64 = 0.75;

/// Samples are kept this long for the offset fit, seconds: a few sweeps' worth, so the cells
/// that come within reach one sweep at a time are enough to follow the offset along the way.
const SAMPLE_WINDOW_S: f64 = 3.0;

/// An earlier visit's cell made current by evidence from close by before an offset was fitted
/// is still moved by one fitted this long after, seconds: the first samples come a cell at a
/// time, and the fit waits for `revisit_min_cells` of them (on `loop`, cells first seen again
/// at 368.3 s met the fit of 373 s; left unmoved, their old epochs stood 10 cm above the new ones
/// as false obstacles).
const CATCH_UP_S: f32 = 10.0;

/// While a fitted plane is in use, a refit along the way needs only this many samples: it
/// follows an offset `revisit_min_cells` samples established, and once the cells within reach
/// are aligned only the leading edge of the reach brings new ones, a few per sweep. Before
/// refits (and the sampling of cells a plane made current), the plane of one fit served for
/// `revisit_gap_s` after it: on `loop` with the graph on, one fitted at -0.115 m moved cells
/// 27 m further on by that much where the offset had drifted to -0.075 m, and the 4 cm between
/// them and their neighbours read as steps.
const REFIT_MIN_CELLS: usize = 12;

/// One sample of the offset: a ground cell (lattice index, and its centre in the map frame,
/// metres), its height in the sweep less the earlier visit's (metres), and the sweep's time
/// (seconds).
#[derive(Clone, Copy, Debug)]
pub(super) struct Sample {
    cell: (i64, i64),
    x_m: f64,
    y_m: f64,
    dz_m: f64,
    t_s: f64,
    /// The newest of the earlier visit's epochs the difference was taken against.
    old_epoch: i64,
}

/// The old map's height offset from the current frame: `dz = a + b (x - x0) + c (y - y0)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct RevisitOffset {
    /// Where the plane was fitted (the robot), map frame, metres.
    x0: f64,
    y0: f64,
    a: f64,
    b: f64,
    c: f64,
    /// Session time of the fit, seconds.
    t_s: f64,
    /// The newest epoch the offset applies to: halfway from the samples' newest old epoch to
    /// the fit. An epoch nearer in time to the earlier visit shares its frame's offset; one
    /// nearer to now (a far glimpse on the way back, within the processing distance only now)
    /// is in the current frame, however long ago it was taken.
    until_epoch: i64,
}

impl RevisitOffset {
    fn dz(&self, x: f64, y: f64) -> f64 {
        self.a + self.b * (x - self.x0) + self.c * (y - self.y0)
    }
}

impl Mapper {
    /// Measures this sweep's offset against an earlier visit's ground and moves that visit's
    /// cells within reach onto the current frame (see the module docs). Runs after binning and
    /// before the evidence is merged; the moved cells within the processing distance are pushed
    /// onto `dirty`.
    pub(super) fn align_revisit(
        &mut self,
        robot: &RobotPose,
        t_s: f64,
        kind: Evidence,
        dirty: &mut Vec<(i64, i64)>,
        rep: &mut UpdateReport,
    ) {
        let gap_s = self.cfg.revisit_gap_s;
        if kind != Evidence::Scan || gap_s <= 0.0 {
            return;
        }
        self.sample_revisit(robot, t_s);
        if let Some(fit) = self.fit_revisit(robot, t_s) {
            rep.revisit_pairs = fit.1;
            self.revisit = Some(fit.0);
        }
        let Some(off) = self.revisit_in_use(t_s) else {
            self.revisit = None;
            return;
        };
        let reach_m = self.cfg.processing_distance_m + 2.0 * self.cfg.grid_size_m;
        let shift =
            largest_at_corners(robot.x_m, robot.y_m, reach_m, |x, y| off.dz(x, y)) > MIN_SHIFT_M;
        let (rcx, rcy) = self.lattice.cell_of(robot.x_m, robot.y_m);
        let r = (reach_m / self.cfg.grid_size_m).ceil() as i64;
        let pd = self.cfg.processing_distance_m;
        let t = t_s as f32;
        let gap = gap_s as f32;
        let before = self.epoch_before(t_s);
        let now = self.epoch_of(t_s);
        for cy in rcy - r..=rcy + r {
            for cx in rcx - r..=rcx + r {
                let (x, y) = self.center_m(cx, cy);
                let dist = norm2(x - robot.x_m, y - robot.y_m);
                if dist > reach_m {
                    continue;
                }
                let old = self.data(cx, cy).is_some_and(|d| {
                    (d.is_earlier_visit(t, gap, before) || t - d.unaligned_s <= CATCH_UP_S)
                        && d.awaits_offset(before, off.until_epoch)
                });
                if !old {
                    continue;
                }
                let d = self.data_mut(cx, cy);
                d.current_s = t;
                d.unaligned_s = f32::NEG_INFINITY;
                // Most cells are made current here before any sweep sampled them (beyond the
                // processing distance, or unseen this sweep); they are still sampled once.
                let dz = if shift { off.dz(x, y) } else { 0.0 };
                d.plane_shift_m = dz as f32;
                if shift {
                    // Only the earlier visit's epochs: far glimpses taken on the way back are
                    // in the current frame already.
                    let moved = before.min(off.until_epoch);
                    d.shift_epochs_before(moved, dz);
                    d.aligned = (d.aligned.0.max(moved), now);
                    self.refresh_ground(cx, cy);
                    rep.revisit_moved += 1;
                    if dist <= pd {
                        dirty.push((cx, cy));
                    }
                }
            }
        }
    }

    /// The fitted plane, while it is in use: until `revisit_gap_s` after its last fit.
    fn revisit_in_use(&self, t_s: f64) -> Option<RevisitOffset> {
        self.revisit
            .filter(|o| t_s - o.t_s <= self.cfg.revisit_gap_s)
    }

    /// The newest evidence epoch that ended more than `revisit_gap_s` before `t_s`.
    pub(super) fn epoch_before(&self, t_s: f64) -> i64 {
        self.epoch_of(t_s - self.cfg.revisit_gap_s) - 1
    }

    /// Adds this sweep's samples: one per ground cell within the processing distance that
    /// holds an earlier visit's ground seen from within it too (the height difference, sweep
    /// minus old epochs), and forgets those older than [`SAMPLE_WINDOW_S`].
    fn sample_revisit(&mut self, robot: &RobotPose, t_s: f64) {
        let pd = self.cfg.processing_distance_m;
        let max_var = self.cfg.max_variance_m2;
        let min_n = self.rules.min_points();
        let (t, gap) = (t_s as f32, self.cfg.revisit_gap_s as f32);
        let before = self.epoch_before(t_s);
        while self
            .revisit_samples
            .front()
            .is_some_and(|s| t_s - s.t_s > SAMPLE_WINDOW_S)
        {
            self.revisit_samples.pop_front();
        }
        let mut sampled: Vec<(i64, i64)> = Vec::new();
        for &i in &self.win.touched {
            let low: Moments = self.win.low[i];
            if low.n < 2 {
                continue;
            }
            let (cx, cy) = self.win.global(i);
            let (x, y) = self.center_m(cx, cy);
            if norm2(x - robot.x_m, y - robot.y_m) > pd {
                continue;
            }
            let Some(d) = self.data(cx, cy) else { continue };
            // What a plane moved the old epochs by, for a cell it made current before this
            // sample: sampled against the old epochs as they were, so the fit keeps measuring
            // along the way instead of serving one plane for `revisit_gap_s`. (A cell whose old
            // epochs include a glimpse the plane did not move gets a wrong sample; the fit's
            // robust spread drops the few there are.)
            let unshift = f64::from(d.plane_shift_m);
            if t - d.current_s <= gap && t - d.unaligned_s > CATCH_UP_S && unshift.is_nan() {
                continue;
            }
            let unshift = if unshift.is_nan() { 0.0 } else { unshift };
            // A far view's heights carry its attitude error times its range: the old visit's
            // offset is measured on what it saw well.
            let (old, seen_m) = d.epochs_before(before);
            if seen_m > pd as f32 {
                continue;
            }
            let Some(old_epoch) = d.newest_epoch_before(before) else {
                continue;
            };
            sampled.push((cx, cy));
            let (old, new) = (old.stats(), low.stats());
            let old_mean = old.mean_m - unshift;
            if old.n < min_n
                || old.var_m2 > max_var
                || new.var_m2 > max_var
                || (new.mean_m - old_mean).abs() > MAX_SAMPLE_M
            {
                continue;
            }
            self.revisit_samples.push_back(Sample {
                cell: (cx, cy),
                x_m: x,
                y_m: y,
                dz_m: new.mean_m - old_mean,
                t_s,
                old_epoch,
            });
        }
        for (cx, cy) in sampled {
            self.data_mut(cx, cy).plane_shift_m = f32::NAN;
        }
    }

    /// The offset plane through the samples of the last sweeps (see [`Mapper::sample_revisit`]),
    /// and how many it rests on; None with fewer than `revisit_min_cells`. The plane's tilt is
    /// used only when the samples pin it (standard error under [`MAX_TILT_SE_RAD`]) and it
    /// stays under [`MAX_TILT_RAD`], else the median alone; an offset within three standard
    /// errors of zero is zero.
    fn fit_revisit(&self, robot: &RobotPose, t_s: f64) -> Option<(RevisitOffset, usize)> {
        // One sample per cell, its newest: a cell whose evidence the far-view rule keeps out
        // is sampled again every sweep, and a few such cells (a car parked since, seen from
        // 12 m) would outvote the ground.
        let mut newest: Vec<&Sample> = self.revisit_samples.iter().rev().collect();
        newest.sort_by_key(|s| s.cell);
        newest.dedup_by_key(|s| s.cell);
        let in_use = self.revisit_in_use(t_s);
        let min_cells = if in_use.is_some() {
            REFIT_MIN_CELLS.min(self.cfg.revisit_min_cells)
        } else {
            self.cfg.revisit_min_cells
        };
        if newest.len() < min_cells.max(4) {
            return None;
        }
        let mut pairs: Vec<(f64, f64, f64)> = newest
            .iter()
            .map(|s| (s.x_m - robot.x_m, s.y_m - robot.y_m, s.dz_m))
            .collect();
        let mut v: Vec<f64> = pairs.iter().map(|p| p.2).collect();
        let med = median(&mut v);
        let mut dev: Vec<f64> = pairs.iter().map(|p| (p.2 - med).abs()).collect();
        let sigma = 1.4826 * median(&mut dev);
        let all = pairs.len();
        let agrees = |dz: f64| (dz - med).abs() <= (3.0 * sigma).max(0.02);
        pairs.retain(|p| agrees(p.2));
        let newest_old = newest
            .iter()
            .filter(|s| agrees(s.dz_m))
            .map(|s| s.old_epoch)
            .max()?;
        let now = self.epoch_of(t_s);
        // A refit follows the same earlier visit: which epochs belong to it was settled by the
        // fit that established the plane. Cells sampled after a plane made them current may
        // hold a later glimpse among their old epochs, which would drag the boundary forward
        // over glimpses taken on the way back.
        let until_epoch = match in_use {
            Some(o) => o.until_epoch,
            None => newest_old + (now - newest_old) / 2,
        };
        // A frame offset moves all the ground alike; samples that disagree more than that
        // are a changed scene (a car parked, a trunk fallen), not the frame.
        if sigma > MAX_SAMPLE_SPREAD_M || (pairs.len() as f64) < MIN_AGREEING * all as f64 {
            return None;
        }
        let n = pairs.len() as f64;

        let (b, c, a) = fit_plane(&pairs)
            .filter(|p| p.tilt_se <= MAX_TILT_SE_RAD && p.b.hypot(p.c) <= MAX_TILT_RAD)
            .map(|p| (p.b, p.c, p.a))
            .unwrap_or_else(|| {
                // The median's standard error, for a normal spread: 1.2533 sigma / sqrt(n).
                let se = 1.2533 * sigma / n.sqrt();
                (0.0, 0.0, if med.abs() > 3.0 * se { med } else { 0.0 })
            });
        Some((
            RevisitOffset {
                x0: robot.x_m,
                y0: robot.y_m,
                a,
                b,
                c,
                t_s,
                until_epoch,
            },
            pairs.len(),
        ))
    }
}

/// The median of `v` (reordered); `v` must not be empty.
pub(super) fn median(v: &mut [f64]) -> f64 {
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

/// A least-squares plane `z = b x + c y + a`, with the larger standard error of its two
/// slopes (radians).
#[derive(Clone, Copy, Debug)]
struct Plane {
    a: f64,
    b: f64,
    c: f64,
    tilt_se: f64,
}

/// The least-squares plane through `(x, y, z)`; None when the points do not pin it.
fn fit_plane(p: &[(f64, f64, f64)]) -> Option<Plane> {
    if p.len() < 4 {
        return None;
    }
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    for &(x, y, z) in p {
        let v = nalgebra::Vector3::new(x, y, 1.0);
        m += v * v.transpose();
        r += v * z;
    }
    let chol = m.cholesky()?;
    let s = chol.solve(&r);
    let rss: f64 = p
        .iter()
        .map(|&(x, y, z)| (z - s.x * x - s.y * y - s.z).powi(2))
        .sum();
    let var = rss / (p.len() - 3) as f64;
    let cov = chol.inverse() * var;
    let tilt_se = cov[(0, 0)].max(cov[(1, 1)]).sqrt();
    (s.iter().all(|v| v.is_finite()) && tilt_se.is_finite()).then_some(Plane {
        a: s.z,
        b: s.x,
        c: s.y,
        tilt_se,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plane_fit_recovers_an_offset_and_a_tilt() {
        let pts: Vec<(f64, f64, f64)> = (0..50)
            .map(|k| {
                let (x, y) = ((k % 10) as f64 - 5.0, (k / 10) as f64 * 2.0 - 5.0);
                (x, y, 0.08 + 0.002 * x - 0.001 * y)
            })
            .collect();
        let p = fit_plane(&pts).unwrap();
        assert!((p.a - 0.08).abs() < 1e-9 && (p.b - 0.002).abs() < 1e-9);
        assert!((p.c + 0.001).abs() < 1e-9 && p.tilt_se < 1e-9, "{p:?}");
        assert!(fit_plane(&pts[..3]).is_none());
        let line: Vec<_> = (0..10).map(|k| (k as f64, 0.0, 0.1)).collect();
        assert!(fit_plane(&line).is_none(), "collinear points pin no tilt");
    }

    #[test]
    fn the_median_is_the_middle_value() {
        assert_eq!(median(&mut [3.0, -1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [5.0]), 5.0);
    }
}

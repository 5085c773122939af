//! Evidence (docs/algorithms.md §4.1-4.3 and §4.5: the source's steps 1-3 and 6, with the project's
//! additions): a sweep's points through the height and isolated-point filters, binned under each
//! cell's ceiling `h_max2`, split into ground and possible stray points, and merged into the cells'
//! two evidence epochs; the robot's footprint as evidence of drivable ground.

use super::cell_data::Moments;
use super::fast_hash::FastMap;
use super::{norm2, Evidence, Mapper, RobotPose, UpdateReport, CEILING_HINT_MARGIN_M};
use crate::filters;

/// Points this far above their cell's lowest return in the sweep go through the isolated-point
/// filter; lower ones are ground and cannot raise an obstacle on their own, metres.
const SUSPECT_ABOVE_M: f32 = 0.04;

/// A cell's stored returns standing this much above the sweep's ceiling for it came in under a
/// ceiling set before the ground below was known, metres: well above the few centimetres the
/// ground under a ceiling moves from sweep to sweep.
const CEILING_WIPE_MARGIN_M: f32 = 0.3;

/// The attitude error a view from afar may carry, radians (0.29 deg): the largest height
/// difference an older far epoch may show against a much closer view and still be taken for the
/// same ground seen worse (see `merge_evidence`).
const FAR_ATTITUDE_RAD: f64 = 0.005;

impl Mapper {
    /// Steps 1-2: drops the points above the climb cone or out of range around the robot, then
    /// isolated points among those standing above their cell's lowest return this sweep.
    pub(super) fn filter_points(
        &mut self,
        pts: &mut Vec<[f32; 3]>,
        robot: &RobotPose,
        rep: &mut UpdateReport,
    ) {
        rep.dropped_height = filters::height_filter(
            pts,
            [robot.x_m, robot.y_m, robot.z_m],
            self.cfg.h_r_m,
            self.cfg.phi_max_deg.to_radians(),
            self.cfg.max_range_m,
        );
        // Only points above their cell's lowest return this sweep are worth testing.
        let li: Vec<Option<usize>> = pts
            .iter()
            .map(|p| {
                let (cx, cy) = self.cell_of(f64::from(p[0]), f64::from(p[1]));
                self.win.local(cx, cy)
            })
            .collect();
        for (p, l) in pts.iter().zip(&li) {
            if let Some(i) = *l {
                if self.win.zmin[i] == f32::INFINITY {
                    self.win.touched.push(i);
                }
                self.win.zmin[i] = self.win.zmin[i].min(p[2]);
            }
        }
        let test: Vec<bool> = pts
            .iter()
            .zip(&li)
            .map(|(p, l)| l.is_none_or(|i| p[2] > self.win.zmin[i] + SUSPECT_ABOVE_M))
            .collect();
        rep.dropped_isolated =
            filters::isolated_point_filter_where(pts, &self.cfg.isolated_pairs, &test);
        for &i in &self.win.touched {
            self.win.zmin[i] = f32::INFINITY;
        }
        self.win.touched.clear();
    }

    /// Step 3: bins the points into the scratch window under each cell's ceiling, as ground
    /// (`low`) or, in scan mode, as possible stray points standing more than `stray_height_m`
    /// above the cell's ground (`high`).
    pub(super) fn bin_points(
        &mut self,
        pts: &[[f32; 3]],
        kind: Evidence,
        ground_hint: Option<&Mapper>,
        rep: &mut UpdateReport,
    ) {
        let mut cells_of = Vec::with_capacity(pts.len());
        for p in pts {
            let (cx, cy) = self.cell_of(f64::from(p[0]), f64::from(p[1]));
            let li = self.win.local(cx, cy);
            cells_of.push(li);
            if let Some(i) = li {
                if self.win.zmin[i] == f32::INFINITY {
                    self.win.touched.push(i);
                }
                self.win.zmin[i] = self.win.zmin[i].min(p[2]);
            }
        }
        self.win.touched.sort_unstable();
        self.compute_ceilings(ground_hint);
        let stray_on = kind == Evidence::Scan && self.cfg.stray_height_m > 0.0;
        // The ground reference for stray points: the lowest point in the cell this scan, or the
        // ground the cell already showed, whichever is lower.
        let mut ref_z: FastMap<usize, f32> = FastMap::default();
        if stray_on {
            for &i in &self.win.touched {
                let (cx, cy) = self.win.global(i);
                let mut r = self.win.zmin[i];
                if let Some(d) = self.data(cx, cy) {
                    let e = d.evidence().stats();
                    if e.n >= self.rules.min_points() {
                        r = r.min(e.mean_m as f32);
                    }
                }
                ref_z.insert(i, r);
            }
        }
        for (p, li) in pts.iter().zip(&cells_of) {
            let Some(i) = *li else { continue };
            if p[2] > self.win.ceiling[i] {
                rep.dropped_ceiling += 1;
                continue;
            }
            let high = stray_on
                && ref_z
                    .get(&i)
                    .is_some_and(|r| p[2] > r + self.cfg.stray_height_m as f32);
            if high {
                self.win.high[i].add(f64::from(p[2]));
            } else {
                self.win.low[i].add(f64::from(p[2]));
            }
        }
    }

    /// The ceiling `h_max2` of every touched cell: the lowest ground within
    /// `ceiling_radius_cells`, from this sweep or (where this sweep's rings left a gap) from what
    /// the cells showed before, plus `h_r` and the climb allowance to that cell. Without the stored
    /// ground a tree canopy between two rings would set its own ceiling and come in as an obstacle.
    /// `ground_hint`'s ground counts as stored ground too, [`CEILING_HINT_MARGIN_M`] higher
    /// ([`Mapper::update_sweep_under`]).
    fn compute_ceilings(&mut self, ground_hint: Option<&Mapper>) {
        let r = i64::from(self.cfg.ceiling_radius_cells);
        let tan_phi = self.cfg.phi_max_deg.to_radians().tan() as f32;
        let l = self.cfg.grid_size_m as f32;
        let h_r = self.cfg.h_r_m as f32;
        let side = self.win.side as i64;
        let mut looked_up: Vec<usize> = Vec::new();
        // The climb allowance per offset, once.
        let span = (2 * r + 1) as usize;
        let cone: Vec<f32> = (0..span * span)
            .map(|k| {
                let (dx, dy) = ((k % span) as i64 - r, (k / span) as i64 - r);
                tan_phi * l * ((dx * dx + dy * dy) as f32).sqrt()
            })
            .collect();
        for k in 0..self.win.touched.len() {
            let i = self.win.touched[k];
            let (x, y) = ((i as i64) % side, (i as i64) / side);
            let mut best = f32::INFINITY;
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= side {
                    continue;
                }
                let row = ((dy + r) as usize) * span;
                for dx in -r..=r {
                    let xx = x + dx;
                    if xx < 0 || xx >= side {
                        continue;
                    }
                    let j = (yy * side + xx) as usize;
                    let mut sg = self.win.stored_ground[j];
                    if sg.is_nan() {
                        let (cx, cy) = self.win.global(j);
                        sg = self.ground(cx, cy);
                        if let Some(h) = ground_hint {
                            sg = sg.min(h.ground(cx, cy) + CEILING_HINT_MARGIN_M);
                        }
                        self.win.stored_ground[j] = sg;
                        looked_up.push(j);
                    }
                    let z = self.win.zmin[j].min(sg);
                    best = best.min(z + cone[row + (dx + r) as usize]);
                }
            }
            self.win.ceiling[i] = best + h_r;
        }
        for j in looked_up {
            self.win.stored_ground[j] = f32::NAN;
        }
    }

    /// The index of the evidence epoch (`evidence_epoch_s` long) that holds session time `t_s`.
    pub(super) fn epoch_of(&self, t_s: f64) -> i64 {
        (t_s / self.cfg.evidence_epoch_s).floor() as i64
    }

    /// Merges the binned sweep into the cells' evidence and pushes the cells it changed onto
    /// `dirty`. `beams`: the sweep came with its origin (free space was marched); without, a
    /// cell's points are taken as having headroom.
    pub(super) fn merge_evidence(
        &mut self,
        robot: &RobotPose,
        t_s: f64,
        kind: Evidence,
        beams: bool,
        dirty: &mut Vec<(i64, i64)>,
        rep: &mut UpdateReport,
    ) {
        let epoch = self.epoch_of(t_s);
        let stamp = stamp_of(t_s);
        let scan = self.scan_id;
        let (gap_s, before) = (self.cfg.revisit_gap_s as f32, self.epoch_before(t_s));
        let revisit_on = kind == Evidence::Scan && gap_s > 0.0;
        let touched = std::mem::take(&mut self.win.touched);
        dirty.reserve(touched.len());
        for &i in &touched {
            let (low, high) = (self.win.low[i], self.win.high[i]);
            if low.n == 0 && high.n == 0 {
                continue;
            }
            let (cx, cy) = self.win.global(i);
            let (ccx, ccy) = self.center_m(cx, cy);
            let range_m = norm2(ccx - robot.x_m, ccy - robot.y_m) as f32;
            // Returns a ceiling now drops were taken in under one set before the ground below
            // was known: a canopy seen with no ring on the ground beneath it set its own ceiling
            // and became the cell's surface. The evidence is running moments, so they cannot be
            // taken out alone: the cell starts again from this sweep's points.
            let ceiling = self.win.ceiling[i];
            let wiped = kind == Evidence::Scan
                && self.data(cx, cy).is_some_and(|d| {
                    let e = d.evidence();
                    e.n > 0 && e.zmax > ceiling + CEILING_WIPE_MARGIN_M
                });
            if wiped {
                // The stored ground follows below, with the sweep's points merged (`wiped`).
                let far = f64::from(range_m) > self.cfg.processing_distance_m;
                self.data_mut(cx, cy).drop_evidence(far);
                self.suspect_canopy_verdicts(cx, cy);
                rep.ceiling_wiped += 1;
            }
            let far_factor = self.cfg.far_evidence_factor as f32;
            let min_n = self.rules.min_points();
            let stale_s = self.cfg.evidence_stale_s as f32;
            let grows = self.cfg.max_step_m as f32;
            // A cell seen well from close by keeps that view against much poorer ones from far
            // away (the moving vantage would otherwise let a sparse far glimpse replace a curb
            // seen at 3 m). Changes are still caught: things that went by free space, things
            // that came by the far view showing points higher (or lower) than anything the cell
            // and its neighbours held, anything once the close view is `evidence_stale_s` old.
            // Against the closest view the cell ever took (since a wipe), not the held epochs':
            // as the robot drives away each epoch is a little farther than the one before and
            // passes, and the close view would creep out to 12 m one epoch at a time.
            let far = self.data(cx, cy).is_some_and(|d| {
                kind == Evidence::Scan
                    && d.cur.n > 0
                    && range_m > far_factor * d.closest_view_m() + 1.0
                    && (t_s as f32) - d.accepted_s < stale_s
            }) && !self.far_news(cx, cy, &low.merged(&high), grows);
            if far {
                rep.far_skipped += 1;
                continue;
            }
            let close = f64::from(range_m) <= self.cfg.processing_distance_m;
            let d = self.data_mut(cx, cy);
            d.accepted_s = t_s as f32;
            if close {
                // The revisit's offset is fitted a few sweeps after the first samples: an
                // earlier visit's cell seen again before then still gets it (`align_revisit`).
                if revisit_on && d.is_earlier_visit(t_s as f32, gap_s, before) {
                    d.unaligned_s = t_s as f32;
                }
                d.current_s = t_s as f32;
            }
            let changed = match kind {
                Evidence::MapCloud => {
                    let m = low.merged(&high);
                    if m == d.last_cloud {
                        false
                    } else {
                        d.last_cloud = m;
                        d.cur = m;
                        d.cur_range_m = range_m;
                        d.prev = Moments::default();
                        d.prev_range_m = f32::INFINITY;
                        true
                    }
                }
                Evidence::Scan => {
                    let mut add = low;
                    if high.n > 0 {
                        if d.pending.n > 0 && d.pending_scan != scan {
                            // Seen again in a later scan: not a stray point.
                            add = add.merged(&d.pending).merged(&high);
                            d.pending = Moments::default();
                        } else {
                            d.pending = high;
                            d.pending_scan = scan;
                            rep.held_stray += high.n as usize;
                        }
                    } else {
                        d.pending = Moments::default();
                    }
                    if add.n > 0 {
                        if epoch > d.epoch || d.cur.n == 0 {
                            d.prev = d.cur;
                            d.prev_range_m = d.cur_range_m;
                            d.prev_epoch = d.epoch;
                            d.cur = Moments::default();
                            d.cur_range_m = f32::INFINITY;
                            d.epoch = epoch;
                        }
                        d.cur = d.cur.merged(&add);
                        d.cur_range_m = d.cur_range_m.min(range_m);
                        d.seen_range_m = d.seen_range_m.min(range_m);
                        // The mirror of the far-view rule: an older epoch seen only from so far
                        // that this view would have kept it out gives way once this one holds
                        // enough returns. Its heights carry its attitude error times its range,
                        // and its lowest return would set the cell's ground beside neighbours
                        // seen from close by (on `loop` a 3-return epoch from 28 m stood 10 cm
                        // under a 19-return one from 13 m, beyond the revisit's reach). Only
                        // while the two differ by no more than the far view's attitude error
                        // can explain: beside a 0.5 m box a close view sees only its top in the
                        // edge cells, and the ground a far view saw there is the box's edge (on
                        // `loop`, dropping it lost 4 cells of the box).
                        if d.prev.n > 0
                            && d.cur.n >= min_n
                            && d.prev_range_m > far_factor * d.cur_range_m + 1.0
                            && (d.prev.stats().mean_m - d.cur.stats().mean_m).abs()
                                <= FAR_ATTITUDE_RAD * f64::from(d.prev_range_m)
                        {
                            d.prev = Moments::default();
                            d.prev_range_m = f32::INFINITY;
                            rep.far_superseded += 1;
                        }
                    }
                    add.n > 0
                }
            };
            if !beams {
                // No beams to judge by: a map cloud's cells are taken as they come.
                d.headroom = true;
            }
            if d.last_scan != scan {
                d.last_scan = scan;
                d.hits = d.hits.saturating_add(1);
            }
            d.stamp_s = stamp;
            if changed || wiped {
                self.refresh_ground(cx, cy);
                dirty.push((cx, cy));
            }
        }
        self.win.touched = touched;
    }

    /// After a ceiling wipe of `(cx, cy)`: the obstacle verdicts that read its evidence (the
    /// cell's and those in its 5 x 5) may rest on the canopy it held, judged as neighbour steps
    /// against it; they forget where they were judged from, and are marked `canopy_suspect` for
    /// the far rules. On `loop` a canopy 12 m from the path made a 22-cell blob of such verdicts
    /// on ground the rules found level once the canopy cell was wiped from 19 m, beyond the
    /// processing distance, where far evidence does not clear a close verdict.
    fn suspect_canopy_verdicts(&mut self, cx: i64, cy: i64) {
        for dy in -2..=2 {
            for dx in -2..=2 {
                let (nx, ny) = (cx + dx, cy + dy);
                let obstacle = self
                    .data(nx, ny)
                    .is_some_and(|d| d.class == crate::classify::Class::Obstacle);
                if obstacle || (dx, dy) == (0, 0) {
                    let d = self.data_mut(nx, ny);
                    d.canopy_suspect = true;
                    d.class_range_m = f32::INFINITY;
                }
            }
        }
    }

    /// Whether a far view's points for cell `(cx, cy)` show something new: a top more than
    /// `grows_m` above the highest point the cell and its 8 neighbours hold, or a bottom more than
    /// `grows_m` below their lowest (a cover gone from a hole). Against the neighbourhood, not the
    /// cell alone: from afar, a few returns off a known step's face land in the cell in front of
    /// it (the far view's few-centimetre pose and beam offsets), which stand above that cell's
    /// own top but not above the step it belongs to; a person or a car stepping in stands above
    /// both.
    fn far_news(&self, cx: i64, cy: i64, incoming: &Moments, grows_m: f32) -> bool {
        let (mut top, mut bottom) = (f32::NEG_INFINITY, f32::INFINITY);
        for dy in -1..=1 {
            for dx in -1..=1 {
                if let Some(d) = self.data(cx + dx, cy + dy) {
                    let e = d.evidence();
                    if e.n > 0 {
                        top = top.max(e.zmax);
                        bottom = bottom.min(e.zmin);
                    }
                }
            }
        }
        incoming.zmax > top + grows_m || incoming.zmin < bottom - grows_m
    }

    /// Step 6a, proprioception: the footprint is traversable ground at the robot's height. Cells
    /// newly driven (or driven at another height) are pushed onto `dirty`.
    pub(super) fn drive_footprint(
        &mut self,
        robot: &RobotPose,
        t_s: f64,
        dirty: &mut Vec<(i64, i64)>,
    ) {
        let stamp = stamp_of(t_s);
        for (cx, cy) in self.footprint_cells(robot) {
            let d = self.data_mut(cx, cy);
            if !d.driven || (d.driven_z - robot.z_m as f32).abs() > 0.01 {
                d.driven = true;
                d.driven_z = robot.z_m as f32;
                d.current_s = t_s as f32;
                d.stamp_s = stamp;
                self.refresh_ground(cx, cy);
                dirty.push((cx, cy));
            }
        }
    }

    /// The cells whose centres lie under the robot's footprint rectangle.
    fn footprint_cells(&self, robot: &RobotPose) -> Vec<(i64, i64)> {
        let (hl, hw) = (
            self.cfg.footprint_length_m / 2.0,
            self.cfg.footprint_width_m / 2.0,
        );
        if hl <= 0.0 || hw <= 0.0 {
            return Vec::new();
        }
        let (c, s) = (robot.yaw_rad.cos(), robot.yaw_rad.sin());
        let rad = hl.hypot(hw);
        let (x0, y0) = self.lattice.cell_of(robot.x_m - rad, robot.y_m - rad);
        let (x1, y1) = self.lattice.cell_of(robot.x_m + rad, robot.y_m + rad);
        let mut out = Vec::new();
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                let (px, py) = self.center_m(cx, cy);
                let (dx, dy) = (px - robot.x_m, py - robot.y_m);
                let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
                if u.abs() <= hl && v.abs() <= hw {
                    out.push((cx, cy));
                }
            }
        }
        out
    }
}

/// A cell's stamp for an update at `t_s`: whole seconds, clamped into `u32`.
pub(super) fn stamp_of(t_s: f64) -> u32 {
    t_s.max(0.0).min(f64::from(u32::MAX)) as u32
}

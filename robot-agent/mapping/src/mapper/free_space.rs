//! Free space (beyond the source): the beams of a sweep crossing the band the robot's body needs
//! above each cell's ground. A cell crossed there has headroom (nothing hangs over it); a cell
//! whose stored points stand where a beam just passed freely held something that has gone (a
//! walker, a stray point), and its old evidence is dropped.

use super::{floor_i64, norm2, Mapper, RobotPose, UpdateReport};

/// The beams of one sweep over one cell.
#[derive(Clone, Copy)]
pub(super) struct Pass {
    /// The ground the cell's crossing beams are measured from (NaN: not visited this sweep).
    pub(super) g: f32,
    /// The lowest crossing in the headroom band (absolute height, metres).
    pub(super) lo: f32,
    /// Beams that crossed the cell in the headroom band.
    pub(super) n: u16,
}

impl Default for Pass {
    fn default() -> Self {
        Self {
            g: f32::NAN,
            lo: f32::INFINITY,
            n: 0,
        }
    }
}

/// The headroom band stops this far below the robot's height: a beam passing just under `h_r`
/// over a cell says little about the robot's top (and a car body's top is about that high).
const HEADROOM_TOP_MARGIN_M: f64 = 0.2;
/// How far the ground beyond the processing distance may lie above or below the robot's for a
/// beam still to be marched there, metres (the terrain, not the band, limits the far march).
const FAR_TERRAIN_SLACK_M: f64 = 0.5;

impl Mapper {
    /// Marks the cells of the window that this sweep's beams crossed inside the headroom band:
    /// from `clear_low_m` up to `h_r - HEADROOM_TOP_MARGIN_M` above the cell's own ground (its
    /// lowest return of this sweep, or its stored mean). Every `beam_stride`-th return is
    /// marched, out to `processing_distance`. Returns the number of beams marched.
    pub(super) fn march_beams(
        &mut self,
        pts: &[[f32; 3]],
        o: [f64; 3],
        robot: &RobotPose,
    ) -> usize {
        let l = self.cfg.grid_size_m;
        let inv_l = 1.0 / l;
        // The cells' ground: this sweep's lowest return per cell first.
        for p in pts {
            let (cx, cy) = (
                floor_i64(f64::from(p[0]) * inv_l),
                floor_i64(f64::from(p[1]) * inv_l),
            );
            if let Some(i) = self.win.local(cx, cy) {
                if self.win.zmin[i] == f32::INFINITY {
                    self.win.touched.push(i);
                }
                self.win.zmin[i] = self.win.zmin[i].min(p[2]);
            }
        }
        let step = 0.7 * l;
        let low = self.cfg.clear_low_m as f32;
        let high = (self.cfg.h_r_m - HEADROOM_TOP_MARGIN_M) as f32;
        let reach = self.cfg.processing_distance_m.max(self.cfg.clear_reach_m);
        let zs = o[2];
        let near = self.cfg.processing_distance_m;
        let h0 = zs - robot.z_m;
        let (band_lo, band_hi) = (
            f64::from(low) - FAR_TERRAIN_SLACK_M,
            f64::from(high) + FAR_TERRAIN_SLACK_M,
        );
        let stride = self.cfg.beam_stride.max(1);
        let mut marched = 0usize;
        let side = self.win.side;
        let (ux0, uy0) = (
            o[0] * inv_l - (self.win.cx0 - self.win.half) as f64,
            o[1] * inv_l - (self.win.cy0 - self.win.half) as f64,
        );
        for p in pts.iter().step_by(stride) {
            let (px, py, pz) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            let (dx, dy) = (px - o[0], py - o[1]);
            let d = norm2(dx, dy);
            if d < 2.0 * l {
                continue;
            }
            // Never the last cells (the return's own and the one it may straddle).
            let mut f1 = (1.0 - 1.5 * l / d).min(reach / d);
            if f1 <= 0.0 {
                continue;
            }
            if f1 * d > near {
                // Beyond the processing distance only the beam's stretch that can still be in
                // a cell's band is marched: the band about the robot's ground, widened by how
                // far the terrain may rise or fall out there. Steeper rings leave it early.
                let k = (pz - zs) / d;
                let r_end = if k > 0.0 {
                    (band_hi - h0) / k
                } else if k < 0.0 {
                    (band_lo - h0) / k
                } else {
                    f64::INFINITY
                };
                f1 = f1.min(r_end.max(near) / d);
            }
            marched += 1;
            let n = ((f1 * d) / step).ceil() as usize + 1;
            let mut last = usize::MAX;
            // Stepped in window cells: the step's cell is its coordinates truncated (negative
            // ones are outside the window anyway).
            let per = f1 / ((n - 1) as f64);
            let (sx, sy, sz) = (dx * per * inv_l, dy * per * inv_l, (pz - zs) * per);
            for k in 1..n {
                let kf = k as f64;
                let (ux, uy) = (ux0 + sx * kf, uy0 + sy * kf);
                if ux < 0.0 || uy < 0.0 {
                    continue;
                }
                let (ix, iy) = (ux as usize, uy as usize);
                if ix >= side || iy >= side {
                    continue;
                }
                let i = iy * side + ix;
                if i == last {
                    continue;
                }
                last = i;
                if self.win.pass[i].g.is_nan() {
                    // First visit this sweep: the cell's ground, or infinity when unknown.
                    let (cx, cy) = self.win.global(i);
                    let g = self.win.zmin[i].min(self.ground(cx, cy));
                    self.win.pass[i].g = g;
                    self.win.pass_touched.push(i);
                }
                let g = self.win.pass[i].g;
                let z = (zs + sz * kf) as f32;
                let h = z - g;
                if !(low..=high).contains(&h) {
                    continue;
                }
                let ps = &mut self.win.pass[i];
                ps.n = ps.n.saturating_add(1);
                if z < ps.lo {
                    ps.lo = z;
                }
            }
        }
        // The sweep's ground lookup is done: the normal binning starts from a clean slate.
        for &i in &self.win.touched {
            self.win.zmin[i] = f32::INFINITY;
        }
        self.win.touched.clear();
        marched
    }

    /// Applies the sweep's free space: every crossed cell has seen headroom; a cell whose stored
    /// points stand higher than where a beam just crossed it freely, with nothing of this sweep
    /// up there, held something that has gone (a walker, a stray point): its old evidence is
    /// dropped so this sweep's points rebuild it.
    pub(super) fn apply_free_space(&mut self, dirty: &mut Vec<(i64, i64)>, rep: &mut UpdateReport) {
        let touched = std::mem::take(&mut self.win.pass_touched);
        let near_passes = self.cfg.clear_min_beams.max(1);
        let margin = self.cfg.clear_margin_m as f32;
        let stand_m = self.cfg.stray_height_m as f32;
        let pd_cells2 = (self.cfg.processing_distance_m / self.cfg.grid_size_m).powi(2);
        let (rcx, rcy) = (self.win.cx0, self.win.cy0);
        for &i in &touched {
            let (cx, cy) = self.win.global(i);
            let (n, lo) = (self.win.pass[i].n, self.win.pass[i].lo);
            if n == 0 {
                continue;
            }
            let far = ((cx - rcx).pow(2) + (cy - rcy).pow(2)) as f64 > pd_cells2;
            let min_passes = if far { 1 } else { near_passes };
            // This sweep's own returns in the cell up at the beams' height: still occupied.
            let now_top = self.win.low[i].zmax.max(self.win.high[i].zmax);
            let occupied_now = now_top >= lo - margin;
            let Some(d) = self.data(cx, cy) else {
                continue;
            };
            if d.driven_free(stand_m) {
                continue;
            }
            let stale = n >= min_passes
                && !occupied_now
                && d.evidence().n > 0
                && d.evidence().zmax > lo + margin
                && (!far || self.neighbours_free_now(cx, cy, lo - margin));
            // A lone grazing beam from afar is too thin to grant headroom (it slips under car
            // bodies at their edges); it only wipes what has gone.
            let first_headroom = !d.headroom && !far;
            if stale || first_headroom {
                let d = self.data_mut(cx, cy);
                d.headroom = true;
                if stale {
                    d.drop_evidence(far);
                    rep.cleared_cells += 1;
                    self.refresh_ground(cx, cy);
                }
                dirty.push((cx, cy));
            }
        }
        self.win.pass_touched = touched;
    }

    /// Whether none of this sweep's returns in the 8 cells around stands at or above `z`: far
    /// away one beam wipes a cell only where nothing of the sweep is up there next door either
    /// (a beam slipping past a car's edge inside a boundary cell must not wipe it).
    fn neighbours_free_now(&self, cx: i64, cy: i64, z: f32) -> bool {
        for dy in -1..=1 {
            for dx in -1..=1 {
                if let Some(j) = self.win.local(cx + dx, cy + dy) {
                    if self.win.low[j].zmax.max(self.win.high[j].zmax) >= z {
                        return false;
                    }
                }
            }
        }
        true
    }
}

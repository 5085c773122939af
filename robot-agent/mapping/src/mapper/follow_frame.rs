//! Frame corrections: when GNSS or gravity moves the map frame under the robot, the stored
//! heights around it move with it (docs/algorithms.md §4.13), so the correction draws no false
//! steps between old and new sweeps.

use super::{largest_at_corners, Mapper};
use nalgebra::Isometry3;

/// Stored heights may lag the map frame by this much before they follow it, metres: far below
/// the height spread of flat ground in one cell (`grass_sd_min_m` is 8 mm), so no step or slope
/// test can tell.
const FOLLOW_TOLERANCE_M: f64 = 5e-4;

impl Mapper {
    /// The map frame moved under the robot by `delta` (a GNSS or gravity correction of the
    /// frame: new map point = `delta` * old). Stored heights follow it, so the map stays what a
    /// map kept in the SLAM frame and shown through the current anchor would be: left alone,
    /// a correction of the frame's tilt or height sets new scans of the same ground off
    /// against the stored heights as false steps. Cells within `radius_m` of the robot follow
    /// fully and the last quarter of the radius tapers to nothing, so no ring of cells is left
    /// as a step against its neighbours (a hard edge at 30 m, or following only the cells seen
    /// in the last 20 s, made 3-7 % of `slopes` false obstacles with the robot's own poses).
    /// Horizontal moves are ignored (a few centimetres, within a cell). Returns the cells moved.
    ///
    /// Corrections that move no point within the radius by more than half a millimetre are
    /// kept and composed with the next ones instead: a pass touches every stored cell within
    /// the radius (most of the map), and the gravity and GNSS loops bring two such slivers
    /// for each correction that matters.
    pub fn follow_frame(&mut self, delta: &Isometry3<f64>, radius_m: f64) -> usize {
        let Some(robot) = self.robot else { return 0 };
        let delta = &(delta * self.frame_lag);
        let full_m = 0.75 * radius_m;
        let taper_m = (radius_m - full_m).max(1e-9);
        let dz_at = |x: f64, y: f64, z: f64| (delta * nalgebra::Point3::new(x, y, z)).z - z;
        let worst = largest_at_corners(robot.x_m, robot.y_m, radius_m, |x, y| {
            dz_at(x, y, robot.z_m)
        });
        if !worst.is_finite() {
            self.frame_lag = Isometry3::identity();
            return 0;
        }
        // Nothing to do yet for a sliver or a purely horizontal correction.
        if worst <= FOLLOW_TOLERANCE_M {
            self.frame_lag = *delta;
            return 0;
        }
        self.frame_lag = Isometry3::identity();
        let n = self.lattice.tile_cells as i64;
        let l = self.cfg.grid_size_m;
        let r2 = radius_m * radius_m;
        let min_n = self.rules.min_points();
        let mut moved = 0;
        for slot in &mut self.slots {
            let (x0, y0) = (i64::from(slot.index.tx) * n, i64::from(slot.index.ty) * n);
            // Skip tiles wholly outside the radius.
            let tile_m = n as f64 * l;
            let (tx, ty) = (x0 as f64 * l, y0 as f64 * l);
            let nx = robot.x_m.clamp(tx, tx + tile_m) - robot.x_m;
            let ny = robot.y_m.clamp(ty, ty + tile_m) - robot.y_m;
            if nx * nx + ny * ny > r2 {
                continue;
            }
            // Only cells ever handed out mutably can hold anything (see `TileSlot::held`).
            let held = slot
                .held
                .iter()
                .enumerate()
                .flat_map(|(w, &bits)| BitIndices(bits).map(move |b| w * 64 + b));
            for i in held {
                let d = &mut slot.data[i];
                let (c, r) = ((i as i64) % n, (i as i64) / n);
                let x = (x0 + c) as f64 * l + 0.5 * l;
                let y = (y0 + r) as f64 * l + 0.5 * l;
                let (ex, ey) = (x - robot.x_m, y - robot.y_m);
                let e2 = ex * ex + ey * ey;
                if e2 > r2 || (d.cur.n == 0 && d.prev.n == 0 && !d.driven) {
                    continue;
                }
                let weight = ((radius_m - e2.sqrt()) / taper_m).clamp(0.0, 1.0);
                let z = if d.cur.n > 0 {
                    d.cur.stats().mean_m
                } else {
                    robot.z_m
                };
                d.shift_heights(weight * dz_at(x, y, z));
                slot.ground[i] = d.ground(min_n);
                moved += 1;
            }
        }
        if let Some(r) = self.robot.as_mut() {
            r.z_m += dz_at(r.x_m, r.y_m, r.z_m);
        }
        moved
    }
}

/// The indices of the set bits of a word, lowest first.
struct BitIndices(u64);

impl Iterator for BitIndices {
    type Item = usize;

    #[inline]
    fn next(&mut self) -> Option<usize> {
        if self.0 == 0 {
            return None;
        }
        let b = self.0.trailing_zeros() as usize;
        self.0 &= self.0 - 1;
        Some(b)
    }
}

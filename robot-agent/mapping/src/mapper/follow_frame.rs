//! Frame corrections: when GNSS or gravity moves the map frame under the robot, the heights seen
//! recently nearby move with it (they were seen under the same SLAM drift as the sweeps still
//! to come), so the correction draws no false steps between old and new sweeps.

use super::Mapper;
use nalgebra::Isometry3;

impl Mapper {
    /// The map frame moved under the robot by `delta` (a GNSS correction of the pose: new map
    /// point = `delta` * old). Stored heights within `radius_m` of the robot and changed within
    /// the last `max_age_s` follow it, since they were seen under the same SLAM drift as the
    /// scans still to come; left alone, a correction of the frame's tilt or height would set
    /// new scans of the same ground off against them as false steps. Older cells keep the
    /// frame they were seen in (they were placed by the corrections of their time, and SLAM
    /// has drifted since). Horizontal moves are ignored (a few centimetres, within a cell).
    /// Returns the cells moved.
    pub fn follow_frame(&mut self, delta: &Isometry3<f64>, radius_m: f64, max_age_s: f64) -> usize {
        let Some(robot) = self.robot else { return 0 };
        let oldest = self.last_t_s.unwrap_or(0.0) - max_age_s;
        let dz_at = |x: f64, y: f64, z: f64| (delta * nalgebra::Point3::new(x, y, z)).z - z;
        let corners = [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)];
        let worst = corners
            .iter()
            .map(|(sx, sy)| {
                dz_at(
                    robot.x_m + sx * radius_m,
                    robot.y_m + sy * radius_m,
                    robot.z_m,
                )
                .abs()
            })
            .fold(0.0, f64::max);
        // Nothing to do for a purely horizontal correction (or a non-finite one).
        if !worst.is_finite() || worst <= 1e-5 {
            return 0;
        }
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
            for (i, d) in slot.data.iter_mut().enumerate() {
                let (c, r) = ((i as i64) % n, (i as i64) / n);
                let x = (x0 + c) as f64 * l + 0.5 * l;
                let y = (y0 + r) as f64 * l + 0.5 * l;
                let (ex, ey) = (x - robot.x_m, y - robot.y_m);
                if ex * ex + ey * ey > r2
                    || (d.cur.n == 0 && d.prev.n == 0 && !d.driven)
                    || f64::from(d.stamp_s) + 1.0 < oldest
                {
                    continue;
                }
                let z = if d.cur.n > 0 {
                    d.cur.stats().mean_m
                } else {
                    robot.z_m
                };
                let dz = dz_at(x, y, z);
                d.cur = d.cur.shifted(dz);
                d.prev = d.prev.shifted(dz);
                d.pending = d.pending.shifted(dz);
                if d.driven {
                    d.driven_z += dz as f32;
                }
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

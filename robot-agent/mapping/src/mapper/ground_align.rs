//! Ground-height consistency between passes (docs/algorithms.md §4.15).
//!
//! The localiser's height drifts by a few centimetres between two passes over the same ground
//! (SLAM's vertical drift, pulled back only slowly by GNSS), and the frame follow (§4.13) cannot
//! see that drift: it is no correction of the frame. Where a sweep comes back to ground mapped
//! long ago, the old and the new heights then meet as a false step (a 5 cm curb read as 8 cm) or
//! hide a true one (a 10 cm strip read as 7 cm). Before a sweep is binned, its ground heights
//! are compared with what flat, long-unseen cells hold in the overlap; the robust (median)
//! difference, smoothed over sweeps and held for a while after the overlap ends, is taken off
//! the sweep, its sensor and the robot's height: one vertical offset, the map's own ground the
//! reference.

use super::fast_hash::FastMap;
use super::{floor_i64, Mapper};
use crate::config::Config;

/// The offset carried from sweep to sweep.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct GroundAlign {
    /// Subtracted from the sweep's heights, metres.
    pub(super) offset_m: f64,
    /// When the offset was last measured or decayed, seconds.
    pub(super) t_s: Option<f64>,
    /// Cells compared at the last sweep that measured.
    pub(super) cells: usize,
}

/// A sweep's points in one cell: enough to tell flat ground and its mean.
#[derive(Clone, Copy)]
struct Bin {
    n: u32,
    sum: f64,
    lo: f32,
    hi: f32,
}

impl GroundAlign {
    /// Whether the configuration turns alignment on.
    pub(super) fn enabled(cfg: &Config) -> bool {
        cfg.ground_align_range_m > 0.0
    }
}

impl Mapper {
    /// Measures the sweep's height offset against the stored ground and returns the offset to
    /// take off it (0 when alignment is off). `pts` are map-frame points, already finite.
    pub(super) fn ground_offset(
        &mut self,
        pts: &[[f32; 3]],
        robot_xy: (f64, f64),
        t_s: f64,
    ) -> f64 {
        let cfg = &self.cfg;
        if !GroundAlign::enabled(cfg) {
            return 0.0;
        }
        // Hold, decaying towards the localiser's own height, while nothing old is in view.
        let mut state = self.ground_align;
        if let Some(t0) = state.t_s {
            let dt = (t_s - t0).max(0.0);
            state.offset_m *= (-dt / cfg.ground_align_hold_s.max(1e-3)).exp();
        }
        state.t_s = Some(t_s);
        let r2 = cfg.ground_align_range_m * cfg.ground_align_range_m;
        let inv = self.inv_cell_m;
        let mut bins: FastMap<(i64, i64), Bin> = FastMap::default();
        for p in pts {
            let (dx, dy) = (f64::from(p[0]) - robot_xy.0, f64::from(p[1]) - robot_xy.1);
            if dx * dx + dy * dy > r2 {
                continue;
            }
            let key = (
                floor_i64(f64::from(p[0]) * inv),
                floor_i64(f64::from(p[1]) * inv),
            );
            let b = bins.entry(key).or_insert(Bin {
                n: 0,
                sum: 0.0,
                lo: f32::INFINITY,
                hi: f32::NEG_INFINITY,
            });
            b.n += 1;
            b.sum += f64::from(p[2]);
            b.lo = b.lo.min(p[2]);
            b.hi = b.hi.max(p[2]);
        }
        let spread = cfg.ground_align_flat_m as f32;
        let min_age = cfg.ground_align_min_age_s as f32;
        let now = t_s as f32;
        let mut diffs: Vec<f64> = Vec::new();
        for (&(cx, cy), b) in &bins {
            if b.n < cfg.ground_align_min_points || b.hi - b.lo > spread {
                continue;
            }
            let Some(d) = self.data(cx, cy) else { continue };
            // Long unseen: another pass, not this one's own recent sweeps.
            if now - d.accepted_s < min_age {
                continue;
            }
            let e = d.evidence();
            if e.n < cfg.ground_align_min_points || e.zmax - e.zmin > spread {
                continue;
            }
            let s = e.stats();
            diffs.push(b.sum / f64::from(b.n) - state.offset_m - s.mean_m);
        }
        state.cells = diffs.len();
        if diffs.len() >= cfg.ground_align_min_cells {
            let mid = diffs.len() / 2;
            let (_, m, _) = diffs.select_nth_unstable_by(mid, f64::total_cmp);
            let residual = *m;
            // A larger disagreement is not drift (another level, a moved frame): left alone.
            if residual.abs() <= cfg.ground_align_max_m {
                state.offset_m += cfg.ground_align_gain * residual;
            }
        }
        self.ground_align = state;
        state.offset_m
    }

    /// The height offset taken off the last sweep (ground alignment, §4.15), metres, and the
    /// cells it was measured on.
    pub fn ground_offset_m(&self) -> (f64, usize) {
        (self.ground_align.offset_m, self.ground_align.cells)
    }
}

#[cfg(test)]
mod tests {
    use crate::synth::{cast_scan, LidarSpec, Rng};
    use crate::{Config, Mapper, RobotPose};

    /// Drives from x = -4 m to 4 m along y = 0 over flat ground, one sweep per 0.1 s from
    /// `t0_s`, with the localiser's height `dz_m` too high (every point and the robot lifted).
    fn pass(m: &mut Mapper, t0_s: f64, dz_m: f64) {
        let spec = LidarSpec {
            az_step_deg: 0.4,
            max_range_m: 20.0,
            ..LidarSpec::vlp16()
        };
        let mut rng = Rng::new(3);
        for i in 0..=80 {
            let x = -4.0 + 0.1 * f64::from(i);
            let sensor = [x, 0.0, 0.7];
            let pts: Vec<[f32; 3]> = cast_scan(&|_, _| 0.0, sensor, &spec, &mut rng)
                .into_iter()
                .map(|p| [p[0], p[1], p[2] + dz_m as f32])
                .collect();
            let robot = RobotPose {
                x_m: x,
                y_m: 0.0,
                z_m: dz_m,
                yaw_rad: 0.0,
            };
            m.update_sweep(pts, [x, 0.0, 0.7 + dz_m], &robot, t0_s + 0.1 * f64::from(i))
                .unwrap();
        }
    }

    fn aligned(range_m: f64) -> Mapper {
        Mapper::new(Config {
            ground_align_range_m: range_m,
            ..Config::default()
        })
        .unwrap()
    }

    /// Mean height of the cells 6-8 m ahead of the end of the drive, beside it.
    fn ground_ahead(m: &Mapper) -> f64 {
        let l = m.lattice();
        let (mut sum, mut n) = (0.0, 0.0);
        for (x, y) in [(10.0, 1.0), (11.0, -1.0), (12.0, 2.0), (10.5, -2.5)] {
            let (cx, cy) = l.cell_of(x, y);
            let s = m.height_stats(cx, cy);
            assert!(s.n > 0, "cell at ({x}, {y}) not observed");
            sum += s.mean_m;
            n += 1.0;
        }
        sum / n
    }

    #[test]
    fn a_second_pass_with_drifted_height_is_brought_onto_the_first() {
        let mut m = aligned(10.0);
        pass(&mut m, 0.0, 0.0);
        assert_eq!(
            m.ground_offset_m().0,
            0.0,
            "nothing old to compare on the first pass"
        );
        // A minute later the localiser is 4 cm too high over the same ground.
        pass(&mut m, 60.0, 0.04);
        let (offset, _) = m.ground_offset_m();
        assert!((offset - 0.04).abs() < 0.005, "offset {offset}");
        let h = ground_ahead(&m);
        assert!(h.abs() < 0.01, "re-observed ground at {h} m, mapped at 0");
    }

    #[test]
    fn without_alignment_the_drift_goes_into_the_map() {
        let mut m = aligned(0.0);
        pass(&mut m, 0.0, 0.0);
        pass(&mut m, 60.0, 0.04);
        assert_eq!(m.ground_offset_m().0, 0.0);
        let h = ground_ahead(&m);
        assert!((h - 0.04).abs() < 0.01, "re-observed ground at {h} m");
    }

    #[test]
    fn the_offset_returns_to_zero_where_nothing_old_is_seen() {
        let mut m = aligned(10.0);
        pass(&mut m, 0.0, 0.0);
        pass(&mut m, 60.0, 0.04);
        let before = m.ground_offset_m().0;
        // Far away, long after: new ground only.
        let spec = LidarSpec {
            az_step_deg: 1.0,
            max_range_m: 10.0,
            ..LidarSpec::vlp16()
        };
        let mut rng = Rng::new(5);
        let pts = cast_scan(&|_, _| 0.0, [500.0, 0.0, 0.7], &spec, &mut rng);
        let robot = RobotPose {
            x_m: 500.0,
            y_m: 0.0,
            z_m: 0.0,
            yaw_rad: 0.0,
        };
        m.update_sweep(pts, [500.0, 0.0, 0.7], &robot, 68.0 + 120.0)
            .unwrap();
        let after = m.ground_offset_m().0;
        assert!(
            after < before * 0.2,
            "offset {after} after 120 s with nothing old in view (was {before})"
        );
    }
}

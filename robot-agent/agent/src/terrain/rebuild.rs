//! Rebuilding the terrain map when the pose graph moves the past (a loop closed, or RTK came
//! back after an outage; docs/algorithms.md §3.7).
//!
//! The cells hold evidence summaries (height statistics per epoch), not the points behind them,
//! and one cell mixes sweeps of many times, so a cell cannot be moved by "its" correction. What
//! is kept instead is a sweep every `map_rebuild_spacing_m` of travel (lidar frame, within the
//! mapper's range) with its SLAM pose; after a correction that moves any of them by more than
//! `map_rebuild_min_move_m`, a fresh mapper is fed the kept sweeps in time order at their
//! corrected poses (`map<-slam` from the graph at each sweep's time) and replaces the map. Every
//! tile is then offered for publication again; the publisher sends those whose cells differ, with
//! newer versions, so stations replace them.

use nalgebra::{Isometry3, Point3};
use sensing::Point;

/// One kept sweep.
struct KeptSweep {
    t_s: f64,
    /// `slam<-base_link` (never changed by corrections).
    slam_from_base: Isometry3<f64>,
    /// `map<-base_link` it was last mapped at.
    mapped_at: Isometry3<f64>,
    /// Returns in the lidar frame.
    points: Vec<[f32; 3]>,
}

/// The sweeps kept for rebuilding, oldest first.
pub struct SweepStore {
    spacing_m: f64,
    min_move_m: f64,
    max_range_m: f32,
    sweeps: Vec<KeptSweep>,
}

/// A sweep to map again: where, seen from where, what.
pub struct Remap<'a> {
    /// The sweep's time, seconds.
    pub t_s: f64,
    /// Corrected `map<-base_link`.
    pub map_from_base: Isometry3<f64>,
    /// Returns in the lidar frame.
    pub points: &'a [[f32; 3]],
}

impl SweepStore {
    /// An empty store keeping a sweep every `spacing_m` of travel, its returns within
    /// `max_range_m` (the mapper's range: what it would drop anyway is not kept).
    pub fn new(spacing_m: f64, min_move_m: f64, max_range_m: f64) -> Self {
        Self {
            spacing_m,
            min_move_m,
            max_range_m: max_range_m as f32,
            sweeps: Vec::new(),
        }
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

    /// A sweep just mapped at `map_from_base` (its SLAM pose `slam_from_base`): kept when the
    /// robot moved `spacing_m` since the last kept one. Returns whether it was kept.
    pub fn offer(
        &mut self,
        t_s: f64,
        slam_from_base: &Isometry3<f64>,
        map_from_base: &Isometry3<f64>,
        points: &[Point],
    ) -> bool {
        let due = self.sweeps.last().is_none_or(|s| {
            (s.slam_from_base.translation.vector - slam_from_base.translation.vector).norm()
                >= self.spacing_m
        });
        if !due || !t_s.is_finite() {
            return false;
        }
        let r2 = self.max_range_m * self.max_range_m;
        let points = points
            .iter()
            .filter(|p| p.is_finite() && p.x * p.x + p.y * p.y + p.z * p.z <= r2)
            .map(|p| [p.x, p.y, p.z])
            .collect();
        self.sweeps.push(KeptSweep {
            t_s,
            slam_from_base: *slam_from_base,
            mapped_at: *map_from_base,
            points,
        });
        true
    }

    /// The kept sweeps at the poses `map_from_slam_at(t)` gives, when some moved by more than
    /// `min_move_m` from where they were mapped; `None` when none did (nothing to rebuild).
    /// Sweeps the function has no answer for stay where they were mapped.
    pub fn corrected(
        &mut self,
        map_from_slam_at: impl Fn(f64) -> Option<Isometry3<f64>>,
    ) -> Option<Vec<Remap<'_>>> {
        let poses: Vec<Isometry3<f64>> = self
            .sweeps
            .iter()
            .map(|s| map_from_slam_at(s.t_s).map_or(s.mapped_at, |m| m * s.slam_from_base))
            .collect();
        let moved = self.sweeps.iter().zip(&poses).any(|(s, p)| {
            (s.mapped_at.translation.vector - p.translation.vector).norm() > self.min_move_m
        });
        if !moved {
            return None;
        }
        for (s, p) in self.sweeps.iter_mut().zip(&poses) {
            s.mapped_at = *p;
        }
        Some(
            self.sweeps
                .iter()
                .map(|s| Remap {
                    t_s: s.t_s,
                    map_from_base: s.mapped_at,
                    points: &s.points,
                })
                .collect(),
        )
    }
}

/// A kept sweep's returns in the map frame and the sensor's position there.
pub fn to_map(r: &Remap<'_>, base_from_lidar: &Isometry3<f64>) -> (Vec<[f32; 3]>, [f64; 3]) {
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
mod tests {
    use super::*;
    use slam::se3;

    fn pt(x: f32) -> Point {
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
        let mut st = SweepStore::new(0.5, 0.05, 30.0);
        for i in 0..10 {
            let p = se3::from_xyz_rpy([0.2 * f64::from(i), 0.0, 0.0], [0.0; 3]);
            st.offer(f64::from(i), &p, &p, &[pt(1.0), pt(40.0), pt(f32::NAN)]);
        }
        // 0, 0.6, 1.2, 1.8 m: every third sweep.
        assert_eq!(st.len(), 4);
        assert_eq!(
            st.points(),
            4,
            "out-of-range and non-finite returns are not kept"
        );
        assert!(st.corrected(|_| Some(Isometry3::identity())).is_none());
        let shift = se3::from_xyz_rpy([0.0, 0.3, 0.0], [0.0; 3]);
        let r = st.corrected(|_| Some(shift)).expect("moved 0.3 m");
        assert_eq!(r.len(), 4);
        assert!((r[1].map_from_base.translation.y - 0.3).abs() < 1e-12);
        let (pts, o) = to_map(&r[1], &Isometry3::identity());
        assert!((pts[0][0] - 1.6).abs() < 1e-5 && (pts[0][1] - 0.3).abs() < 1e-5);
        assert!((o[1] - 0.3).abs() < 1e-12);
        // Mapped there now: the same correction again is nothing to rebuild.
        assert!(st.corrected(|_| Some(shift)).is_none());
    }
}

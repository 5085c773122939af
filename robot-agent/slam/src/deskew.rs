//! De-skewing a sweep: every return expressed in the lidar frame at the sweep's stamp, from the
//! motion during the sweep (docs/algorithms.md §3.1 step 2).

use crate::se3;
use nalgebra::{Matrix3, UnitQuaternion, Vector3, Vector6};
use sensing::Point;
use std::collections::VecDeque;

/// Time step of a [`GyroTrack`], seconds: at a 1 rad/s turn a return's rotation is then off by
/// at most 0.125 mrad (4 mm at 30 m).
const BIN_S: f64 = 0.25e-3;

/// Longest sweep a track is built for, seconds (a 0.5 Hz sensor); longer spans use the
/// constant twist.
const MAX_SPAN_S: f64 = 2.0;

/// The lidar's rotation through a sweep from the gyroscope, `lidar(stamp)<-lidar(stamp + t)`
/// every [`BIN_S`], each reading's mean rate held over its own interval (since the reading
/// before). A constant rate over the sweep smears a jolt, a wheel climbing a curb, over the
/// whole sweep; the readings place it within their interval.
pub(crate) struct GyroTrack {
    rot: Vec<Matrix3<f32>>,
}

impl GyroTrack {
    /// The track over `[t0, t0 + span_s]` from `readings` (`(t, base_link rate)`, in time
    /// order) less `bias` (rad/s); `None` without a reading newer than `t0`. Past the newest
    /// reading its rate is held.
    pub(crate) fn new(
        readings: &VecDeque<(f64, Vector3<f64>)>,
        bias: &Vector3<f64>,
        base_from_lidar: &UnitQuaternion<f64>,
        t0: f64,
        span_s: f64,
    ) -> Option<Self> {
        if !(0.0..=MAX_SPAN_S).contains(&span_s) {
            return None;
        }
        let mut k = readings.partition_point(|(t, _)| *t <= t0);
        if k == readings.len() {
            return None;
        }
        let lidar_from_base = base_from_lidar.inverse();
        let n = (span_s / BIN_S).ceil() as usize + 1;
        let mut rot = Vec::with_capacity(n);
        let mut q = UnitQuaternion::identity();
        let mut t = t0;
        for b in 0..n {
            let tb = t0 + b as f64 * BIN_S;
            while t < tb {
                let (end, w) = match readings.get(k) {
                    Some((tk, w)) => (tk.min(tb), w),
                    None => (tb, &readings[readings.len() - 1].1),
                };
                q *= UnitQuaternion::from_scaled_axis(lidar_from_base * ((w - bias) * (end - t)));
                t = end;
                if readings.get(k).is_some_and(|(tk, _)| t >= *tk) {
                    k += 1;
                }
            }
            rot.push(q.to_rotation_matrix().into_inner().cast::<f32>());
        }
        Some(Self { rot })
    }

    /// The rotation at `t_s` into the sweep.
    fn at(&self, t_s: f32) -> &Matrix3<f32> {
        let i = (f64::from(t_s.max(0.0)) / BIN_S).round() as usize;
        &self.rot[i.min(self.rot.len() - 1)]
    }

    /// `points` in the lidar frame at the stamp: turned by the track, moved by `v_mps` (the
    /// lidar's velocity in its own frame) times their time.
    pub(crate) fn deskew(&self, points: &[Point], v_mps: &Vector3<f32>) -> Vec<Point> {
        points
            .iter()
            .map(|p| {
                let q = self.at(p.t_s) * Vector3::new(p.x, p.y, p.z) + v_mps * p.t_s;
                Point {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    ..*p
                }
            })
            .collect()
    }
}

/// `points` in the lidar frame at the stamp, with the body twist per second `xi = (omega, v)`
/// held over the sweep: `exp(xi t_p) p`.
pub(crate) fn deskew_constant(points: &[Point], xi: &Vector6<f64>) -> Vec<Point> {
    points
        .iter()
        .map(|p| {
            let q = se3::exp_apply(
                xi,
                f64::from(p.t_s),
                &Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z)),
            );
            Point {
                x: q.x as f32,
                y: q.y as f32,
                z: q.z as f32,
                ..*p
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(x: f32, t_s: f32) -> Point {
        Point {
            x,
            y: 0.0,
            z: 0.0,
            t_s,
            ..Point::default()
        }
    }

    #[test]
    fn a_jolt_turns_only_the_returns_after_it() {
        // Readings every 20 ms; the one at 1.06 s holds a 0.1 rad pitch over (1.04, 1.06].
        let readings: VecDeque<_> = [0.98, 1.0, 1.02, 1.04, 1.06, 1.08, 1.10]
            .iter()
            .map(|&t| {
                let wy = if t == 1.06 { 5.0 } else { 0.0 };
                (t, Vector3::new(0.0, wy, 0.0))
            })
            .collect();
        let track = GyroTrack::new(
            &readings,
            &Vector3::zeros(),
            &UnitQuaternion::identity(),
            1.0,
            0.1,
        )
        .unwrap();
        let pts = [point(10.0, 0.02), point(10.0, 0.05), point(10.0, 0.08)];
        let out = track.deskew(&pts, &Vector3::zeros());
        // Before the jolt: unmoved; halfway through it: half the turn; after it: all of it.
        assert!(out[0].z.abs() < 1e-6, "{:?}", out[0]);
        let half = -(10.0 * 0.05f32.sin());
        assert!((out[1].z - half).abs() < 2e-3, "{:?}", out[1]);
        let full = -(10.0 * 0.1f32.sin());
        assert!((out[2].z - full).abs() < 2e-3, "{:?}", out[2]);
        // The constant rate of the same readings spreads the turn over the sweep.
        let mean = Vector6::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
        let smeared = deskew_constant(&pts, &mean);
        assert!(smeared[0].z < -0.15, "{:?}", smeared[0]);
    }

    #[test]
    fn a_steady_turn_matches_the_constant_twist() {
        let readings: VecDeque<_> = (0..10)
            .map(|k| (0.95 + 0.02 * f64::from(k), Vector3::new(0.1, -0.2, 0.6)))
            .collect();
        // A lidar mounted turned 90 deg about z: rates move into its frame.
        let mount = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let track = GyroTrack::new(&readings, &Vector3::zeros(), &mount, 1.0, 0.1).unwrap();
        let w = mount.inverse() * Vector3::new(0.1, -0.2, 0.6);
        let xi = Vector6::new(w.x, w.y, w.z, 0.5, 0.0, 0.0);
        let pts: Vec<Point> = (0..=10)
            .map(|i| Point {
                y: 5.0,
                z: 1.0,
                ..point(20.0, 0.01 * i as f32)
            })
            .collect();
        let a = track.deskew(&pts, &Vector3::new(0.5, 0.0, 0.0));
        let b = deskew_constant(&pts, &xi);
        for (p, q) in a.iter().zip(&b) {
            let d = Vector3::new(p.x - q.x, p.y - q.y, p.z - q.z).norm();
            assert!(d < 3e-3, "{p:?} {q:?}");
        }
        // Nothing newer than the stamp: no track.
        assert!(GyroTrack::new(&readings, &Vector3::zeros(), &mount, 1.2, 0.1).is_none());
    }
}

//! Trajectory error metrics against ground truth (ATE, per-frame RPE, final drift), and the
//! provenance of map points (where in the world a point was seen) for scoring dynamic-point
//! removal against known moving objects.

use nalgebra::{Isometry3, Point3, Vector3};
use serde::Serialize;

/// Errors of an estimated trajectory against ground truth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TrajectoryErrors {
    /// Poses compared.
    pub frames: usize,
    /// Ground-truth path length, metres.
    pub path_m: f64,
    /// RMS position error after aligning the first poses, metres.
    pub ate_m: f64,
    /// RMS translation error of consecutive-frame relative poses, metres.
    pub rpe_m: f64,
    /// RMS rotation error of consecutive-frame relative poses, degrees.
    pub rpe_deg: f64,
    /// Final position error / path length, percent.
    pub drift_pct: f64,
}

/// Compares `est` with `gt` (same length used: the shorter of the two).
pub fn trajectory_errors(est: &[Isometry3<f64>], gt: &[Isometry3<f64>]) -> TrajectoryErrors {
    let n = est.len().min(gt.len());
    if n == 0 {
        return TrajectoryErrors::default();
    }
    let align = gt[0] * est[0].inverse();
    let aligned: Vec<Isometry3<f64>> = est[..n].iter().map(|e| align * e).collect();
    let mut se = 0.0;
    for (a, g) in aligned.iter().zip(gt) {
        se += (a.translation.vector - g.translation.vector).norm_squared();
    }
    let ate_m = (se / n as f64).sqrt();
    let (mut st, mut sr, mut path_m) = (0.0, 0.0, 0.0);
    for i in 1..n {
        let re = est[i - 1].inverse() * est[i];
        let rg = gt[i - 1].inverse() * gt[i];
        let d = rg.inverse() * re;
        st += d.translation.vector.norm_squared();
        sr += d.rotation.angle().powi(2);
        path_m += (gt[i].translation.vector - gt[i - 1].translation.vector).norm();
    }
    let pairs = (n - 1).max(1) as f64;
    let final_err = (aligned[n - 1].translation.vector - gt[n - 1].translation.vector).norm();
    TrajectoryErrors {
        frames: n,
        path_m,
        ate_m,
        rpe_m: (st / pairs).sqrt(),
        rpe_deg: (sr / pairs).sqrt().to_degrees(),
        drift_pct: if path_m > 0.0 {
            100.0 * final_err / path_m
        } else {
            0.0
        },
    }
}

/// A vertical cylinder in the world frame: a person's body at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cylinder {
    /// Axis x, metres.
    pub x_m: f64,
    /// Axis y, metres.
    pub y_m: f64,
    /// Bottom, metres.
    pub z_min_m: f64,
    /// Top, metres.
    pub z_max_m: f64,
    /// Radius, metres.
    pub radius_m: f64,
}

impl Cylinder {
    /// True when `p` is inside (boundary included).
    pub fn contains(&self, p: &Vector3<f64>) -> bool {
        p.z >= self.z_min_m
            && p.z <= self.z_max_m
            && (p.x - self.x_m).hypot(p.y - self.y_m) <= self.radius_m
    }
}

/// Where map points were in the world when they were seen. A map point carries the stamp of the
/// scan that inserted it ([`crate::map::Map::stamps`]); taken back into that scan's sensor frame
/// with the estimated pose and out again with the true one, it lands where the sensor actually
/// measured it, whatever the SLAM error at that time.
#[derive(Clone, Debug, Default)]
pub struct Provenance {
    stamps: Vec<f64>,
    /// `gt_k * est_k^-1` per scan.
    fix: Vec<Isometry3<f64>>,
}

impl Provenance {
    /// Scans' stamps (increasing), their estimated poses (map frame) and true poses (world).
    pub fn new(stamps: &[f64], est: &[Isometry3<f64>], gt: &[Isometry3<f64>]) -> Self {
        let mut p = Self::default();
        for ((t, e), g) in stamps.iter().zip(est).zip(gt) {
            p.push(*t, e, g);
        }
        p
    }

    /// Adds the next scan (stamps must increase).
    pub fn push(&mut self, stamp_s: f64, est: &Isometry3<f64>, gt: &Isometry3<f64>) {
        self.stamps.push(stamp_s);
        self.fix.push(gt * est.inverse());
    }

    /// Index of the scan stamped `t_s`, if it is one of the known scans.
    pub fn scan_of(&self, t_s: f64) -> Option<usize> {
        let i = self.stamps.partition_point(|s| *s < t_s - 1e-9);
        (i < self.stamps.len() && (self.stamps[i] - t_s).abs() <= 1e-9).then_some(i)
    }

    /// World position of the map point `p` inserted by the scan stamped `t_s`.
    pub fn world(&self, p: &[f32; 3], t_s: f64) -> Option<Vector3<f64>> {
        let k = self.scan_of(t_s)?;
        let q = Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        Some((self.fix[k] * q).coords)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn provenance_undoes_the_pose_error_of_the_inserting_scan() {
        let stamps = [0.0, 0.1, 0.2];
        let gt: Vec<_> = (0..3)
            .map(|i| Isometry3::translation(i as f64, 0.0, 0.0))
            .collect();
        // The estimate of scan 2 is 0.5 m off in y: its map points are too.
        let mut est = gt.clone();
        est[2] = Isometry3::translation(2.0, 0.5, 0.0);
        let prov = Provenance::new(&stamps, &est, &gt);
        let seen_at = Vector3::new(2.0, 1.0, 0.0);
        let in_map = est[2] * gt[2].inverse() * Point3::from(seen_at);
        let p = [in_map.x as f32, in_map.y as f32, in_map.z as f32];
        let w = prov.world(&p, 0.2).expect("known scan");
        assert!((w - seen_at).norm() < 1e-6, "{w}");
        assert!(prov.world(&p, 0.15).is_none());
        let c = Cylinder {
            x_m: 2.0,
            y_m: 1.0,
            z_min_m: -0.5,
            z_max_m: 0.5,
            radius_m: 0.1,
        };
        assert!(c.contains(&w) && !c.contains(&(w + Vector3::new(0.0, 0.2, 0.0))));
    }

    #[test]
    fn perfect_and_offset_trajectories() {
        let gt: Vec<Isometry3<f64>> = (0..11)
            .map(|i| Isometry3::translation(i as f64, 0.0, 0.0))
            .collect();
        let e = trajectory_errors(&gt, &gt);
        assert_eq!(
            (e.frames, e.path_m, e.ate_m, e.rpe_m, e.drift_pct),
            (11, 10.0, 0.0, 0.0, 0.0)
        );
        // A constant offset of the whole estimate is removed by the first-pose alignment.
        let moved: Vec<_> = gt
            .iter()
            .map(|g| Isometry3::translation(5.0, 5.0, 0.0) * g)
            .collect();
        assert!(trajectory_errors(&moved, &gt).ate_m < 1e-12);
        // 10% scale error: final error 1 m over 10 m.
        let scaled: Vec<_> = (0..11)
            .map(|i| Isometry3::translation(i as f64 * 1.1, 0.0, 0.0))
            .collect();
        let e = trajectory_errors(&scaled, &gt);
        assert!(
            (e.drift_pct - 10.0).abs() < 1e-9 && (e.rpe_m - 0.1).abs() < 1e-9,
            "{e:?}"
        );
        let rot: Vec<_> = gt
            .iter()
            .enumerate()
            .map(|(i, g)| {
                Isometry3::from_parts(
                    Translation3::from(g.translation.vector),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, 0.01 * i as f64),
                )
            })
            .collect();
        assert!((trajectory_errors(&rot, &gt).rpe_deg - 0.01f64.to_degrees()).abs() < 1e-9);
    }
}

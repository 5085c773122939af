//! Trajectory error metrics against ground truth (ATE, per-frame RPE, final drift).

use nalgebra::Isometry3;
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

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

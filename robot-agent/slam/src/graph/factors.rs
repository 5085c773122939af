//! Factors of the pose graph: their errors, Jacobians and robust weights.
//!
//! Poses are `world<-keyframe` and are perturbed on the right, `T exp(d)` with `d` a twist
//! `[omega, v]` (crate::se3). Relative-pose errors are `log(Z^-1 Ti^-1 Tj)`; their Jacobians are
//! taken by central differences (six evaluations per pose: cheap next to the sparse solve, and
//! exact enough where the first-order closed forms are not, i.e. with large loop errors).

use crate::se3;
use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix, Vector3, Vector6};

/// Which measurement a relative-pose factor came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum BetweenKind {
    /// Scan-to-map odometry between consecutive keyframes.
    Odometry,
    /// A verified loop closure (robust kernel applies).
    Loop,
}

/// One factor of the graph.
#[derive(Clone, Debug, PartialEq)]
pub enum Factor {
    /// A prior on one keyframe's full pose (the gauge anchor).
    Prior {
        /// Keyframe index.
        kf: usize,
        /// Prior `world<-keyframe`.
        pose: Isometry3<f64>,
        /// Information (inverse covariance), twist order `[omega, v]`.
        info: Matrix6<f64>,
    },
    /// A relative pose `Z = Ti^-1 Tj` measured between two keyframes.
    Between {
        /// Earlier keyframe.
        from: usize,
        /// Later keyframe.
        to: usize,
        /// Measured `from<-to`.
        measured: Isometry3<f64>,
        /// Information, twist order `[omega, v]`.
        info: Matrix6<f64>,
        /// Odometry or loop.
        kind: BetweenKind,
    },
    /// A GNSS position (ENU metres, in the graph's world frame) of one keyframe's origin.
    Position {
        /// Keyframe index.
        kf: usize,
        /// Measured position, metres.
        enu_m: Vector3<f64>,
        /// Information, 1/m^2.
        info: Matrix3<f64>,
    },
    /// The world's up direction as the accelerometer saw it in one keyframe's frame: its roll
    /// and pitch (yaw is free).
    Gravity {
        /// Keyframe index.
        kf: usize,
        /// World up `[0, 0, 1]` expressed in the keyframe's frame, unit length.
        up: Vector3<f64>,
        /// Information, 1/rad^2 (each axis of the small-angle error).
        info: f64,
    },
}

/// A factor linearised at the current poses: error, Jacobian blocks and the IRLS weight.
pub(crate) struct Linearised {
    /// Keyframes touched (one or two) and their Jacobian blocks (rows = error dimension).
    pub blocks: Vec<(usize, SMatrix<f64, 6, 6>)>,
    /// Error (a 3-vector padded with zeros for position factors).
    pub error: Vector6<f64>,
    /// Information, padded to 6x6 with zeros.
    pub info: Matrix6<f64>,
}

/// Information matrix from standard deviations of rotation (rad) and translation (m).
pub fn information(sigma_rot_rad: f64, sigma_trans_m: f64) -> Matrix6<f64> {
    let r = 1.0 / sigma_rot_rad.max(1e-9).powi(2);
    let t = 1.0 / sigma_trans_m.max(1e-9).powi(2);
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// The tilt error of a gravity factor: the keyframe's up seen in its own frame minus the
/// measured one (for small errors, the roll/pitch error in radians; yaw does not change it).
fn gravity_error(t: &Isometry3<f64>, up: &Vector3<f64>) -> Vector6<f64> {
    let e = t.rotation.inverse() * Vector3::z() - up;
    Vector6::new(e.x, e.y, e.z, 0.0, 0.0, 0.0)
}

fn between_error(ti: &Isometry3<f64>, tj: &Isometry3<f64>, z: &Isometry3<f64>) -> Vector6<f64> {
    se3::log(&(z.inverse() * ti.inverse() * tj))
}

/// Jacobian of `f` with respect to a right perturbation of `t`, by central differences.
fn numeric_jacobian(
    t: &Isometry3<f64>,
    f: impl Fn(&Isometry3<f64>) -> Vector6<f64>,
) -> Matrix6<f64> {
    const H: f64 = 1e-6;
    let mut j = Matrix6::zeros();
    for k in 0..6 {
        let mut d = Vector6::zeros();
        d[k] = H;
        let plus = f(&(t * se3::exp(&d)));
        d[k] = -H;
        let minus = f(&(t * se3::exp(&d)));
        j.set_column(k, &((plus - minus) / (2.0 * H)));
    }
    j
}

impl Factor {
    /// Squared Mahalanobis error `e^T Omega e` at `poses`.
    pub fn chi2(&self, poses: &[Isometry3<f64>]) -> f64 {
        match self {
            Factor::Prior { kf, pose, info } => {
                let e = se3::log(&(pose.inverse() * poses[*kf]));
                e.dot(&(info * e))
            }
            Factor::Between {
                from,
                to,
                measured,
                info,
                ..
            } => {
                let e = between_error(&poses[*from], &poses[*to], measured);
                e.dot(&(info * e))
            }
            Factor::Position { kf, enu_m, info } => {
                let e = poses[*kf].translation.vector - enu_m;
                e.dot(&(info * e))
            }
            Factor::Gravity { kf, up, info } => {
                info * gravity_error(&poses[*kf], up).norm_squared()
            }
        }
    }

    /// True for factors that get the robust kernel.
    pub fn is_robust(&self) -> bool {
        matches!(
            self,
            Factor::Between {
                kind: BetweenKind::Loop,
                ..
            }
        )
    }

    /// Linearises at `poses`.
    pub(crate) fn linearise(&self, poses: &[Isometry3<f64>]) -> Linearised {
        match self {
            Factor::Prior { kf, pose, info } => {
                let zi = pose.inverse();
                let f = |t: &Isometry3<f64>| se3::log(&(zi * t));
                Linearised {
                    error: f(&poses[*kf]),
                    blocks: vec![(*kf, numeric_jacobian(&poses[*kf], f))],
                    info: *info,
                }
            }
            Factor::Between {
                from,
                to,
                measured,
                info,
                ..
            } => {
                let (ti, tj) = (poses[*from], poses[*to]);
                let ji = numeric_jacobian(&ti, |t| between_error(t, &tj, measured));
                let jj = numeric_jacobian(&tj, |t| between_error(&ti, t, measured));
                Linearised {
                    error: between_error(&ti, &tj, measured),
                    blocks: vec![(*from, ji), (*to, jj)],
                    info: *info,
                }
            }
            Factor::Position { kf, enu_m, info } => {
                let t = poses[*kf];
                let e3 = t.translation.vector - enu_m;
                // d(translation)/d(v) of T exp([0, v]) is R; rotation does not move the origin.
                let r = t.rotation.to_rotation_matrix().into_inner();
                let mut j = Matrix6::zeros();
                j.fixed_view_mut::<3, 3>(0, 3).copy_from(&r);
                let mut inf = Matrix6::zeros();
                inf.fixed_view_mut::<3, 3>(0, 0).copy_from(info);
                Linearised {
                    error: Vector6::new(e3.x, e3.y, e3.z, 0.0, 0.0, 0.0),
                    blocks: vec![(*kf, j)],
                    info: inf,
                }
            }
            Factor::Gravity { kf, up, info } => {
                let f = |t: &Isometry3<f64>| gravity_error(t, up);
                Linearised {
                    error: f(&poses[*kf]),
                    blocks: vec![(*kf, numeric_jacobian(&poses[*kf], f))],
                    info: Matrix6::from_diagonal(&Vector6::new(*info, *info, *info, 0.0, 0.0, 0.0)),
                }
            }
        }
    }
}

/// Cauchy kernel `rho(s) = c^2 ln(1 + s/c^2)` on a squared Mahalanobis error `s`.
pub fn cauchy_cost(chi2: f64, c: f64) -> f64 {
    let c2 = c * c;
    c2 * (chi2 / c2).ln_1p()
}

/// The IRLS weight of the Cauchy kernel, `rho'(s)`.
pub fn cauchy_weight(chi2: f64, c: f64) -> f64 {
    1.0 / (1.0 + chi2 / (c * c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numeric_jacobian_of_between_matches_first_order_at_zero_error() {
        // At zero error the closed form is dE/dj = I and dE/di = -Ad(Tj^-1 Ti).
        let ti = se3::from_xyz_rpy([1.0, 2.0, 0.5], [0.1, -0.2, 0.7]);
        let tj = se3::from_xyz_rpy([3.0, -1.0, 0.2], [0.0, 0.1, -0.4]);
        let z = ti.inverse() * tj;
        let f = Factor::Between {
            from: 0,
            to: 1,
            measured: z,
            info: Matrix6::identity(),
            kind: BetweenKind::Odometry,
        };
        let l = f.linearise(&[ti, tj]);
        assert!(l.error.norm() < 1e-9);
        assert!((l.blocks[1].1 - Matrix6::identity()).norm() < 1e-5);
        // Moving both by the same right perturbation expressed in each frame keeps the error.
        let rel = tj.inverse() * ti;
        let r = rel.rotation.to_rotation_matrix().into_inner();
        let p = rel.translation.vector;
        let px = Matrix3::new(0.0, -p.z, p.y, p.z, 0.0, -p.x, -p.y, p.x, 0.0);
        let mut ad = Matrix6::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        ad.fixed_view_mut::<3, 3>(3, 0).copy_from(&(px * r));
        assert!((l.blocks[0].1 + ad).norm() < 1e-5, "{}", l.blocks[0].1);
    }

    #[test]
    fn cauchy_weight_and_cost_agree() {
        let c = 2.0;
        let s = 3.0;
        let h = 1e-6;
        let d = (cauchy_cost(s + h, c) - cauchy_cost(s - h, c)) / (2.0 * h);
        assert!((d - cauchy_weight(s, c)).abs() < 1e-8);
        assert_eq!(cauchy_weight(0.0, c), 1.0);
    }
}

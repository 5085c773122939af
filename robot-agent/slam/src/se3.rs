//! SE(3) helpers: the exponential/logarithm maps used for Gauss-Newton updates, velocity priors
//! and de-skewing. Twists are `[omega_x, omega_y, omega_z, v_x, v_y, v_z]` (rotation first).

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};

fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// The left Jacobian `V` of SO(3): `t = V v` in the SE(3) exponential.
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let th = w.norm();
    let k = hat(w);
    if th < 1e-6 {
        return Matrix3::identity() + 0.5 * k;
    }
    let a = (1.0 - th.cos()) / (th * th);
    let b = (th - th.sin()) / (th * th * th);
    Matrix3::identity() + a * k + b * k * k
}

/// `exp(xi)`: the rigid transform of a constant twist applied for unit time.
pub fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = Vector3::new(xi[0], xi[1], xi[2]);
    let v = Vector3::new(xi[3], xi[4], xi[5]);
    let t = left_jacobian(&w) * v;
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(w))
}

/// Below this angle the coefficients of [`exp_apply`] come from their Taylor series (five
/// terms: the first one left out is under 1e-17 relative), above it from `sin_cos`.
const SERIES_MAX_RAD: f64 = 0.1;

/// `exp(xi * t) * p`: a point moved by a constant twist applied for `t` (de-skewing a sweep,
/// one call per return). With `w = omega t`, `u = v t` and `th = |w|`, Rodrigues' formula and
/// the left Jacobian in cross products: `p + S w x p + A w x (w x p) + u + A w x u +
/// B w x (w x u)`, `S = sin th / th`, `A = (1 - cos th) / th^2`, `B = (th - sin th) / th^3`.
/// A sweep turns a few hundredths of a radian, so the three coefficients are short series
/// instead of three trigonometric calls per point ([`exp`] took ~5 % of the agent's time here);
/// the result agrees with [`exp`] to ~1e-16 relative, far below an `f32` coordinate's step.
pub fn exp_apply(xi: &Vector6<f64>, t: f64, p: &Vector3<f64>) -> Vector3<f64> {
    let w = Vector3::new(xi[0] * t, xi[1] * t, xi[2] * t);
    let u = Vector3::new(xi[3] * t, xi[4] * t, xi[5] * t);
    let th2 = w.norm_squared();
    let (s, a, b) = if th2 < SERIES_MAX_RAD * SERIES_MAX_RAD {
        let x = th2;
        (
            1.0 - x / 6.0 * (1.0 - x / 20.0 * (1.0 - x / 42.0 * (1.0 - x / 72.0))),
            0.5 * (1.0 - x / 12.0 * (1.0 - x / 30.0 * (1.0 - x / 56.0 * (1.0 - x / 90.0)))),
            (1.0 - x / 20.0 * (1.0 - x / 42.0 * (1.0 - x / 72.0 * (1.0 - x / 110.0)))) / 6.0,
        )
    } else {
        let th = th2.sqrt();
        let (sin, cos) = th.sin_cos();
        (sin / th, (1.0 - cos) / th2, (th - sin) / (th2 * th))
    };
    let wp = w.cross(p);
    let wu = w.cross(&u);
    p + wp * s + w.cross(&wp) * a + u + wu * a + w.cross(&wu) * b
}

/// `log(T)`: the twist whose exponential is `T` (inverse of [`exp`]).
pub fn log(t: &Isometry3<f64>) -> Vector6<f64> {
    let w = t.rotation.scaled_axis();
    let v = left_jacobian(&w)
        .try_inverse()
        .unwrap_or_else(Matrix3::identity)
        * t.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// Rotation angle of a transform, radians.
pub fn rotation_angle(t: &Isometry3<f64>) -> f64 {
    t.rotation.angle()
}

/// Translation length of a transform, metres.
pub fn translation_norm(t: &Isometry3<f64>) -> f64 {
    t.translation.vector.norm()
}

/// Transform from (x, y, z) metres and (roll, pitch, yaw) radians.
pub fn from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip() {
        let xi = Vector6::new(0.1, -0.2, 0.3, 1.0, -2.0, 0.5);
        let back = log(&exp(&xi));
        assert!((back - xi).norm() < 1e-9, "{back:?}");
    }

    #[test]
    fn exp_apply_matches_exp() {
        let xi = Vector6::new(0.3, -0.2, 0.9, 1.5, -0.4, 0.2);
        let p = Vector3::new(12.0, -7.5, 1.25);
        // Both sides of the series' limit (|omega| is 0.97 rad/s), and a negative time.
        for t in [0.0, 1e-9, 1e-7, 1e-4, 0.03, 0.1, 0.102, 0.11, 1.0, -0.05] {
            let want = (exp(&(xi * t)) * nalgebra::Point3::from(p)).coords;
            let got = exp_apply(&xi, t, &p);
            assert!((got - want).norm() < 1e-13, "t {t}: {got:?} vs {want:?}");
        }
        assert_eq!(exp_apply(&Vector6::zeros(), 0.1, &p), p);
    }

    #[test]
    fn exp_of_pure_rotation_and_translation() {
        let t = exp(&Vector6::new(0.0, 0.0, 0.0, 1.0, 2.0, 3.0));
        assert!((t.translation.vector - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
        let r = exp(&Vector6::new(
            0.0,
            0.0,
            std::f64::consts::FRAC_PI_2,
            0.0,
            0.0,
            0.0,
        ));
        let p = r * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!((p.coords - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn constant_twist_moves_on_an_arc() {
        // Half a turn at 1 rad/s and 1 m/s forward: a semicircle of radius 1 ends 2 m to the side.
        let xi = Vector6::new(
            0.0,
            0.0,
            std::f64::consts::PI,
            std::f64::consts::PI,
            0.0,
            0.0,
        );
        let t = exp(&xi);
        assert!(
            (t.translation.vector - Vector3::new(0.0, 2.0, 0.0)).norm() < 1e-9,
            "{t:?}"
        );
    }

    #[test]
    fn small_step_matches_first_order() {
        let xi = Vector6::new(1e-8, 0.0, 0.0, 1e-8, 0.0, 0.0);
        let t = exp(&xi);
        assert!((rotation_angle(&t) - 1e-8).abs() < 1e-14);
        assert!((translation_norm(&t) - 1e-8).abs() < 1e-14);
    }
}

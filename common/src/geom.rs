//! Small SE(2)/SE(3) helpers over nalgebra.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a_rad: f64) -> f64 {
    let w = (a_rad + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if w <= -std::f64::consts::PI {
        w + std::f64::consts::TAU
    } else {
        w
    }
}

/// A planar pose: position in metres, heading in radians (counter-clockwise from x).
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Pose2 {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Heading, radians.
    pub yaw_rad: f64,
}

impl Pose2 {
    /// A pose from its parts.
    pub fn new(x_m: f64, y_m: f64, yaw_rad: f64) -> Self {
        Self { x_m, y_m, yaw_rad }
    }

    /// `self * other`: other expressed in self's frame, mapped out.
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        let (s, c) = self.yaw_rad.sin_cos();
        Pose2 {
            x_m: self.x_m + c * other.x_m - s * other.y_m,
            y_m: self.y_m + s * other.x_m + c * other.y_m,
            yaw_rad: wrap_angle(self.yaw_rad + other.yaw_rad),
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.yaw_rad.sin_cos();
        Pose2 {
            x_m: -(c * self.x_m + s * self.y_m),
            y_m: -(-s * self.x_m + c * self.y_m),
            yaw_rad: wrap_angle(-self.yaw_rad),
        }
    }

    /// A point given in this pose's frame, expressed in the parent frame.
    pub fn transform_point(&self, x_m: f64, y_m: f64) -> (f64, f64) {
        let (s, c) = self.yaw_rad.sin_cos();
        (self.x_m + c * x_m - s * y_m, self.y_m + s * x_m + c * y_m)
    }

    /// Distance to another pose's position, metres.
    pub fn distance_to(&self, other: &Pose2) -> f64 {
        (self.x_m - other.x_m).hypot(self.y_m - other.y_m)
    }

    /// Dead reckoning over `dt_s` with speed `v_mps` and turn rate `omega_rps` (exact arc).
    pub fn integrate(&self, v_mps: f64, omega_rps: f64, dt_s: f64) -> Pose2 {
        let dth = omega_rps * dt_s;
        let (dx, dy) = if dth.abs() < 1e-9 {
            (v_mps * dt_s, 0.0)
        } else {
            let r = v_mps / omega_rps;
            (r * dth.sin(), r * (1.0 - dth.cos()))
        };
        self.compose(&Pose2::new(dx, dy, dth))
    }

    /// The pose as a 3D isometry at height `z_m` with zero pitch and roll.
    pub fn to_isometry3(&self, z_m: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.x_m, self.y_m, z_m),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw_rad),
        )
    }

    /// The planar part of a 3D isometry (yaw from its rotation).
    pub fn from_isometry3(iso: &Isometry3<f64>) -> Pose2 {
        let (_, _, yaw) = iso.rotation.euler_angles();
        Pose2::new(iso.translation.vector.x, iso.translation.vector.y, yaw)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_inverse_is_identity() {
        let p = Pose2::new(3.0, -2.0, 2.5);
        let q = p.compose(&p.inverse());
        assert!(q.x_m.abs() < 1e-12 && q.y_m.abs() < 1e-12 && q.yaw_rad.abs() < 1e-12);
    }

    #[test]
    fn integrate_quarter_circle() {
        let p = Pose2::default().integrate(1.0, 1.0, std::f64::consts::FRAC_PI_2);
        assert!((p.x_m - 1.0).abs() < 1e-12 && (p.y_m - 1.0).abs() < 1e-12);
        assert!((p.yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn wrap() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(-0.5) + 0.5).abs() < 1e-12);
    }

    #[test]
    fn isometry_round_trip() {
        let p = Pose2::new(1.0, 2.0, -1.0);
        let q = Pose2::from_isometry3(&p.to_isometry3(5.0));
        assert!((q.yaw_rad - p.yaw_rad).abs() < 1e-12 && (q.x_m - 1.0).abs() < 1e-12);
    }
}

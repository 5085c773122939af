//! The robot profile (`config/robot.toml`): body, mobility limits and sensor mounting.
//! Defaults are the source works' Clearpath Husky A200 (docs/algorithms.md §4).
//!
//! Shared by the agent (footprint, sensor mounts, limits), the simulator (the plant and the truth
//! labels) and the station (the limits it shows), so it lives here rather than in any of them.
//!
//! `base_link`: origin on the ground surface under the robot centre, x forward, y left, z up.
//! Sensor mounts are `base_link -> sensor` transforms given as position and roll/pitch/yaw
//! (degrees, applied as `Rz(yaw) Ry(pitch) Rx(roll)`; positive pitch tilts the x axis down).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::Deserialize;

/// A static `base_link -> sensor` transform.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Mount {
    /// Position in `base_link`, metres.
    pub xyz_m: [f64; 3],
    /// Roll, pitch, yaw, degrees.
    pub rpy_deg: [f64; 3],
}

impl Default for Mount {
    fn default() -> Self {
        Self {
            xyz_m: [0.0; 3],
            rpy_deg: [0.0; 3],
        }
    }
}

impl Mount {
    /// The transform `base_link <- sensor` (maps sensor-frame points into `base_link`).
    pub fn isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(Vector3::from(self.xyz_m)),
            UnitQuaternion::from_euler_angles(
                self.rpy_deg[0].to_radians(),
                self.rpy_deg[1].to_radians(),
                self.rpy_deg[2].to_radians(),
            ),
        )
    }
}

/// GNSS antenna positions (dual-antenna receiver: position from the primary, heading from the
/// baseline secondary -> primary).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssMount {
    /// Primary (position) antenna in `base_link`, metres.
    pub primary_xyz_m: [f64; 3],
    /// Secondary (heading) antenna in `base_link`, metres.
    pub secondary_xyz_m: [f64; 3],
}

impl Default for GnssMount {
    fn default() -> Self {
        // Primary straight above base_link so GGA is the robot position plus a vertical lever
        // arm; the 1 m baseline points forward so AVR yaw is the robot heading.
        Self {
            primary_xyz_m: [0.0, 0.0, 0.9],
            secondary_xyz_m: [-1.0, 0.0, 0.9],
        }
    }
}

/// Body, limits and sensor mounting of one robot.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotProfile {
    /// Profile name.
    pub name: String,
    /// Footprint length (x), metres.
    pub length_m: f64,
    /// Footprint width (y), metres.
    pub width_m: f64,
    /// Height including sensors, metres.
    pub height_m: f64,
    /// Extra clearance above `height_m` an overhang needs to be passable, metres.
    pub clearance_m: f64,
    /// Distance between the left and right wheel contact lines, metres.
    pub track_width_m: f64,
    /// Distance between front and rear axles, metres.
    pub wheelbase_m: f64,
    /// Highest step the robot climbs, metres (steps of this height or more are not climbable).
    pub max_step_m: f64,
    /// Steepest slope the robot climbs, degrees.
    pub max_slope_deg: f64,
    /// Forward speed limit, m/s.
    pub max_speed_mps: f64,
    /// Turn-rate limit, rad/s.
    pub max_omega_rps: f64,
    /// Wheel (track) speed limit, m/s.
    pub max_wheel_speed_mps: f64,
    /// Linear acceleration limit, m/s^2.
    pub max_accel_mps2: f64,
    /// Angular acceleration limit, rad/s^2.
    pub max_alpha_rps2: f64,
    /// VLP-16 mount.
    pub lidar: Mount,
    /// SR4000 depth-camera mount (x forward, y left, z up camera frame).
    pub depth_camera: Mount,
    /// GNSS antennas.
    pub gnss: GnssMount,
}

impl Default for RobotProfile {
    fn default() -> Self {
        Self {
            name: "husky-a200".into(),
            length_m: 1.0,
            width_m: 0.7,
            height_m: 1.0,
            clearance_m: 0.1,
            track_width_m: 0.555,
            wheelbase_m: 0.512,
            max_step_m: 0.1,
            max_slope_deg: 23.0,
            max_speed_mps: 1.0,
            max_omega_rps: 2.0,
            max_wheel_speed_mps: 1.0,
            max_accel_mps2: 1.0,
            max_alpha_rps2: 3.0,
            lidar: Mount {
                xyz_m: [0.0, 0.0, 0.75],
                rpy_deg: [0.0, 0.0, 0.0],
            },
            depth_camera: Mount {
                xyz_m: [0.45, 0.0, 0.65],
                rpy_deg: [0.0, 35.0, 0.0],
            },
            gnss: GnssMount::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_file_matches_defaults() {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/robot.toml");
        let text = std::fs::read_to_string(p).unwrap();
        // `[io]`, `[runtime]` and `[bus]` configure `robot-agent run`, not the body; its loader
        // takes them out before reading the profile.
        let mut table: toml::Table = toml::from_str(&text).unwrap();
        for section in ["io", "runtime", "bus"] {
            table.remove(section);
        }
        let prof: RobotProfile = toml::Value::Table(table).try_into().unwrap();
        assert_eq!(prof, RobotProfile::default());
    }

    #[test]
    fn pitch_tilts_down() {
        let m = RobotProfile::default().depth_camera.isometry();
        let fwd = m.rotation * Vector3::x();
        assert!(fwd.z < -0.5, "{fwd}");
    }
}

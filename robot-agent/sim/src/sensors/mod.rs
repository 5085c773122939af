//! Sensor models: VLP-16, SR4000 depth camera, wheel odometry, dual-antenna RTK GNSS.

mod gnss;
mod inertial;
mod lidar;

pub(crate) use gnss::Gnss;
pub use gnss::GnssFix;
pub(crate) use inertial::{Imu, Odometry};
pub(crate) use lidar::{depth_frame, Lidar};
use serde::Deserialize;

/// VLP-16 laser elevations in firing order (laser id 0..15), degrees.
pub const VLP16_ELEVATIONS_DEG: [f64; 16] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];
/// Time between two lasers' firings in one VLP-16 firing sequence, seconds.
pub const VLP16_LASER_DT_S: f64 = 2.304e-6;

/// VLP-16 model parameters.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LidarConfig {
    /// Produce scans at all.
    pub enabled: bool,
    /// Rotation rate, Hz.
    pub rate_hz: f64,
    /// Firing columns per rotation (0.2 deg at 10 Hz = 1800).
    pub columns: usize,
    /// Maximum range, metres.
    pub max_range_m: f64,
    /// Minimum range, metres (closer returns are dropped, as the sensor does).
    pub min_range_m: f64,
    /// Range noise standard deviation, metres (+-3 cm at 2 sigma).
    pub range_noise_sigma_m: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            columns: 1800,
            max_range_m: 100.0,
            min_range_m: 0.4,
            range_noise_sigma_m: 0.015,
        }
    }
}

/// SR4000 depth-camera parameters.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthConfig {
    /// Produce frames at all.
    pub enabled: bool,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// Image width, pixels.
    pub width_px: usize,
    /// Image height, pixels.
    pub height_px: usize,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f64,
    /// Vertical field of view, degrees.
    pub vfov_deg: f64,
    /// Maximum range, metres.
    pub max_range_m: f64,
    /// Range noise standard deviation, metres.
    pub range_noise_sigma_m: f64,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            width_px: 176,
            height_px: 144,
            hfov_deg: 69.0,
            vfov_deg: 56.0,
            max_range_m: 5.0,
            range_noise_sigma_m: 0.005,
        }
    }
}

/// Wheel-odometry error model.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdomConfig {
    /// Produce samples at all.
    pub enabled: bool,
    /// Sample rate, Hz (at most one sample per `step`).
    pub rate_hz: f64,
    /// Distance scale error (0.02 = odometry reads 2 % long).
    pub scale_error: f64,
    /// Constant yaw-rate bias, rad/s.
    pub yaw_drift_rps: f64,
    /// White noise on the measured speed, m/s.
    pub v_noise_mps: f64,
    /// White noise on the measured turn rate, rad/s.
    pub omega_noise_rps: f64,
}

impl Default for OdomConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 50.0,
            scale_error: 0.02,
            yaw_drift_rps: 0.002,
            v_noise_mps: 0.01,
            omega_noise_rps: 0.005,
        }
    }
}

/// IMU accelerometer error model (a MEMS unit of the kind ground robots carry).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImuConfig {
    /// Produce samples at all.
    pub enabled: bool,
    /// Sample rate, Hz (at most one sample per simulator sub-step of 20 ms).
    pub rate_hz: f64,
    /// White noise per sample and axis, m/s^2.
    pub accel_noise_mps2: f64,
    /// Standard deviation of the constant per-axis bias drawn at start-up, m/s^2
    /// (0.01 m/s^2 reads as a 0.06 deg tilt).
    pub accel_bias_mps2: f64,
    /// Gyroscope white noise per sample and axis, rad/s.
    pub gyro_noise_rps: f64,
    /// Standard deviation of the gyroscope's constant per-axis bias, rad/s (0.002: 0.1 deg/s,
    /// an uncalibrated MEMS part after warm-up).
    pub gyro_bias_rps: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 50.0,
            accel_noise_mps2: 0.02,
            accel_bias_mps2: 0.01,
            gyro_noise_rps: 0.002,
            gyro_bias_rps: 0.002,
        }
    }
}

/// GNSS receiver model.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GnssConfig {
    /// Produce sentences at all.
    pub enabled: bool,
    /// Epoch rate, Hz.
    pub rate_hz: f64,
    /// UTC time of day at simulation time 0, seconds.
    pub utc_start_s: f64,
    /// Geoid separation written into GGA, metres (GGA altitude = ellipsoidal height - this).
    pub geoid_separation_m: f64,
    /// RTK fixed: horizontal noise standard deviation, metres.
    pub rtk_sigma_m: f64,
    /// RTK float: noise standard deviation, metres.
    pub float_sigma_m: f64,
    /// Single point: noise standard deviation, metres.
    pub single_sigma_m: f64,
    /// Heading noise standard deviation with RTK fixed, degrees.
    pub heading_sigma_deg: f64,
    /// RTK is lost within this distance of a tall structure (wall or box >= 2 m), metres.
    pub rtk_loss_distance_m: f64,
    /// No fix at all within this distance, metres.
    pub no_fix_distance_m: f64,
    /// After RTK loss, seconds of RTK float before fixed again.
    pub float_after_loss_s: f64,
    /// Seconds of RTK float at start.
    pub initial_float_s: f64,
}

impl Default for GnssConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            rate_hz: 10.0,
            utc_start_s: 12.0 * 3600.0,
            geoid_separation_m: 0.0,
            rtk_sigma_m: 0.01,
            float_sigma_m: 0.15,
            single_sigma_m: 1.5,
            heading_sigma_deg: 0.2,
            rtk_loss_distance_m: 4.0,
            no_fix_distance_m: 1.5,
            float_after_loss_s: 10.0,
            initial_float_s: 0.0,
        }
    }
}

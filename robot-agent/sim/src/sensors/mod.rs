//! Sensor models: spinning LiDARs (VLP-16, HDL-32E, OS1-64), SR4000 depth camera, wheel odometry,
//! dual-antenna RTK GNSS.

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

/// The spinning LiDARs the simulator models: each one's laser table and firing timing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LidarModel {
    /// Velodyne VLP-16: 16 lasers 2 deg apart over +-15 deg, interleaved firing.
    #[default]
    Vlp16,
    /// Velodyne HDL-32E: 32 lasers 1.33 deg apart from -30.67 to +10.67 deg, interleaved.
    Hdl32e,
    /// Ouster OS1-64 (gen 1): 64 lasers evenly over +-16.6 deg, fired together, 1024 columns.
    Os1_64,
}

impl std::str::FromStr for LidarModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "vlp16" | "vlp-16" => Ok(LidarModel::Vlp16),
            "hdl32e" | "hdl-32e" | "hdl32" => Ok(LidarModel::Hdl32e),
            "os1-64" | "os1_64" | "os164" => Ok(LidarModel::Os1_64),
            _ => Err(format!(
                "unknown LiDAR model {s:?}; the simulator has vlp16, hdl32e and os1-64"
            )),
        }
    }
}

impl LidarModel {
    /// Laser elevations in firing order (laser id 0..n), degrees.
    pub fn elevations_deg(self) -> Vec<f64> {
        match self {
            LidarModel::Vlp16 => VLP16_ELEVATIONS_DEG.to_vec(),
            // Even ids climb from -30.67 deg, odd ids from -9.33 deg, 4/3 deg apart.
            LidarModel::Hdl32e => (0..32)
                .map(|id| {
                    let base = if id % 2 == 0 { -30.67 } else { -9.33 };
                    base + (id / 2) as f64 * (4.0 / 3.0)
                })
                .collect(),
            LidarModel::Os1_64 => (0..64).map(|id| 16.6 - id as f64 * (33.2 / 63.0)).collect(),
        }
    }

    /// Time between two lasers' firings within one column, seconds.
    pub fn laser_dt_s(self) -> f64 {
        match self {
            LidarModel::Vlp16 => VLP16_LASER_DT_S,
            LidarModel::Hdl32e => 1.152e-6,
            LidarModel::Os1_64 => 0.0,
        }
    }

    /// Firing columns per rotation at `rate_hz`: the Velodynes fire columns at a fixed rate, so a
    /// slower spin gives finer columns; the Ouster's column count is fixed.
    pub fn columns(self, rate_hz: f64) -> usize {
        let per_s = match self {
            LidarModel::Vlp16 => 18_000.0,
            LidarModel::Hdl32e => 21_700.0,
            LidarModel::Os1_64 => return 1024,
        };
        (per_s / rate_hz.max(0.1)).round().max(1.0) as usize
    }
}

/// Spinning-LiDAR model parameters.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LidarConfig {
    /// Produce scans at all.
    pub enabled: bool,
    /// Which sensor: laser table and firing timing.
    pub model: LidarModel,
    /// Rotation rate, Hz.
    pub rate_hz: f64,
    /// Firing columns per rotation (VLP-16: 0.2 deg at 10 Hz = 1800).
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
        Self::of(LidarModel::Vlp16, 10.0)
    }
}

impl LidarConfig {
    /// `model` spinning at `rate_hz`, with its own column count.
    pub fn of(model: LidarModel, rate_hz: f64) -> Self {
        Self {
            enabled: true,
            model,
            rate_hz,
            columns: model.columns(rate_hz),
            max_range_m: 100.0,
            min_range_m: 0.4,
            range_noise_sigma_m: 0.015,
        }
    }

    /// Parses `MODEL[@HZ]` (`vlp16`, `vlp16@2`, `hdl32e@10`, `os1-64`); 10 Hz when no rate is
    /// given.
    pub fn parse_spec(spec: &str) -> Result<Self, String> {
        let (model, hz) = match spec.split_once('@') {
            Some((m, hz)) => {
                let hz: f64 = hz.trim().parse().map_err(|_| {
                    format!("bad rotation rate {hz:?} in {spec:?} (Hz, e.g. vlp16@2)")
                })?;
                (m, hz)
            }
            None => (spec, 10.0),
        };
        if !(1.0..=40.0).contains(&hz) {
            return Err(format!(
                "rotation rate {hz} Hz in {spec:?} is outside 1-40 Hz"
            ));
        }
        Ok(Self::of(model.trim().parse()?, hz))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laser_tables_span_the_datasheet_fields_of_view() {
        for (m, n, lo, hi) in [
            (LidarModel::Vlp16, 16, -15.0, 15.0),
            (LidarModel::Hdl32e, 32, -30.67, 10.67),
            (LidarModel::Os1_64, 64, -16.6, 16.6),
        ] {
            let e = m.elevations_deg();
            assert_eq!(e.len(), n, "{m:?}");
            let min = e.iter().cloned().fold(f64::INFINITY, f64::min);
            let max = e.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            assert!(
                (min - lo).abs() < 0.01 && (max - hi).abs() < 0.01,
                "{m:?}: {min}..{max}"
            );
            let mut s = e.clone();
            s.sort_by(f64::total_cmp);
            assert!(
                s.windows(2).all(|w| w[1] - w[0] > 0.4),
                "{m:?}: distinct lasers"
            );
        }
    }

    #[test]
    fn specs_parse_with_their_rates_and_bad_ones_say_why() {
        let c = LidarConfig::parse_spec("vlp16@2").unwrap();
        assert_eq!(
            (c.model, c.rate_hz, c.columns),
            (LidarModel::Vlp16, 2.0, 9000)
        );
        assert_eq!(
            LidarConfig::parse_spec("vlp16").unwrap(),
            LidarConfig::default()
        );
        let c = LidarConfig::parse_spec("HDL-32E@10").unwrap();
        assert_eq!((c.model, c.columns), (LidarModel::Hdl32e, 2170));
        assert_eq!(LidarConfig::parse_spec("os1-64@20").unwrap().columns, 1024);
        assert!(LidarConfig::parse_spec("vlp32")
            .unwrap_err()
            .contains("vlp16"));
        assert!(LidarConfig::parse_spec("vlp16@x")
            .unwrap_err()
            .contains("rate"));
        assert!(LidarConfig::parse_spec("vlp16@0")
            .unwrap_err()
            .contains("1-40"));
    }
}

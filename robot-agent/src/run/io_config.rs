//! The `[io]`, `[runtime]` and `[bus]` sections of `config/robot.toml`: where a real robot's sensors come
//! from and its base commands go, and the runtime's stamp and silence limits. Read by
//! `crate::config` (the one reader of the robot file); every key can be overridden on the
//! `robot-agent run` command line.

use crate::runtime::faults::SilenceLimits;
use crate::runtime::stamps::StampLimits;
use crate::runtime::RuntimeLimits;
use serde::Deserialize;

/// `[io]`: sources as `KIND:ARGS` specs (`io::source::SourceSpec`); an empty string is "none".
/// The defaults are what a ROS 2 Clearpath Husky publishes.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct IoConfig {
    /// LiDAR: `ros2:TOPIC` (PointCloud2) or `vlp16-udp:PORT`.
    pub lidar: String,
    /// Message type of a `ros2:` LiDAR topic: `PointCloud2` (`sensor_msgs`), or `VelodyneScan`
    /// (`velodyne_msgs`: a VLP-16 driver's raw packets, decoded by terranav).
    pub lidar_msg: String,
    /// Depth camera: `ros2:TOPIC` (PointCloud2), or empty.
    pub depth: String,
    /// Wheel odometry: `ros2:TOPIC` (nav_msgs/Odometry).
    pub odom: String,
    /// IMU: `ros2:TOPIC` (sensor_msgs/Imu), or empty.
    pub imu: String,
    /// GNSS: `ros2:TOPIC` (NavSatFix), `nmea-serial:DEV@BAUD`, `nmea-tcp:HOST:PORT`,
    /// `nmea-udp:PORT`, `gpsd:HOST[:PORT]`, or empty.
    pub gnss: String,
    /// True heading: `ros2:TOPIC` (geometry_msgs/QuaternionStamped, ENU), or empty (NMEA and
    /// gpsd sources bring their own).
    pub heading: String,
    /// Base commands: `ros2:TOPIC` (geometry_msgs/Twist), or empty (the robot is not driven).
    pub cmd_vel: String,
    /// A navigation computer that follows waypoint lists (`orpheus-udp:HOST:PORT`), or empty:
    /// missions go to it as routes, and `cmd_vel` keeps only the operator's driving.
    pub nav_computer: String,
    /// ROS 2 key form: `bridge` (zenoh-bridge-ros2dds) or `rmw` (rmw_zenoh).
    pub ros2_keys: String,
    /// ROS 2 namespace of the robot's topics (empty for none).
    pub ros2_namespace: String,
    /// ROS_DOMAIN_ID (rmw form).
    pub ros2_domain_id: u32,
    /// Zenoh endpoints of the robot's ROS 2 side (the bridge, or rmw_zenoh's router), e.g.
    /// `tcp/127.0.0.1:7447`; empty: the station's session settings are used for it too.
    pub ros2_connect: Vec<String>,
}

impl Default for IoConfig {
    fn default() -> Self {
        Self {
            lidar: "ros2:velodyne_points".into(),
            lidar_msg: "PointCloud2".into(),
            depth: String::new(),
            odom: "ros2:odom".into(),
            imu: "ros2:imu/data".into(),
            gnss: "ros2:fix".into(),
            heading: String::new(),
            cmd_vel: "ros2:cmd_vel".into(),
            nav_computer: String::new(),
            ros2_keys: "bridge".into(),
            ros2_namespace: String::new(),
            ros2_domain_id: 0,
            ros2_connect: Vec::new(),
        }
    }
}

/// `[runtime]`: the stamp gate and the sensor watchdog.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct RuntimeConfig {
    /// LiDAR silence after which the base is stopped, seconds.
    pub lidar_timeout_s: f64,
    /// Odometry silence reported as a fault, seconds.
    pub odom_timeout_s: f64,
    /// IMU silence reported as a fault, seconds.
    pub imu_timeout_s: f64,
    /// GNSS silence after which the robot is on SLAM only (reported), seconds.
    pub gnss_timeout_s: f64,
    /// How far a stamp may lead the newest accepted stamp of any input, seconds.
    pub max_stamp_lead_s: f64,
    /// How far a stamp may trail it (sensor latency plus transport), seconds.
    pub max_stamp_lag_s: f64,
    /// With GNSS, how long the first sweeps wait for an RTK fixed fix with a heading to anchor
    /// the map in ENU at the datum (else the map is the first pose's frame), seconds.
    pub anchor_wait_s: f64,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        let l = RuntimeLimits::default();
        Self {
            lidar_timeout_s: l.silence.lidar_timeout_s,
            odom_timeout_s: l.silence.odom_timeout_s,
            imu_timeout_s: l.silence.imu_timeout_s,
            gnss_timeout_s: l.silence.gnss_timeout_s,
            max_stamp_lead_s: l.stamps.max_lead_s,
            max_stamp_lag_s: l.stamps.max_lag_s,
            anchor_wait_s: l.anchor_wait_s,
        }
    }
}

impl RuntimeConfig {
    /// The limits, checked: every value finite and positive.
    pub fn limits(&self) -> anyhow::Result<RuntimeLimits> {
        for (k, v) in [
            ("lidar_timeout_s", self.lidar_timeout_s),
            ("odom_timeout_s", self.odom_timeout_s),
            ("imu_timeout_s", self.imu_timeout_s),
            ("gnss_timeout_s", self.gnss_timeout_s),
            ("max_stamp_lead_s", self.max_stamp_lead_s),
            ("max_stamp_lag_s", self.max_stamp_lag_s),
            ("anchor_wait_s", self.anchor_wait_s),
        ] {
            anyhow::ensure!(v.is_finite() && v > 0.0, "[runtime] {k} = {v}: must be > 0");
        }
        Ok(RuntimeLimits {
            stamps: StampLimits {
                max_lead_s: self.max_stamp_lead_s,
                max_lag_s: self.max_stamp_lag_s,
            },
            silence: SilenceLimits {
                lidar_timeout_s: self.lidar_timeout_s,
                odom_timeout_s: self.odom_timeout_s,
                imu_timeout_s: self.imu_timeout_s,
                gnss_timeout_s: self.gnss_timeout_s,
            },
            anchor_wait_s: self.anchor_wait_s,
        })
    }
}

/// Both sections.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunFile {
    /// `[io]`.
    pub io: IoConfig,
    /// `[runtime]`.
    pub runtime: RuntimeConfig,
    /// `[bus]`.
    pub bus: crate::bus::BusFile,
}

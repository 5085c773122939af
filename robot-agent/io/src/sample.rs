//! What the sources deliver and the sinks take, independent of the wire they came over (ROS 2
//! CDR, NMEA, gpsd JSON). Stamps are seconds on the sender's clock (the ROS header stamp, or for
//! NMEA the receive time the source adds); frames follow REP 103/105 (x forward, z up, ENU world).

/// A unit quaternion `[x, y, z, w]` (ROS order).
pub type Quat = [f64; 4];

/// A point cloud (from `sensor_msgs/msg/PointCloud2`), in `frame_id`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cloud {
    /// Header stamp, seconds.
    pub stamp_s: f64,
    /// Frame the points are in (`base_link`, `velodyne`, ...).
    pub frame_id: String,
    /// Points, metres. Non-finite points of a non-dense cloud are dropped (and counted in
    /// `dropped_non_finite`).
    pub points: Vec<[f32; 3]>,
    /// Per-point intensity, when the cloud has an `intensity` field.
    pub intensity: Option<Vec<f32>>,
    /// Per-point laser ring, when the cloud has a `ring` or `channel` field.
    pub ring: Option<Vec<u16>>,
    /// Per-point time relative to `stamp_s`, seconds, when the cloud has `t`, `time` or
    /// `timestamp` (absolute times are made relative; nanosecond integers are scaled).
    pub time_s: Option<Vec<f32>>,
    /// Points dropped because a coordinate was NaN or infinite.
    pub dropped_non_finite: usize,
}

/// Odometry (from `nav_msgs/msg/Odometry`): the pose of `child_frame_id` in `frame_id`, and its
/// velocity in `child_frame_id`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Odometry {
    /// Header stamp, seconds.
    pub stamp_s: f64,
    /// Frame of the pose (`odom`).
    pub frame_id: String,
    /// Frame of the body (`base_link`).
    pub child_frame_id: String,
    /// Position, metres.
    pub position_m: [f64; 3],
    /// Orientation.
    pub orientation: Quat,
    /// Forward speed (twist.linear.x), m/s.
    pub linear_x_mps: f64,
    /// Yaw rate (twist.angular.z), rad/s.
    pub angular_z_rps: f64,
}

/// An IMU sample (from `sensor_msgs/msg/Imu`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Imu {
    /// Header stamp, seconds.
    pub stamp_s: f64,
    /// Frame of the IMU.
    pub frame_id: String,
    /// Orientation, absent when the message says it has none (covariance[0] == -1).
    pub orientation: Option<Quat>,
    /// Angular velocity, rad/s.
    pub angular_velocity_rps: [f64; 3],
    /// Linear acceleration (gravity included), m/s².
    pub linear_acceleration_mps2: [f64; 3],
}

/// Fix status, as in `sensor_msgs/msg/NavSatStatus`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FixStatus {
    /// No fix.
    NoFix,
    /// Autonomous fix.
    Fix,
    /// Satellite-based augmentation (SBAS, or DGPS).
    Sbas,
    /// Ground-based augmentation (RTK).
    Gbas,
}

impl FixStatus {
    /// From the ROS `status.status` byte (-1 no fix, 0 fix, 1 SBAS, 2 GBAS).
    pub fn from_ros(status: i8) -> Self {
        match status {
            0 => FixStatus::Fix,
            1 => FixStatus::Sbas,
            2 => FixStatus::Gbas,
            _ => FixStatus::NoFix,
        }
    }

    /// To the ROS `status.status` byte.
    pub fn to_ros(self) -> i8 {
        match self {
            FixStatus::NoFix => -1,
            FixStatus::Fix => 0,
            FixStatus::Sbas => 1,
            FixStatus::Gbas => 2,
        }
    }

    /// From an NMEA GGA quality indicator (0 invalid, 1 GPS, 2 DGPS, 4/5 RTK, 6 dead reckoning).
    pub fn from_gga_quality(quality: u8) -> Self {
        match quality {
            1 | 3 => FixStatus::Fix,
            2 | 9 => FixStatus::Sbas,
            4 | 5 => FixStatus::Gbas,
            _ => FixStatus::NoFix,
        }
    }
}

/// A GNSS fix (from `sensor_msgs/msg/NavSatFix`, NMEA GGA or a gpsd TPV report).
#[derive(Clone, Debug, PartialEq)]
pub struct NavFix {
    /// Stamp, seconds.
    pub stamp_s: f64,
    /// Latitude, degrees north (WGS-84).
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, metres (NaN when unknown).
    pub alt_m: f64,
    /// Fix quality.
    pub status: FixStatus,
    /// Position covariance, ENU, row-major, m²; `None` when unknown.
    pub covariance_m2: Option<[f64; 9]>,
    /// The receiver's GGA quality (1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning)
    /// when the source reports it (gpsd's TPV `status`); `None` for ROS `NavSatFix`, whose one
    /// ground-augmented status cannot tell RTK fixed from float.
    pub gga_quality: Option<u8>,
}

/// A true heading (dual-antenna receiver, NMEA HDT/THS, or a ROS heading topic).
#[derive(Clone, Debug, PartialEq)]
pub struct Heading {
    /// Stamp, seconds.
    pub stamp_s: f64,
    /// Heading, degrees clockwise from true north, in [0, 360).
    pub heading_deg: f64,
}

/// A rigid transform `child_frame_id` -> `frame_id` (from `tf2_msgs/msg/TFMessage`, usually
/// `tf_static`): a point p in the child frame is `rotation * p + translation` in the parent.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Transform {
    /// Stamp, seconds.
    pub stamp_s: f64,
    /// Parent frame.
    pub frame_id: String,
    /// Child frame.
    pub child_frame_id: String,
    /// Translation, metres.
    pub translation_m: [f64; 3],
    /// Rotation.
    pub rotation: Quat,
}

/// A base velocity command (to `geometry_msgs/msg/Twist` on `cmd_vel`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Twist {
    /// Forward speed, m/s.
    pub linear_x_mps: f64,
    /// Yaw rate, rad/s (counter-clockwise positive).
    pub angular_z_rps: f64,
}

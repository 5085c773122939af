//! Points, scans and the other timestamped samples the robot consumes.

use common::geom::Pose2;

/// One LiDAR return.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Point {
    /// x, metres, in the scan's frame (the sensor frame unless stated otherwise).
    pub x: f32,
    /// y, metres.
    pub y: f32,
    /// z, metres.
    pub z: f32,
    /// Return intensity (sensor units, 0 when unknown).
    pub intensity: f32,
    /// Laser (ring) index, 0 when unknown.
    pub ring: u16,
    /// Time of the return relative to the scan's `stamp_s`, seconds (0 when the sensor gives none);
    /// scans are swept while the robot moves, so de-skewing needs it.
    pub t_s: f32,
}

impl Point {
    /// A point with position only.
    pub fn xyz(x: f32, y: f32, z: f32) -> Self {
        Self {
            x,
            y,
            z,
            ..Self::default()
        }
    }

    /// True when all coordinates are finite (real drivers and files can carry NaN for no return).
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }

    /// Distance from the frame origin, metres.
    pub fn range_m(&self) -> f32 {
        (self.x * self.x + self.y * self.y + self.z * self.z).sqrt()
    }
}

/// One sweep of a LiDAR (or one depth-camera frame), in the sensor frame.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Scan {
    /// Time of the first return, seconds (session clock, simulated or real).
    pub stamp_s: f64,
    /// The returns; `Point::t_s` is relative to `stamp_s`.
    pub points: Vec<Point>,
}

impl Scan {
    /// Drops non-finite points, returning how many were dropped (callers count them as bad input).
    pub fn retain_finite(&mut self) -> usize {
        let before = self.points.len();
        self.points.retain(Point::is_finite);
        before - self.points.len()
    }
}

/// One wheel-odometry reading: the dead-reckoned pose in the `odom` frame.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct OdomSample {
    /// Time, seconds (session clock).
    pub t_s: f64,
    /// Pose of `base_link` in `odom`.
    pub pose_odom: Pose2,
    /// Forward speed, m/s.
    pub v_mps: f64,
    /// Turn rate, rad/s.
    pub omega_rps: f64,
}

/// One reading of an IMU mounted at `base_link`: accelerometer, and gyroscope when it has one.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ImuSample {
    /// Time, seconds (session clock): the end of the interval the reading averages.
    pub t_s: f64,
    /// Specific force (acceleration less gravity, so +9.81 up at rest) in `base_link`, averaged
    /// over the sample interval as an IMU's anti-aliasing filter does, m/s^2.
    pub accel_mps2: [f64; 3],
    /// Angular rate of `base_link` about its own axes, averaged over the same interval, rad/s
    /// (`None`: the unit has no gyroscope, or did not report it).
    pub gyro_rps: Option<[f64; 3]>,
}

/// One NMEA-0183 sentence as received from a GNSS receiver, with its arrival time.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct GnssSentence {
    /// Arrival time, seconds (session clock).
    pub t_s: f64,
    /// The sentence text, `$` to checksum (line ending optional).
    pub text: String,
}

/// One position fix as a driver decoded it (ROS 2 `NavSatFix`, a gpsd report) rather than as
/// NMEA text.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct GnssFixSample {
    /// Time, seconds (session clock).
    pub t_s: f64,
    /// Latitude, degrees north (WGS-84).
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, metres.
    pub h_m: f64,
    /// Quality in GGA terms (0 none, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float).
    pub quality: u8,
    /// Satellites used, when the source says (`NavSatFix` does not).
    pub satellites: Option<u8>,
}

/// A true heading (dual-antenna receiver) as a driver decoded it.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct GnssHeadingSample {
    /// Time, seconds (session clock).
    pub t_s: f64,
    /// Heading of base_link, degrees clockwise from true north.
    pub heading_deg: f64,
}

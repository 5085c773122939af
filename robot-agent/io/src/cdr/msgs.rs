//! The fixed-layout ROS 2 messages terranav reads and writes, field by field as in their `.msg`
//! definitions (std_msgs/Header = builtin_interfaces/Time stamp + string frame_id).

use super::{CdrError, Reader, Writer};
use crate::sample::{FixStatus, Heading, Imu, NavFix, Odometry, Quat, Transform, Twist};

/// `std_msgs/msg/Header` fields.
pub(crate) fn read_header(r: &mut Reader<'_>) -> Result<(f64, String), CdrError> {
    let sec = r.i32("header.stamp.sec")?;
    let nanosec = r.u32("header.stamp.nanosec")?;
    if nanosec >= 1_000_000_000 {
        return Err(CdrError::Invalid {
            what: "header.stamp",
            why: format!("nanosec {nanosec} >= 1e9"),
        });
    }
    let frame = r.string("header.frame_id")?;
    Ok((sec as f64 + nanosec as f64 * 1e-9, frame))
}

/// Writes a `std_msgs/msg/Header`.
pub(crate) fn write_header(w: &mut Writer, stamp_s: f64, frame_id: &str) {
    let sec = stamp_s.floor();
    let mut nanosec = ((stamp_s - sec) * 1e9).round() as u32;
    let mut sec = sec as i32;
    if nanosec >= 1_000_000_000 {
        sec += 1;
        nanosec -= 1_000_000_000;
    }
    w.i32(sec);
    w.u32(nanosec);
    w.string(frame_id);
}

fn read_quat(r: &mut Reader<'_>, what: &'static str) -> Result<Quat, CdrError> {
    normalised(r.f64s::<4>(what)?, what)
}

/// The quaternion made exactly unit, or an error if it is far from unit (or not finite).
fn normalised(q: Quat, what: &'static str) -> Result<Quat, CdrError> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !n.is_finite() || (n - 1.0).abs() > 1e-3 {
        return Err(CdrError::Invalid {
            what,
            why: format!("quaternion norm {n} is not 1"),
        });
    }
    Ok(q.map(|v| v / n))
}

fn finite<const N: usize>(v: [f64; N], what: &'static str) -> Result<[f64; N], CdrError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(CdrError::Invalid {
            what,
            why: "non-finite value".into(),
        })
    }
}

/// Decodes `nav_msgs/msg/Odometry`.
pub fn decode_odometry(msg: &[u8]) -> Result<Odometry, CdrError> {
    let mut r = Reader::new(msg)?;
    let (stamp_s, frame_id) = read_header(&mut r)?;
    let child_frame_id = r.string("child_frame_id")?;
    let position_m = finite(r.f64s::<3>("pose.position")?, "pose.position")?;
    let orientation = read_quat(&mut r, "pose.orientation")?;
    r.f64s::<36>("pose.covariance")?;
    let linear = finite(r.f64s::<3>("twist.linear")?, "twist.linear")?;
    let angular = finite(r.f64s::<3>("twist.angular")?, "twist.angular")?;
    r.f64s::<36>("twist.covariance")?;
    Ok(Odometry {
        stamp_s,
        frame_id,
        child_frame_id,
        position_m,
        orientation,
        linear_x_mps: linear[0],
        angular_z_rps: angular[2],
    })
}

/// Encodes `nav_msgs/msg/Odometry` (covariances zero).
pub fn encode_odometry(o: &Odometry) -> Vec<u8> {
    let mut w = Writer::new();
    write_header(&mut w, o.stamp_s, &o.frame_id);
    w.string(&o.child_frame_id);
    w.f64s(&o.position_m);
    w.f64s(&o.orientation);
    w.f64s(&[0.0; 36]);
    w.f64s(&[o.linear_x_mps, 0.0, 0.0, 0.0, 0.0, o.angular_z_rps]);
    w.f64s(&[0.0; 36]);
    w.finish()
}

/// Decodes `sensor_msgs/msg/Imu`.
pub fn decode_imu(msg: &[u8]) -> Result<Imu, CdrError> {
    let mut r = Reader::new(msg)?;
    let (stamp_s, frame_id) = read_header(&mut r)?;
    let q = r.f64s::<4>("orientation")?;
    let orientation_cov = r.f64s::<9>("orientation_covariance")?;
    // REP 145: covariance[0] == -1 says "no orientation estimate"; the quaternion is then junk.
    let orientation = if orientation_cov[0] == -1.0 {
        None
    } else {
        Some(normalised(q, "orientation")?)
    };
    let angular_velocity_rps = finite(r.f64s::<3>("angular_velocity")?, "angular_velocity")?;
    r.f64s::<9>("angular_velocity_covariance")?;
    let linear_acceleration_mps2 =
        finite(r.f64s::<3>("linear_acceleration")?, "linear_acceleration")?;
    r.f64s::<9>("linear_acceleration_covariance")?;
    Ok(Imu {
        stamp_s,
        frame_id,
        orientation,
        angular_velocity_rps,
        linear_acceleration_mps2,
    })
}

/// Encodes `sensor_msgs/msg/Imu` (covariances zero, or -1 for a missing orientation).
pub fn encode_imu(m: &Imu) -> Vec<u8> {
    let mut w = Writer::new();
    write_header(&mut w, m.stamp_s, &m.frame_id);
    w.f64s(&m.orientation.unwrap_or([0.0, 0.0, 0.0, 1.0]));
    let mut cov = [0.0; 9];
    if m.orientation.is_none() {
        cov[0] = -1.0;
    }
    w.f64s(&cov);
    w.f64s(&m.angular_velocity_rps);
    w.f64s(&[0.0; 9]);
    w.f64s(&m.linear_acceleration_mps2);
    w.f64s(&[0.0; 9]);
    w.finish()
}

/// Decodes `sensor_msgs/msg/NavSatFix`. A fix whose status says "no fix" may carry NaN
/// coordinates; any other non-finite or out-of-range latitude/longitude is an error.
pub fn decode_nav_sat_fix(msg: &[u8]) -> Result<NavFix, CdrError> {
    let mut r = Reader::new(msg)?;
    let (stamp_s, _frame) = read_header(&mut r)?;
    let status = FixStatus::from_ros(r.i8("status.status")?);
    r.u16("status.service")?;
    let lat_deg = r.f64("latitude")?;
    let lon_deg = r.f64("longitude")?;
    let alt_m = r.f64("altitude")?;
    let cov = r.f64s::<9>("position_covariance")?;
    let cov_type = r.u8("position_covariance_type")?;
    if status != FixStatus::NoFix
        && !(lat_deg.abs() <= 90.0 && lon_deg.abs() <= 180.0 && alt_m.is_finite())
    {
        return Err(CdrError::Invalid {
            what: "NavSatFix",
            why: format!("position ({lat_deg}, {lon_deg}, {alt_m}) out of range"),
        });
    }
    let covariance_m2 = (cov_type != 0 && cov.iter().all(|v| v.is_finite())).then_some(cov);
    Ok(NavFix {
        stamp_s,
        lat_deg,
        lon_deg,
        alt_m,
        status,
        covariance_m2,
        gga_quality: None,
    })
}

/// Encodes `sensor_msgs/msg/NavSatFix` (service GPS, frame `gps`).
pub fn encode_nav_sat_fix(f: &NavFix) -> Vec<u8> {
    let mut w = Writer::new();
    write_header(&mut w, f.stamp_s, "gps");
    w.i8(f.status.to_ros());
    w.u16(1);
    w.f64(f.lat_deg);
    w.f64(f.lon_deg);
    w.f64(f.alt_m);
    w.f64s(&f.covariance_m2.unwrap_or([0.0; 9]));
    // COVARIANCE_TYPE_KNOWN = 3, UNKNOWN = 0.
    w.u8(if f.covariance_m2.is_some() { 3 } else { 0 });
    w.finish()
}

/// Decodes `geometry_msgs/msg/Twist`.
pub fn decode_twist(msg: &[u8]) -> Result<Twist, CdrError> {
    let mut r = Reader::new(msg)?;
    let linear = finite(r.f64s::<3>("linear")?, "linear")?;
    let angular = finite(r.f64s::<3>("angular")?, "angular")?;
    Ok(Twist {
        linear_x_mps: linear[0],
        angular_z_rps: angular[2],
    })
}

/// Encodes `geometry_msgs/msg/Twist` (the base command on `cmd_vel`).
pub fn encode_twist(t: &Twist) -> Vec<u8> {
    let mut w = Writer::new();
    w.f64s(&[t.linear_x_mps, 0.0, 0.0, 0.0, 0.0, t.angular_z_rps]);
    w.finish()
}

/// Decodes `tf2_msgs/msg/TFMessage` (a sequence of `geometry_msgs/msg/TransformStamped`).
pub fn decode_tf_message(msg: &[u8]) -> Result<Vec<Transform>, CdrError> {
    let mut r = Reader::new(msg)?;
    // A TransformStamped is at least 8 (stamp) + 4 + 4 (two strings) + 56 (7 doubles) bytes.
    let n = r.seq_len(72, "transforms")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let (stamp_s, frame_id) = read_header(&mut r)?;
        let child_frame_id = r.string("child_frame_id")?;
        let translation_m = finite(r.f64s::<3>("translation")?, "translation")?;
        let rotation = read_quat(&mut r, "rotation")?;
        out.push(Transform {
            stamp_s,
            frame_id,
            child_frame_id,
            translation_m,
            rotation,
        });
    }
    Ok(out)
}

/// Encodes `tf2_msgs/msg/TFMessage`.
pub fn encode_tf_message(transforms: &[Transform]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u32(transforms.len() as u32);
    for t in transforms {
        write_header(&mut w, t.stamp_s, &t.frame_id);
        w.string(&t.child_frame_id);
        w.f64s(&t.translation_m);
        w.f64s(&t.rotation);
    }
    w.finish()
}

/// Decodes a heading from `geometry_msgs/msg/QuaternionStamped` (an ENU orientation, yaw
/// counter-clockwise from east, as ROS GNSS drivers publish it) into degrees from true north.
pub fn decode_heading_quaternion(msg: &[u8]) -> Result<Heading, CdrError> {
    let mut r = Reader::new(msg)?;
    let (stamp_s, _frame) = read_header(&mut r)?;
    let [x, y, z, w] = read_quat(&mut r, "quaternion")?;
    let yaw_enu = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    let heading_deg = (90.0 - yaw_enu.to_degrees()).rem_euclid(360.0);
    Ok(Heading {
        stamp_s,
        heading_deg,
    })
}

/// Encodes a heading as `geometry_msgs/msg/QuaternionStamped` (ENU yaw, frame `gps`).
pub fn encode_heading_quaternion(h: &Heading) -> Vec<u8> {
    let mut w = Writer::new();
    write_header(&mut w, h.stamp_s, "gps");
    let yaw = (90.0 - h.heading_deg).to_radians();
    w.f64s(&[0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()]);
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let o = Odometry {
            stamp_s: 1700000000.25,
            frame_id: "odom".into(),
            child_frame_id: "base_link".into(),
            position_m: [1.0, -2.0, 0.5],
            orientation: [0.0, 0.0, 0.6, 0.8],
            linear_x_mps: 0.7,
            angular_z_rps: -0.1,
        };
        assert_eq!(decode_odometry(&encode_odometry(&o)).unwrap(), o);
        let i = Imu {
            stamp_s: 12.5,
            frame_id: "imu_link".into(),
            orientation: None,
            angular_velocity_rps: [0.1, 0.2, 0.3],
            linear_acceleration_mps2: [0.0, 0.0, 9.81],
        };
        assert_eq!(decode_imu(&encode_imu(&i)).unwrap(), i);
        let i2 = Imu {
            orientation: Some([0.0, 0.0, 0.0, 1.0]),
            ..i
        };
        assert_eq!(decode_imu(&encode_imu(&i2)).unwrap(), i2);
        let f = NavFix {
            stamp_s: 3.0,
            lat_deg: 52.1,
            lon_deg: -1.3,
            alt_m: 80.0,
            status: FixStatus::Gbas,
            covariance_m2: Some([0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.04]),
            gga_quality: None,
        };
        assert_eq!(decode_nav_sat_fix(&encode_nav_sat_fix(&f)).unwrap(), f);
        let t = Twist {
            linear_x_mps: 0.5,
            angular_z_rps: 0.25,
        };
        assert_eq!(decode_twist(&encode_twist(&t)).unwrap(), t);
        let tf = vec![Transform {
            stamp_s: 0.0,
            frame_id: "base_link".into(),
            child_frame_id: "velodyne".into(),
            translation_m: [0.2, 0.0, 0.6],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }];
        assert_eq!(decode_tf_message(&encode_tf_message(&tf)).unwrap(), tf);
        let h = decode_heading_quaternion(&encode_heading_quaternion(&Heading {
            stamp_s: 1.0,
            heading_deg: 30.0,
        }))
        .unwrap();
        assert!((h.heading_deg - 30.0).abs() < 1e-9);
    }

    #[test]
    fn bad_values_are_typed_errors() {
        let o = Odometry {
            orientation: [0.0, 0.0, 0.0, 2.0],
            ..Default::default()
        };
        assert!(matches!(
            decode_odometry(&encode_odometry(&o)),
            Err(CdrError::Invalid { .. })
        ));
        let f = NavFix {
            stamp_s: 0.0,
            lat_deg: 91.0,
            lon_deg: 0.0,
            alt_m: 0.0,
            status: FixStatus::Fix,
            covariance_m2: None,
            gga_quality: None,
        };
        assert!(decode_nav_sat_fix(&encode_nav_sat_fix(&f)).is_err());
        let no_fix = NavFix {
            lat_deg: f64::NAN,
            status: FixStatus::NoFix,
            ..f
        };
        assert!(decode_nav_sat_fix(&encode_nav_sat_fix(&no_fix)).is_ok());
    }
}

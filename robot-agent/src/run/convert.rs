//! ROS 2 samples (as `io` decodes them) into the agent's inputs: clouds into the sensor frame the
//! agent's mount expects, odometry and IMU into `base_link` terms, fixes into GGA terms. Pure
//! functions over the frames the robot published (`tf_static`) and the configured mounts.

use io::sample::{Cloud, FixStatus, Heading, Imu, NavFix, Odometry, Transform};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use sensing::{GnssFixSample, GnssHeadingSample, ImuSample, OdomSample, Point, Scan};
use std::collections::HashMap;

/// The body frame of REP 105.
pub const BASE_LINK: &str = "base_link";

/// Frames ROS drivers use for the body besides `base_link`; taken as `base_link` (the ground
/// projection differs by the wheel radius at most, which the mount in the config absorbs).
const BODY_ALIASES: [&str; 2] = ["base_footprint", ""];

/// Static transforms as the robot published them: child frame -> (parent frame, parent <- child).
#[derive(Clone, Debug, Default)]
pub struct Frames {
    parent: HashMap<String, (String, Isometry3<f64>)>,
}

fn iso(t: &Transform) -> Option<Isometry3<f64>> {
    let [x, y, z, w] = t.rotation;
    let q = Quaternion::new(w, x, y, z);
    let ok = t.translation_m.iter().all(|v| v.is_finite())
        && [x, y, z, w].iter().all(|v| v.is_finite())
        && q.norm() > 1e-6;
    ok.then(|| {
        Isometry3::from_parts(
            Translation3::from(Vector3::from(t.translation_m)),
            UnitQuaternion::from_quaternion(q),
        )
    })
}

fn is_body(frame: &str) -> bool {
    let f = frame.trim_start_matches('/');
    f == BASE_LINK || BODY_ALIASES.contains(&f)
}

impl Frames {
    /// Adds (or replaces) the transforms of one `tf_static` message; returns how many were
    /// refused (non-finite or a zero quaternion).
    pub fn add(&mut self, transforms: &[Transform]) -> usize {
        let mut refused = 0;
        for t in transforms {
            match iso(t) {
                Some(i) => {
                    self.parent.insert(
                        t.child_frame_id.trim_start_matches('/').to_owned(),
                        (t.frame_id.trim_start_matches('/').to_owned(), i),
                    );
                }
                None => refused += 1,
            }
        }
        refused
    }

    /// `base_link <- frame`, when the tree links them (at most 16 hops; loops are not followed).
    pub fn body_from(&self, frame: &str) -> Option<Isometry3<f64>> {
        let mut f = frame.trim_start_matches('/');
        let mut acc = Isometry3::identity();
        for _ in 0..16 {
            if is_body(f) {
                return Some(acc);
            }
            let (p, i) = self.parent.get(f)?;
            acc = i * acc;
            f = p;
        }
        None
    }
}

/// A cloud into the frame of the sensor whose configured mount is `mount` (`base_link <- sensor`),
/// since the agent applies that mount itself: a cloud in `base_link` is moved by the mount's
/// inverse; one in another frame first into `base_link` by `tf_static` when the robot published
/// the link, else it is taken as already in the sensor frame.
pub fn cloud_to_scan(c: &Cloud, frames: &Frames, mount: &Isometry3<f64>) -> Scan {
    let to_sensor = if is_body(&c.frame_id) {
        Some(mount.inverse())
    } else {
        frames.body_from(&c.frame_id).map(|b| mount.inverse() * b)
    };
    // Within a millimetre and a hundredth of a degree of the identity: leave the points alone.
    let to_sensor =
        to_sensor.filter(|t| t.translation.vector.norm() > 1e-3 || t.rotation.angle() > 1.7e-4);
    let points = c
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let [x, y, z] = match &to_sensor {
                Some(t) => {
                    let q = t * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                    [q.x as f32, q.y as f32, q.z as f32]
                }
                None => *p,
            };
            Point {
                x,
                y,
                z,
                intensity: c.intensity.as_ref().map_or(0.0, |v| v[i]),
                ring: c.ring.as_ref().map_or(0, |v| v[i]),
                t_s: c.time_s.as_ref().map_or(0.0, |v| v[i]),
            }
        })
        .collect();
    Scan {
        stamp_s: c.stamp_s,
        points,
    }
}

fn yaw_of(q: &[f64; 4]) -> f64 {
    let [x, y, z, w] = *q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// Odometry into the agent's planar sample (the pose of the body in `odom`). `None` when a value
/// is not finite.
pub fn odometry(o: &Odometry) -> Option<OdomSample> {
    let yaw = yaw_of(&o.orientation);
    let s = OdomSample {
        t_s: o.stamp_s,
        pose_odom: common::geom::Pose2::new(o.position_m[0], o.position_m[1], yaw),
        v_mps: o.linear_x_mps,
        omega_rps: o.angular_z_rps,
    };
    let ok = [s.pose_odom.x_m, s.pose_odom.y_m, yaw, s.v_mps, s.omega_rps]
        .iter()
        .all(|v| v.is_finite());
    ok.then_some(s)
}

/// An IMU reading into `base_link` (rotated by its frame's `tf_static` link when published; the
/// lever arm is ignored, as the agent uses the accelerometer for gravity only).
pub fn imu(m: &Imu, frames: &Frames) -> ImuSample {
    let body = frames.body_from(&m.frame_id).map(|b| b.rotation);
    let rotate = |v: [f64; 3]| {
        let v = Vector3::from(v);
        let v = body.map_or(v, |r| r * v);
        [v.x, v.y, v.z]
    };
    let w = m.angular_velocity_rps;
    ImuSample {
        t_s: m.stamp_s,
        accel_mps2: rotate(m.linear_acceleration_mps2),
        // A driver without a gyroscope leaves the rates NaN (or zero, which is told apart only by
        // its covariance; a zero rate de-skews nothing, so it is harmless).
        gyro_rps: w.iter().all(|x| x.is_finite()).then(|| rotate(w)),
    }
}

/// Horizontal standard deviation above which a `GBAS` fix counts as RTK float, metres: ROS's
/// `NavSatStatus` has one status for every ground-augmented fix, and RTK fixed is centimetres.
pub const RTK_FIXED_MAX_SIGMA_M: f64 = 0.1;

/// A `NavSatFix` (or a gpsd report) into GGA terms. Quality: the receiver's own when the source
/// gave it (gpsd), else no fix 0, fix 1, SBAS 2, GBAS 4 (RTK fixed) when the covariance is
/// unknown or within [`RTK_FIXED_MAX_SIGMA_M`], else 5.
pub fn fix(f: &NavFix) -> GnssFixSample {
    let quality = match (f.status, f.gga_quality) {
        (FixStatus::NoFix, _) => 0,
        (_, Some(q)) if q > 0 => q,
        (FixStatus::Fix, _) => 1,
        (FixStatus::Sbas, _) => 2,
        (FixStatus::Gbas, _) => {
            let sigma = f
                .covariance_m2
                .map(|c| ((c[0] + c[4]) / 2.0).max(0.0).sqrt());
            if sigma.is_some_and(|s| s > RTK_FIXED_MAX_SIGMA_M) {
                5
            } else {
                4
            }
        }
    };
    GnssFixSample {
        t_s: f.stamp_s,
        lat_deg: f.lat_deg,
        lon_deg: f.lon_deg,
        h_m: f.alt_m,
        quality,
        satellites: None,
    }
}

/// A heading into the agent's sample.
pub fn heading(h: &Heading) -> GnssHeadingSample {
    GnssHeadingSample {
        t_s: h.stamp_s,
        heading_deg: h.heading_deg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tf(parent: &str, child: &str, xyz: [f64; 3], yaw: f64) -> Transform {
        Transform {
            stamp_s: 0.0,
            frame_id: parent.into(),
            child_frame_id: child.into(),
            translation_m: xyz,
            rotation: [0.0, 0.0, (yaw / 2.0).sin(), (yaw / 2.0).cos()],
        }
    }

    fn cloud(frame: &str, p: [f32; 3]) -> Cloud {
        Cloud {
            stamp_s: 5.0,
            frame_id: frame.into(),
            points: vec![p],
            ..Cloud::default()
        }
    }

    #[test]
    fn clouds_end_in_the_configured_sensor_frame() {
        let mount = Isometry3::translation(0.0, 0.0, 0.75);
        let none = Frames::default();
        // Already in the sensor frame (no tf): untouched.
        let s = cloud_to_scan(&cloud("velodyne", [1.0, 2.0, 3.0]), &none, &mount);
        assert_eq!(
            (s.points[0].x, s.points[0].y, s.points[0].z),
            (1.0, 2.0, 3.0)
        );
        assert_eq!(s.stamp_s, 5.0);
        // In base_link: the mount's inverse, so the agent's mount puts it back.
        let s = cloud_to_scan(&cloud("base_link", [1.0, 0.0, 1.0]), &none, &mount);
        assert!((s.points[0].z - 0.25).abs() < 1e-6);
        // In a sensor frame the robot mounts elsewhere (tf_static through a chain): into base_link
        // by the tree, then into the configured sensor frame.
        let mut frames = Frames::default();
        frames.add(&[
            tf("base_link", "top_plate", [0.0, 0.0, 0.5], 0.0),
            tf(
                "top_plate",
                "lidar",
                [0.1, 0.0, 0.25],
                std::f64::consts::FRAC_PI_2,
            ),
        ]);
        let s = cloud_to_scan(&cloud("lidar", [1.0, 0.0, 0.0]), &frames, &mount);
        // lidar x is base_link y: (0.1, 1, 0.75) in base_link, (0.1, 1, 0) in the sensor frame.
        let p = s.points[0];
        assert!((p.x - 0.1).abs() < 1e-6 && (p.y - 1.0).abs() < 1e-6 && p.z.abs() < 1e-6);
        // A loop in the tree is not followed for ever.
        let mut bad = Frames::default();
        bad.add(&[tf("a", "b", [0.0; 3], 0.0), tf("b", "a", [0.0; 3], 0.0)]);
        assert!(bad.body_from("a").is_none());
        // A zero quaternion is refused.
        let mut z = tf("base_link", "x", [0.0; 3], 0.0);
        z.rotation = [0.0; 4];
        assert_eq!(Frames::default().add(&[z]), 1);
    }

    #[test]
    fn odometry_imu_and_fixes() {
        let o = Odometry {
            stamp_s: 1.0,
            position_m: [2.0, 3.0, 0.0],
            orientation: [0.0, 0.0, (0.3f64).sin(), (0.3f64).cos()],
            linear_x_mps: 0.5,
            angular_z_rps: 0.1,
            ..Odometry::default()
        };
        let s = odometry(&o).unwrap();
        assert!((s.pose_odom.yaw_rad - 0.6).abs() < 1e-12 && s.pose_odom.x_m == 2.0);
        assert!(odometry(&Odometry {
            linear_x_mps: f64::NAN,
            ..o.clone()
        })
        .is_none());
        // An IMU mounted upside down reads gravity as -z; in base_link it is +z.
        let mut frames = Frames::default();
        let mut flip = tf("base_link", "imu_link", [0.0; 3], 0.0);
        flip.rotation = [1.0, 0.0, 0.0, 0.0];
        frames.add(&[flip]);
        let m = Imu {
            stamp_s: 1.0,
            frame_id: "imu_link".into(),
            linear_acceleration_mps2: [0.0, 0.0, -9.81],
            ..Imu::default()
        };
        assert!((imu(&m, &frames).accel_mps2[2] - 9.81).abs() < 1e-9);
        let f = |status, cov: Option<f64>| {
            fix(&NavFix {
                stamp_s: 1.0,
                lat_deg: 48.0,
                lon_deg: 11.0,
                alt_m: 500.0,
                status,
                covariance_m2: cov.map(|c| [c, 0.0, 0.0, 0.0, c, 0.0, 0.0, 0.0, c]),
                gga_quality: None,
            })
            .quality
        };
        assert_eq!(f(FixStatus::Gbas, Some(0.0004)), 4);
        assert_eq!(f(FixStatus::Gbas, None), 4);
        assert_eq!(f(FixStatus::Gbas, Some(0.09)), 5);
        assert_eq!(f(FixStatus::Fix, Some(4.0)), 1);
        assert_eq!(f(FixStatus::NoFix, None), 0);
        // gpsd says RTK float outright, without a covariance.
        let float = NavFix {
            stamp_s: 1.0,
            lat_deg: 48.0,
            lon_deg: 11.0,
            alt_m: 500.0,
            status: FixStatus::Gbas,
            covariance_m2: None,
            gga_quality: Some(5),
        };
        assert_eq!(fix(&float).quality, 5);
    }
}

//! The runtime's inputs as recording messages and back, exactly: a replay must hand the agent
//! the very numbers the robot got. Foxglove's schemas carry them where one fits (clouds as
//! `foxglove.PointCloud` with every point's fields as f32, odometry as `foxglove.Odometry`, fixes as
//! `foxglove.LocationFix`); each message also carries `stamp_s`, the runtime's stamp in f64
//! seconds, which Foxglove's nanosecond timestamp rounds (a simulator's session clock is finer),
//! and odometry its `yaw_rad`, which a quaternion would round. Both are extra properties the
//! schemas allow and viewers ignore.

use super::channels::{self, InputKind};
use crate::runtime::Input;
use record::foxglove::{self, num, numeric};
use sensing::{GnssFixSample, GnssHeadingSample, GnssSentence, ImuSample, OdomSample, Point, Scan};
use serde_json::{json, Value};

/// Bytes per point of a recorded cloud: x, y, z, intensity, t (f32), ring (u16), 2 spare.
const POINT_STRIDE: usize = 24;

/// Why a recorded input could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// Not JSON.
    #[error("not JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A field is missing or of the wrong type.
    #[error("field {0} missing or not {1}")]
    Field(&'static str, &'static str),
    /// The cloud's bytes do not match its layout.
    #[error("point cloud: {0}")]
    Cloud(String),
}

/// The stamp of an input in Unix nanoseconds for Foxglove's `timestamp` (session stamps are
/// placed on the session's wall clock).
fn stamp_ns(stamp_s: f64, to_unix_ns: &dyn Fn(f64) -> u64) -> u64 {
    to_unix_ns(stamp_s)
}

/// The message of `input`; `to_unix_ns` turns a header stamp into Unix nanoseconds.
pub fn to_json(input: &Input, to_unix_ns: &dyn Fn(f64) -> u64) -> Value {
    match input {
        Input::Scan(s) => cloud(s, channels::LIDAR_FRAME, to_unix_ns),
        Input::Depth(s) => cloud(s, channels::DEPTH_FRAME, to_unix_ns),
        Input::Odom(o) => {
            let (sin, cos) = (o.pose_odom.yaw_rad / 2.0).sin_cos();
            let mut v = json!({
                "timestamp": foxglove::time(stamp_ns(o.t_s, to_unix_ns)),
                "frame_id": "odom",
                "body_frame_id": "base_link",
                "pose": foxglove::pose([o.pose_odom.x_m, o.pose_odom.y_m, 0.0], [0.0, 0.0, sin, cos]),
                "linear_velocity": {"x": num(o.v_mps), "y": 0.0, "z": 0.0},
                "angular_velocity": {"x": 0.0, "y": 0.0, "z": num(o.omega_rps)},
            });
            v["stamp_s"] = num(o.t_s);
            v["yaw_rad"] = num(o.pose_odom.yaw_rad);
            v
        }
        Input::Imu(i) => {
            let mut v = json!({
                "timestamp": foxglove::time(stamp_ns(i.t_s, to_unix_ns)),
                "frame_id": "base_link",
                "linear_acceleration": {"x": num(i.accel_mps2[0]), "y": num(i.accel_mps2[1]), "z": num(i.accel_mps2[2])},
                "stamp_s": num(i.t_s),
            });
            if let Some(g) = i.gyro_rps {
                v["angular_velocity"] = json!({"x": num(g[0]), "y": num(g[1]), "z": num(g[2])});
            }
            v
        }
        Input::Gnss(g) => json!({
            "timestamp": foxglove::time(stamp_ns(g.t_s, to_unix_ns)),
            "frame_id": "gnss",
            "sentence": g.text,
            "stamp_s": num(g.t_s),
        }),
        Input::Fix(f) => {
            let mut v = foxglove::location_fix(
                stamp_ns(f.t_s, to_unix_ns),
                "gnss",
                f.lat_deg,
                f.lon_deg,
                f.h_m,
            );
            v["stamp_s"] = num(f.t_s);
            v["quality"] = json!(f.quality);
            v["satellites"] = json!(f.satellites);
            v
        }
        Input::Heading(h) => json!({
            "timestamp": foxglove::time(stamp_ns(h.t_s, to_unix_ns)),
            "heading_deg": num(h.heading_deg),
            "stamp_s": num(h.t_s),
        }),
    }
}

fn cloud(s: &Scan, frame: &str, to_unix_ns: &dyn Fn(f64) -> u64) -> Value {
    let mut data = vec![0u8; s.points.len() * POINT_STRIDE];
    for (p, out) in s.points.iter().zip(data.chunks_exact_mut(POINT_STRIDE)) {
        out[0..4].copy_from_slice(&p.x.to_le_bytes());
        out[4..8].copy_from_slice(&p.y.to_le_bytes());
        out[8..12].copy_from_slice(&p.z.to_le_bytes());
        out[12..16].copy_from_slice(&p.intensity.to_le_bytes());
        out[16..20].copy_from_slice(&p.t_s.to_le_bytes());
        out[20..22].copy_from_slice(&p.ring.to_le_bytes());
    }
    let mut v = foxglove::point_cloud(
        stamp_ns(s.stamp_s, to_unix_ns),
        frame,
        POINT_STRIDE as u32,
        vec![
            foxglove::field("x", 0, numeric::FLOAT32),
            foxglove::field("y", 4, numeric::FLOAT32),
            foxglove::field("z", 8, numeric::FLOAT32),
            foxglove::field("intensity", 12, numeric::FLOAT32),
            foxglove::field("t", 16, numeric::FLOAT32),
            foxglove::field("ring", 20, numeric::UINT16),
        ],
        &data,
    );
    v["stamp_s"] = num(s.stamp_s);
    v
}

/// A number; JSON null (a value that was not finite) reads as NaN.
fn f(v: &Value, name: &'static str) -> Result<f64, InputError> {
    match v {
        Value::Null => Ok(f64::NAN),
        v => v.as_f64().ok_or(InputError::Field(name, "a number")),
    }
}

fn get<'a>(v: &'a Value, path: &[&'static str]) -> Result<&'a Value, InputError> {
    let mut cur = v;
    for k in path {
        cur = cur
            .get(k)
            .ok_or(InputError::Field(path[path.len() - 1], "present"))?;
    }
    Ok(cur)
}

fn num_at(v: &Value, path: &[&'static str]) -> Result<f64, InputError> {
    f(get(v, path)?, path[path.len() - 1])
}

/// Reads back an input of `kind` from its message bytes.
pub fn from_json(kind: InputKind, bytes: &[u8]) -> Result<Input, InputError> {
    let v: Value = serde_json::from_slice(bytes)?;
    let stamp = num_at(&v, &["stamp_s"])?;
    Ok(match kind {
        InputKind::Lidar => Input::Scan(scan_of(&v, stamp)?),
        InputKind::Depth => Input::Depth(scan_of(&v, stamp)?),
        InputKind::Odom => Input::Odom(OdomSample {
            t_s: stamp,
            pose_odom: common::geom::Pose2::new(
                num_at(&v, &["pose", "position", "x"])?,
                num_at(&v, &["pose", "position", "y"])?,
                num_at(&v, &["yaw_rad"])?,
            ),
            v_mps: num_at(&v, &["linear_velocity", "x"])?,
            omega_rps: num_at(&v, &["angular_velocity", "z"])?,
        }),
        InputKind::Imu => Input::Imu(ImuSample {
            t_s: stamp,
            accel_mps2: [
                num_at(&v, &["linear_acceleration", "x"])?,
                num_at(&v, &["linear_acceleration", "y"])?,
                num_at(&v, &["linear_acceleration", "z"])?,
            ],
            gyro_rps: match v.get("angular_velocity") {
                None => None,
                Some(_) => Some([
                    num_at(&v, &["angular_velocity", "x"])?,
                    num_at(&v, &["angular_velocity", "y"])?,
                    num_at(&v, &["angular_velocity", "z"])?,
                ]),
            },
        }),
        InputKind::Nmea => Input::Gnss(GnssSentence {
            t_s: stamp,
            text: get(&v, &["sentence"])?
                .as_str()
                .ok_or(InputError::Field("sentence", "a string"))?
                .to_string(),
        }),
        InputKind::Fix => Input::Fix(GnssFixSample {
            t_s: stamp,
            lat_deg: num_at(&v, &["latitude"])?,
            lon_deg: num_at(&v, &["longitude"])?,
            h_m: num_at(&v, &["altitude"])?,
            quality: get(&v, &["quality"])?
                .as_u64()
                .and_then(|q| u8::try_from(q).ok())
                .ok_or(InputError::Field("quality", "a byte"))?,
            satellites: match get(&v, &["satellites"])? {
                Value::Null => None,
                s => Some(
                    s.as_u64()
                        .and_then(|q| u8::try_from(q).ok())
                        .ok_or(InputError::Field("satellites", "a byte"))?,
                ),
            },
        }),
        InputKind::Heading => Input::Heading(GnssHeadingSample {
            t_s: stamp,
            heading_deg: num_at(&v, &["heading_deg"])?,
        }),
    })
}

fn scan_of(v: &Value, stamp_s: f64) -> Result<Scan, InputError> {
    let stride = get(v, &["point_stride"])?
        .as_u64()
        .ok_or(InputError::Field("point_stride", "an integer"))? as usize;
    let data = foxglove::unb64(
        get(v, &["data"])?
            .as_str()
            .ok_or(InputError::Field("data", "a string"))?,
    )
    .map_err(|e| InputError::Cloud(format!("data: {e}")))?;
    // Fields by name, so that a cloud laid out otherwise (another writer's) reads too.
    let mut at = std::collections::HashMap::new();
    for fl in get(v, &["fields"])?
        .as_array()
        .ok_or(InputError::Field("fields", "an array"))?
    {
        let name = fl["name"].as_str().unwrap_or_default();
        let offset = fl["offset"].as_u64().unwrap_or(u64::MAX) as usize;
        let ty = fl["type"].as_u64().unwrap_or(0) as u8;
        at.insert(name.to_string(), (offset, ty));
    }
    let f32_at = |name: &str| -> Result<Option<usize>, InputError> {
        match at.get(name) {
            None => Ok(None),
            Some(&(o, numeric::FLOAT32)) if o + 4 <= stride => Ok(Some(o)),
            Some(_) => Err(InputError::Cloud(format!(
                "field {name} is not a float32 within the point"
            ))),
        }
    };
    let (Some(x), Some(y), Some(z)) = (f32_at("x")?, f32_at("y")?, f32_at("z")?) else {
        return Err(InputError::Cloud("no x, y, z".into()));
    };
    let intensity = f32_at("intensity")?;
    let t = f32_at("t")?;
    let ring = match at.get("ring") {
        Some(&(o, numeric::UINT16)) if o + 2 <= stride => Some(o),
        None => None,
        Some(_) => {
            return Err(InputError::Cloud(
                "field ring is not a uint16 within the point".into(),
            ))
        }
    };
    if stride == 0 || data.len() % stride != 0 {
        return Err(InputError::Cloud(format!(
            "{} bytes are not whole points of {stride}",
            data.len()
        )));
    }
    let rd = |p: &[u8], o: usize| f32::from_le_bytes([p[o], p[o + 1], p[o + 2], p[o + 3]]);
    let points = data
        .chunks_exact(stride)
        .map(|p| Point {
            x: rd(p, x),
            y: rd(p, y),
            z: rd(p, z),
            intensity: intensity.map_or(0.0, |o| rd(p, o)),
            ring: ring.map_or(0, |o| u16::from_le_bytes([p[o], p[o + 1]])),
            t_s: t.map_or(0.0, |o| rd(p, o)),
        })
        .collect();
    Ok(Scan { stamp_s, points })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip(i: Input, kind: InputKind) -> Input {
        let v = to_json(&i, &|t| (t * 1e9) as u64);
        from_json(kind, &serde_json::to_vec(&v).unwrap()).unwrap()
    }

    #[test]
    fn every_input_reads_back_bit_for_bit() {
        let t = 0.1 + 0.2; // not a whole number of nanoseconds
        let scan = Scan {
            stamp_s: t,
            points: vec![
                Point {
                    x: 1.1,
                    y: -2.2,
                    z: 0.3,
                    intensity: 7.5,
                    ring: 15,
                    t_s: 0.0999,
                },
                Point {
                    x: f32::NAN,
                    y: 0.0,
                    z: 1e-30,
                    intensity: 0.0,
                    ring: 0,
                    t_s: 0.0,
                },
            ],
        };
        match round_trip(Input::Scan(scan.clone()), InputKind::Lidar) {
            Input::Scan(s) => {
                assert_eq!(s.stamp_s.to_bits(), t.to_bits());
                assert_eq!(s.points[0], scan.points[0]);
                assert!(s.points[1].x.is_nan() && s.points[1].z == 1e-30);
            }
            o => panic!("{o:?}"),
        }
        let odom = OdomSample {
            t_s: t,
            pose_odom: common::geom::Pose2::new(1.0 / 3.0, -2.0, 3.1),
            v_mps: 0.123456789,
            omega_rps: -1e-17,
        };
        assert_eq!(
            format!("{:?}", round_trip(Input::Odom(odom), InputKind::Odom)),
            format!("{:?}", Input::Odom(odom))
        );
        let imu = ImuSample {
            t_s: t,
            accel_mps2: [0.1, f64::NAN, 9.81],
            gyro_rps: None,
        };
        match round_trip(Input::Imu(imu), InputKind::Imu) {
            Input::Imu(i) => {
                assert!(i.accel_mps2[0] == 0.1 && i.accel_mps2[1].is_nan() && i.t_s == t);
                assert_eq!(i.gyro_rps, None);
            }
            o => panic!("{o:?}"),
        }
        let gyro = ImuSample {
            gyro_rps: Some([1e-3, -0.25, 1.0 / 7.0]),
            accel_mps2: [0.0, 0.0, 9.81],
            ..imu
        };
        match round_trip(Input::Imu(gyro), InputKind::Imu) {
            Input::Imu(i) => assert_eq!(i.gyro_rps, gyro.gyro_rps),
            o => panic!("{o:?}"),
        }
        for (i, k) in [
            (
                Input::Gnss(GnssSentence {
                    t_s: t,
                    text: "$GPGGA,1*00".into(),
                }),
                InputKind::Nmea,
            ),
            (
                Input::Fix(GnssFixSample {
                    t_s: t,
                    lat_deg: 48.1,
                    lon_deg: 11.5,
                    h_m: 500.25,
                    quality: 4,
                    satellites: None,
                }),
                InputKind::Fix,
            ),
            (
                Input::Heading(GnssHeadingSample {
                    t_s: t,
                    heading_deg: 359.99,
                }),
                InputKind::Heading,
            ),
        ] {
            assert_eq!(format!("{:?}", round_trip(i.clone(), k)), format!("{i:?}"));
        }
    }

    #[test]
    fn bad_messages_are_errors_not_panics() {
        assert!(from_json(InputKind::Odom, b"{").is_err());
        assert!(from_json(InputKind::Odom, b"{\"stamp_s\": 1}").is_err());
        let bad = json!({"stamp_s": 1.0, "point_stride": 24, "fields": [], "data": "AAAA"});
        assert!(from_json(InputKind::Lidar, &serde_json::to_vec(&bad).unwrap()).is_err());
        let short = json!({"stamp_s": 1.0, "point_stride": 24, "data": "AAAA", "fields": [
            {"name": "x", "offset": 0, "type": 7}, {"name": "y", "offset": 4, "type": 7}, {"name": "z", "offset": 8, "type": 7}]});
        assert!(from_json(InputKind::Lidar, &serde_json::to_vec(&short).unwrap()).is_err());
    }
}

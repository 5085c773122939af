//! `robot-agent sim --serve-ros2`: the simulated world as a robot's hardware. It runs only the
//! world (no agent), in real time, publishes the sensors as the ROS 2 topics a Husky's drivers
//! publish (clouds, odometry, IMU, NavSatFix and heading, `tf_static`), stamped with Unix time
//! from the world's start, and drives the plant with the `cmd_vel` it receives (zero after
//! [`CMD_TIMEOUT_S`] without one, as a real base's watchdog does). A robot agent then runs
//! against it exactly as against a real robot (`robot-agent run`).
//!
//! Its first stdout line is a JSON object with the world's datum (`"datum": "LAT,LON,H"`, for
//! `robot-agent run --datum`); then every `--truth-period-s` (1 s) it prints a JSON line with the simulator's truth (pose, speed, collisions,
//! commands received) on stdout: what tests judge the agent against, never sent to the agent.

use super::SIM_DT_S;
use crate::bus::ZenohSettings;
use common::geo::{parse_sentence, Sentence};
use io::cdr;
use io::ros2::keys;
use io::ros2::{Ros2Bus, Ros2Graph, Ros2Publisher};
use io::sample::{Cloud, FixStatus, Heading, Imu, NavFix, Odometry, Transform, Twist};
use nalgebra::Isometry3;
use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// A base stops when no `cmd_vel` came for this long, seconds.
pub const CMD_TIMEOUT_S: f64 = 0.5;

/// Frame of the LiDAR cloud.
pub const LIDAR_FRAME: &str = "velodyne";
/// Frame of the depth-camera cloud (x forward, y left, z up).
pub const DEPTH_FRAME: &str = "depth_camera";

/// Topic names the world publishes on (relative: under the namespace).
#[derive(Clone, Debug)]
pub struct WorldTopics {
    /// LiDAR PointCloud2.
    pub lidar: String,
    /// Depth-camera PointCloud2 (published when the camera is on).
    pub depth: String,
    /// Odometry.
    pub odom: String,
    /// IMU.
    pub imu: String,
    /// NavSatFix.
    pub fix: String,
    /// Heading (QuaternionStamped).
    pub heading: String,
    /// Twist in.
    pub cmd_vel: String,
}

impl Default for WorldTopics {
    fn default() -> Self {
        Self {
            lidar: "velodyne_points".into(),
            depth: "depth/points".into(),
            odom: "odom".into(),
            imu: "imu/data".into(),
            fix: "fix".into(),
            heading: "heading".into(),
            cmd_vel: "cmd_vel".into(),
        }
    }
}

/// A sensor held silent over a stretch of simulated time (fault injection for tests and demos).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Silence {
    /// Which stream: `lidar`, `depth`, `odom`, `imu`, `gnss`.
    pub what: SilencedStream,
    /// From, seconds of simulated time.
    pub from_s: f64,
    /// For, seconds.
    pub for_s: f64,
}

/// Streams a [`Silence`] can mute.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SilencedStream {
    /// LiDAR.
    Lidar,
    /// Depth camera.
    Depth,
    /// Odometry.
    Odom,
    /// IMU.
    Imu,
    /// GNSS (fix and heading).
    Gnss,
}

impl std::str::FromStr for Silence {
    type Err = String;
    /// `STREAM@FROM_S+FOR_S`, e.g. `lidar@20+2`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: expected STREAM@FROM_S+FOR_S, e.g. lidar@20+2");
        let (what, span) = s.split_once('@').ok_or_else(bad)?;
        let (from, dur) = span.split_once('+').ok_or_else(bad)?;
        let what = match what {
            "lidar" => SilencedStream::Lidar,
            "depth" => SilencedStream::Depth,
            "odom" => SilencedStream::Odom,
            "imu" => SilencedStream::Imu,
            "gnss" => SilencedStream::Gnss,
            o => return Err(format!("{o:?}: not one of lidar, depth, odom, imu, gnss")),
        };
        let from_s: f64 = from.parse().map_err(|_| bad())?;
        let for_s: f64 = dur.parse().map_err(|_| bad())?;
        if !(from_s.is_finite() && for_s.is_finite() && from_s >= 0.0 && for_s > 0.0) {
            return Err(bad());
        }
        Ok(Silence {
            what,
            from_s,
            for_s,
        })
    }
}

/// Everything the world process needs.
pub struct WorldOptions {
    /// The simulator's configuration (scenario start, seed, robot profile, depth camera).
    pub sim: sim::SimConfig,
    /// Where the ROS 2 graph is, and its key form.
    pub graph: Ros2Graph,
    /// The world's Zenoh session (it listens, as a bridge does).
    pub zenoh: ZenohSettings,
    /// Topic names.
    pub topics: WorldTopics,
    /// Sensors muted over stretches of time.
    pub silences: Vec<Silence>,
    /// Period of the truth lines on stdout, seconds.
    pub truth_period_s: f64,
}

struct Publishers {
    lidar: Ros2Publisher,
    depth: Option<Ros2Publisher>,
    odom: Ros2Publisher,
    imu: Ros2Publisher,
    fix: Ros2Publisher,
    heading: Ros2Publisher,
    tf_static: Ros2Publisher,
}

fn iso_to_tf(parent: &str, child: &str, iso: &Isometry3<f64>, stamp_s: f64) -> Transform {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    Transform {
        stamp_s,
        frame_id: parent.into(),
        child_frame_id: child.into(),
        translation_m: [t.x, t.y, t.z],
        rotation: [q.i, q.j, q.k, q.w],
    }
}

fn cloud(frame: &str, stamp_s: f64, s: &sensing::Scan) -> Cloud {
    Cloud {
        stamp_s,
        frame_id: frame.into(),
        points: s.points.iter().map(|p| [p.x, p.y, p.z]).collect(),
        intensity: Some(s.points.iter().map(|p| p.intensity).collect()),
        ring: Some(s.points.iter().map(|p| p.ring).collect()),
        time_s: Some(s.points.iter().map(|p| p.t_s).collect()),
        dropped_non_finite: 0,
    }
}

/// Standard deviation a receiver reports for a GGA quality, metres (NavSatFix covariance).
fn sigma_for_quality(q: u8) -> f64 {
    match q {
        4 => 0.02,
        5 => 0.3,
        2 | 9 => 0.7,
        _ => 2.5,
    }
}

/// One NMEA sentence of the simulated receiver as the ROS messages a GNSS driver publishes.
fn gnss_messages(text: &str, stamp_s: f64) -> (Option<NavFix>, Option<Heading>) {
    match parse_sentence(text) {
        Ok(Sentence::Gga(g)) => {
            let status = match (g.lat_deg, g.lon_deg) {
                (Some(_), Some(_)) => FixStatus::from_gga_quality(g.quality),
                _ => FixStatus::NoFix,
            };
            let var = sigma_for_quality(g.quality).powi(2);
            (
                Some(NavFix {
                    stamp_s,
                    lat_deg: g.lat_deg.unwrap_or(f64::NAN),
                    lon_deg: g.lon_deg.unwrap_or(f64::NAN),
                    alt_m: g.alt_hae_m().unwrap_or(f64::NAN),
                    status,
                    covariance_m2: Some([var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, 4.0 * var]),
                    gga_quality: None,
                }),
                None,
            )
        }
        Ok(Sentence::Avr(a)) if a.quality > 0 => (
            None,
            a.yaw_deg.map(|h| Heading {
                stamp_s,
                heading_deg: h.rem_euclid(360.0),
            }),
        ),
        Ok(Sentence::Hdt(h)) => (
            None,
            h.heading_deg.map(|h| Heading {
                stamp_s,
                heading_deg: h,
            }),
        ),
        _ => (None, None),
    }
}

/// Runs the world until `stop` is set.
pub fn serve_world(
    scenario: &sim::Scenario,
    opts: WorldOptions,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("world-io")
        .enable_all()
        .build()?;
    let depth_on = opts.sim.depth.enabled;
    let mut simu = sim::Simulation::new(scenario, opts.sim);
    let t = &opts.topics;
    let config = opts.zenoh.to_config()?;
    let (bus, pubs) = rt.block_on(async {
        let session = zenoh::open(config)
            .await
            .map_err(|e| anyhow::anyhow!("zenoh: {e}"))?;
        let bus = Ros2Bus::new(session, opts.graph.clone(), "terranav_world").await?;
        let pubs = Publishers {
            lidar: bus.publisher(&t.lidar, &keys::POINT_CLOUD2).await?,
            depth: if depth_on {
                Some(bus.publisher(&t.depth, &keys::POINT_CLOUD2).await?)
            } else {
                None
            },
            odom: bus.publisher(&t.odom, &keys::ODOMETRY).await?,
            imu: bus.publisher(&t.imu, &keys::IMU).await?,
            fix: bus.publisher(&t.fix, &keys::NAV_SAT_FIX).await?,
            heading: bus.publisher(&t.heading, &keys::QUATERNION_STAMPED).await?,
            tf_static: bus.publisher("/tf_static", &keys::TF_MESSAGE).await?,
        };
        anyhow::Ok((bus, pubs))
    })?;
    // The newest command and when it came; counts of good and refused ones.
    let cmd: Arc<Mutex<(Twist, Option<Instant>)>> = Arc::default();
    let (cmds_ok, cmds_bad) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    {
        let sub = rt.block_on(bus.subscribe(&t.cmd_vel, &keys::TWIST, cdr::decode_twist))?;
        let (cmd, ok, bad) = (cmd.clone(), cmds_ok.clone(), cmds_bad.clone());
        rt.spawn(async move {
            while let Some(r) = sub.recv().await {
                match r {
                    Ok(tw) if tw.linear_x_mps.is_finite() && tw.angular_z_rps.is_finite() => {
                        ok.fetch_add(1, Ordering::Relaxed);
                        if let Ok(mut c) = cmd.lock() {
                            *c = (tw, Some(Instant::now()));
                        }
                    }
                    _ => {
                        bad.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        });
    }
    let epoch_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0);
    let silenced = |what: SilencedStream, t_s: f64| {
        opts.silences
            .iter()
            .any(|s| s.what == what && t_s >= s.from_s && t_s < s.from_s + s.for_s)
    };
    let tf = vec![
        iso_to_tf("base_link", LIDAR_FRAME, &simu.lidar_extrinsic(), epoch_s),
        iso_to_tf("base_link", DEPTH_FRAME, &simu.depth_extrinsic(), epoch_s),
    ];
    tracing::info!(
        "world {} serving ROS 2 ({:?} keys{}): {} {} {} {} {} {}, cmd_vel <- {}",
        scenario.name,
        opts.graph.form,
        if opts.graph.namespace.is_empty() {
            String::new()
        } else {
            format!(", namespace {}", opts.graph.namespace)
        },
        t.lidar,
        if depth_on { t.depth.as_str() } else { "" },
        t.odom,
        t.imu,
        t.fix,
        t.heading,
        t.cmd_vel
    );
    let put = |p: &Ros2Publisher, bytes: Vec<u8>| {
        if let Err(e) = rt.block_on(p.put_cdr(bytes, (epoch_s * 1e9) as i64)) {
            tracing::warn!("publishing on {}: {e}", p.key());
        }
    };
    {
        // The first line: the world's datum, to give `robot-agent run --datum` so the robot's map
        // frame is the world's (as robots sharing a site datum do).
        let d = scenario.datum();
        let line = serde_json::json!({
            "world": scenario.name,
            "datum": format!("{},{},{}", d.lat_deg, d.lon_deg, d.h_m),
            "epoch_unix_s": epoch_s,
        });
        let mut o = std::io::stdout().lock();
        let _ = writeln!(o, "{line}");
        let _ = o.flush();
    }
    let wall0 = Instant::now();
    let mut next_tf_s = 0.0;
    let mut next_report_s = 0.0;
    let mut collisions = 0usize;
    let stdout = std::io::stdout();
    while !stop.load(Ordering::Relaxed) {
        let target = wall0.elapsed().as_secs_f64();
        if simu.time_s() >= target {
            std::thread::sleep(Duration::from_millis(1));
            continue;
        }
        let (v, w) = match cmd.lock().map(|c| *c) {
            Ok((tw, Some(at))) if at.elapsed().as_secs_f64() <= CMD_TIMEOUT_S => {
                (tw.linear_x_mps, tw.angular_z_rps)
            }
            _ => (0.0, 0.0),
        };
        let out = simu.step(SIM_DT_S, v, w);
        let t_s = simu.time_s();
        collisions += out.collisions.len();
        if t_s >= next_tf_s {
            next_tf_s += 1.0;
            put(&pubs.tf_static, cdr::encode_tf_message(&tf));
        }
        if let Some(o) = out.odom.filter(|_| !silenced(SilencedStream::Odom, t_s)) {
            let half = o.pose_odom.yaw_rad / 2.0;
            let msg = Odometry {
                stamp_s: epoch_s + o.t_s,
                frame_id: "odom".into(),
                child_frame_id: "base_link".into(),
                position_m: [o.pose_odom.x_m, o.pose_odom.y_m, 0.0],
                orientation: [0.0, 0.0, half.sin(), half.cos()],
                linear_x_mps: o.v_mps,
                angular_z_rps: o.omega_rps,
            };
            put(&pubs.odom, cdr::encode_odometry(&msg));
        }
        if !silenced(SilencedStream::Imu, t_s) {
            for s in &out.imu {
                let msg = Imu {
                    stamp_s: epoch_s + s.t_s,
                    frame_id: "base_link".into(),
                    orientation: None,
                    angular_velocity_rps: s.gyro_rps.unwrap_or([f64::NAN; 3]),
                    linear_acceleration_mps2: s.accel_mps2,
                };
                put(&pubs.imu, cdr::encode_imu(&msg));
            }
        }
        if !silenced(SilencedStream::Gnss, t_s) {
            for g in &out.gnss {
                match gnss_messages(&g.text, epoch_s + g.t_s) {
                    (Some(f), _) => put(&pubs.fix, cdr::encode_nav_sat_fix(&f)),
                    (_, Some(h)) => put(&pubs.heading, cdr::encode_heading_quaternion(&h)),
                    _ => {}
                }
            }
        }
        if let Some(s) = out
            .scan
            .as_ref()
            .filter(|_| !silenced(SilencedStream::Lidar, t_s))
        {
            let c = cloud(LIDAR_FRAME, epoch_s + s.stamp_s, s);
            put(&pubs.lidar, cdr::encode_point_cloud2(&c));
        }
        if let (Some(p), Some(s)) = (&pubs.depth, out.depth.as_ref()) {
            if !silenced(SilencedStream::Depth, t_s) {
                let c = cloud(DEPTH_FRAME, epoch_s + s.stamp_s, s);
                put(p, cdr::encode_point_cloud2(&c));
            }
        }
        if t_s >= next_report_s {
            next_report_s += opts.truth_period_s;
            let p = simu.truth_pose2();
            let (v, w) = simu.truth_velocity();
            let line = serde_json::json!({
                "t_s": t_s,
                "unix_s": epoch_s + t_s,
                "x_m": p.x_m,
                "y_m": p.y_m,
                "yaw_rad": p.yaw_rad,
                "v_mps": v,
                "omega_rps": w,
                "collisions": collisions,
                "cmd_vel_received": cmds_ok.load(Ordering::Relaxed),
                "cmd_vel_refused": cmds_bad.load(Ordering::Relaxed),
            });
            let mut o = stdout.lock();
            let _ = writeln!(o, "{line}");
            let _ = o.flush();
        }
    }
    tracing::info!("world stopping");
    drop(pubs);
    drop(bus);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn silences_parse_with_clear_errors() {
        let s: Silence = "lidar@20+2".parse().unwrap();
        assert_eq!(
            (s.what, s.from_s, s.for_s),
            (SilencedStream::Lidar, 20.0, 2.0)
        );
        for bad in ["lidar", "lidar@20", "radar@1+1", "gnss@-1+5", "imu@1+0"] {
            assert!(bad.parse::<Silence>().is_err(), "{bad}");
        }
    }

    #[test]
    fn receiver_sentences_become_navsatfix_and_heading() {
        use common::geo::{format_gga, Gga, UtcTime};
        let gga = format_gga(&Gga {
            talker: "GP".into(),
            time: Some(UtcTime::from_seconds_of_day(3600.0)),
            lat_deg: Some(48.1),
            lon_deg: Some(11.5),
            quality: 4,
            satellites: Some(12),
            hdop: Some(0.8),
            alt_msl_m: Some(500.0),
            geoid_sep_m: Some(47.0),
            dgps_age_s: None,
            dgps_station: None,
        });
        let (f, h) = gnss_messages(&gga, 10.0);
        let f = f.unwrap();
        assert!(h.is_none());
        assert_eq!(f.status, FixStatus::Gbas);
        assert!((f.alt_m - 547.0).abs() < 1e-9 && f.stamp_s == 10.0);
        // Through the runtime's conversion it is RTK fixed again.
        assert_eq!(super::super::convert::fix(&f).quality, 4);
        let (f, h) = gnss_messages("$GPHDT,123.4,T*00", 10.0);
        assert!(f.is_none() && h.is_none(), "bad checksum is dropped");
    }
}

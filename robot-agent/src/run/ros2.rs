//! The robot's ROS 2 side for `robot-agent run`: one Zenoh session in the bridge or rmw key
//! form, a driver per subscribed topic (decoded, converted, handed to the loop), `tf_static`
//! kept for the frames, and the base as `cmd_vel` Twists.

use super::convert::{self, Frames};
use super::robot::{Base, SourceEvent, SourceStart};
use crate::bus::ZenohSettings;
use crate::runtime::stamps::Topic;
use crate::runtime::Input;
use agent::Cmd;
use io::cdr::{self, CdrError};
use io::ros2::keys::{self, RosType};
use io::ros2::{Ros2Bus, Ros2Graph, Subscription, TwistPublisher};
use io::sample::Twist;
use nalgebra::Isometry3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::sync::{Arc, RwLock};
use std::time::Duration;

/// What a ROS 2 topic feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ros2Input {
    /// `sensor_msgs/msg/PointCloud2` from the LiDAR.
    Lidar,
    /// `velodyne_msgs/msg/VelodyneScan` from a VLP-16 driver: its raw packets, decoded and cut
    /// into sweeps here (`sensing::velodyne`), as the driver's own cloud node would.
    VelodynePackets,
    /// `sensor_msgs/msg/PointCloud2` from the depth camera.
    Depth,
    /// `nav_msgs/msg/Odometry`.
    Odom,
    /// `sensor_msgs/msg/Imu`.
    Imu,
    /// `sensor_msgs/msg/NavSatFix`.
    Fix,
    /// `geometry_msgs/msg/QuaternionStamped`, an ENU heading.
    Heading,
}

impl Ros2Input {
    fn topic(self) -> Topic {
        match self {
            Ros2Input::Lidar | Ros2Input::VelodynePackets => Topic::Lidar,
            Ros2Input::Depth => Topic::Depth,
            Ros2Input::Odom => Topic::Odom,
            Ros2Input::Imu => Topic::Imu,
            Ros2Input::Fix => Topic::Gnss,
            Ros2Input::Heading => Topic::Heading,
        }
    }

    fn ros_type(self) -> RosType {
        match self {
            Ros2Input::Lidar | Ros2Input::Depth => keys::POINT_CLOUD2,
            Ros2Input::VelodynePackets => keys::VELODYNE_SCAN,
            Ros2Input::Odom => keys::ODOMETRY,
            Ros2Input::Imu => keys::IMU,
            Ros2Input::Fix => keys::NAV_SAT_FIX,
            Ros2Input::Heading => keys::QUATERNION_STAMPED,
        }
    }
}

/// The session to the robot's ROS 2 graph, with its own I/O threads.
pub struct Ros2Link {
    rt: tokio::runtime::Runtime,
    bus: Arc<Ros2Bus>,
    frames: Arc<RwLock<Frames>>,
}

fn unix_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}

impl Ros2Link {
    /// Opens the session (`zenoh`: where the bridge or the rmw_zenoh router is) and joins the
    /// graph as node `node`; starts following `tf_static`.
    pub fn open(zenoh: &ZenohSettings, graph: Ros2Graph, node: &str) -> anyhow::Result<Self> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("ros2-io")
            .enable_all()
            .build()?;
        let config = zenoh.to_config()?;
        let bus = rt.block_on(async {
            let session = zenoh::open(config)
                .await
                .map_err(|e| anyhow::anyhow!("zenoh (ROS 2 side): {e}"))?;
            anyhow::Ok(Ros2Bus::new(session, graph, node).await?)
        })?;
        let link = Ros2Link {
            rt,
            bus: Arc::new(bus),
            frames: Arc::default(),
        };
        link.follow_tf_static()?;
        Ok(link)
    }

    /// The frames received so far.
    pub fn frames(&self) -> Arc<RwLock<Frames>> {
        self.frames.clone()
    }

    fn follow_tf_static(&self) -> anyhow::Result<()> {
        let sub = self.rt.block_on(self.bus.subscribe(
            "/tf_static",
            &keys::TF_MESSAGE,
            cdr::decode_tf_message,
        ))?;
        let frames = self.frames.clone();
        self.rt.spawn(async move {
            while let Some(r) = sub.recv().await {
                match r {
                    Ok(tfs) => {
                        let refused = frames.write().map(|mut f| f.add(&tfs)).unwrap_or(0);
                        if refused > 0 {
                            tracing::warn!("tf_static: {refused} transforms refused (not finite)");
                        }
                    }
                    Err(e) => tracing::debug!("tf_static: {e}"),
                }
            }
        });
        Ok(())
    }

    /// The driver of `topic` feeding `what`; `mount` is the configured `base_link <- sensor` of a
    /// cloud input (unused for the others).
    pub fn source(
        &self,
        what: Ros2Input,
        topic: &str,
        mount: Isometry3<f64>,
    ) -> anyhow::Result<SourceStart> {
        let ty = what.ros_type();
        let handle = self.rt.handle().clone();
        let frames = self.frames.clone();
        let start: SourceStart = match what {
            Ros2Input::Lidar | Ros2Input::Depth => {
                let sub =
                    self.rt
                        .block_on(self.bus.subscribe(topic, &ty, cdr::decode_point_cloud2))?;
                pump(handle, sub, what.topic(), move |c| {
                    let f = frames.read().map(|f| f.clone()).unwrap_or_default();
                    let scan = convert::cloud_to_scan(&c, &f, &mount);
                    Ok(vec![if what == Ros2Input::Lidar {
                        Input::Scan(scan)
                    } else {
                        Input::Depth(scan)
                    }])
                })
            }
            Ros2Input::VelodynePackets => {
                let sub = self.rt.block_on(self.bus.subscribe(topic, &ty, raw_cdr))?;
                let mut packets = PacketsToSweeps::default();
                pump(handle, sub, what.topic(), move |bytes| {
                    packets.sweeps(&bytes)
                })
            }
            Ros2Input::Odom => {
                let sub = self
                    .rt
                    .block_on(self.bus.subscribe(topic, &ty, cdr::decode_odometry))?;
                pump(handle, sub, what.topic(), |o| {
                    convert::odometry(&o)
                        .map(|o| vec![Input::Odom(o)])
                        .ok_or_else(|| "odometry with a non-finite value".to_string())
                })
            }
            Ros2Input::Imu => {
                let sub = self
                    .rt
                    .block_on(self.bus.subscribe(topic, &ty, cdr::decode_imu))?;
                pump(handle, sub, what.topic(), move |m| {
                    let f = frames.read().map(|f| f.clone()).unwrap_or_default();
                    Ok(vec![Input::Imu(convert::imu(&m, &f))])
                })
            }
            Ros2Input::Fix => {
                let sub =
                    self.rt
                        .block_on(self.bus.subscribe(topic, &ty, cdr::decode_nav_sat_fix))?;
                pump(handle, sub, what.topic(), |f| {
                    Ok(vec![Input::Fix(convert::fix(&f))])
                })
            }
            Ros2Input::Heading => {
                let sub = self.rt.block_on(self.bus.subscribe(
                    topic,
                    &ty,
                    cdr::decode_heading_quaternion,
                ))?;
                pump(handle, sub, what.topic(), |h| {
                    Ok(vec![Input::Heading(convert::heading(&h))])
                })
            }
        };
        tracing::info!("{} <- ROS 2 {topic} ({})", what.topic(), ty.name);
        Ok(start)
    }

    /// The base: `geometry_msgs/msg/Twist` on `topic`.
    pub fn base(&self, topic: &str) -> anyhow::Result<Box<dyn Base>> {
        let publisher = self.rt.block_on(self.bus.twist_publisher(topic))?;
        tracing::info!("base -> ROS 2 {topic} ({})", publisher.key());
        Ok(Box::new(TwistBase {
            handle: self.rt.handle().clone(),
            publisher,
        }))
    }
}

/// Receives `sub` until stopped, handing the inputs each sample converts into to the loop (a
/// sample may make none, one or several: packets make a sweep now and then).
fn pump<T: Send + 'static>(
    handle: tokio::runtime::Handle,
    sub: Subscription<T>,
    topic: Topic,
    mut convert: impl FnMut(T) -> Result<Vec<Input>, String> + Send + 'static,
) -> SourceStart {
    Box::new(move |tx: Sender<SourceEvent>, stop: Arc<AtomicBool>| {
        handle.block_on(async move {
            while !stop.load(Ordering::Relaxed) {
                let r = tokio::time::timeout(Duration::from_millis(100), sub.recv()).await;
                let events = match r {
                    Err(_) => continue,
                    Ok(None) => {
                        let _ = tx.send(SourceEvent::Ended(topic, "session closed".into()));
                        return;
                    }
                    Ok(Some(Err(e))) => vec![SourceEvent::Undecodable(topic, describe(&e))],
                    Ok(Some(Ok(m))) => match convert(m) {
                        Ok(inputs) => inputs.into_iter().map(SourceEvent::Input).collect(),
                        Err(why) => vec![SourceEvent::Undecodable(topic, why)],
                    },
                };
                for event in events {
                    if tx.send(event).is_err() {
                        return;
                    }
                }
            }
        })
    })
}

fn describe(e: &CdrError) -> String {
    format!("CDR: {e}")
}

/// A payload taken as it is (its own decoder runs in the driver).
fn raw_cdr(bytes: &[u8]) -> Result<Vec<u8>, CdrError> {
    Ok(bytes.to_vec())
}

/// `velodyne_msgs/msg/VelodyneScan` messages into sweeps: one assembler across messages, because
/// a driver's message need not start where a rotation does; sweeps are cut at 0 deg azimuth.
#[derive(Debug, Default)]
struct PacketsToSweeps {
    asm: Option<sensing::velodyne::ScanAssembler>,
}

impl PacketsToSweeps {
    /// The sweeps one message completes; `Err` when it is not a VelodyneScan or none of its
    /// packets is a VLP-16 data packet.
    fn sweeps(&mut self, bytes: &[u8]) -> Result<Vec<Input>, String> {
        let msg = sensing::velodyne::rosbag::decode_velodyne_scan(bytes)
            .map_err(|e| format!("VelodyneScan: {e}"))?;
        let asm = self.asm.get_or_insert_with(|| {
            sensing::velodyne::ScanAssembler::new(sensing::velodyne::VelodyneConfig::default())
        });
        let malformed_before = asm.stats().malformed();
        let mut out = Vec::new();
        for p in &msg.packets {
            out.extend(
                asm.push_packet(&p.data, p.stamp_s)
                    .iter()
                    .map(|s| Input::Scan(s.to_scan())),
            );
        }
        let malformed = asm.stats().malformed() - malformed_before;
        if malformed > 0 && malformed as usize == msg.packets.len() {
            return Err(format!("VelodyneScan: all {malformed} packets malformed"));
        }
        if malformed > 0 {
            tracing::debug!("VelodyneScan: {malformed} malformed packets skipped");
        }
        Ok(out)
    }
}

/// `cmd_vel` out.
struct TwistBase {
    handle: tokio::runtime::Handle,
    publisher: TwistPublisher,
}

impl Base for TwistBase {
    fn drive(&mut self, cmd: Cmd) -> anyhow::Result<()> {
        let t = Twist {
            linear_x_mps: cmd.v_mps,
            angular_z_rps: cmd.omega_rps,
        };
        self.handle
            .block_on(self.publisher.put(&t, unix_ns()))
            .map_err(|e| anyhow::anyhow!("cmd_vel: {e}"))
    }
}

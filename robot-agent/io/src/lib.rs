//! terranav-io: the robot's sources and sinks on real hardware, for the runtime
//! (`robot-agent run`) to wire into the agent. Nothing here knows the agent: sources deliver
//! [`sample`] types, sinks take them.
//!
//! - [`cdr`]: ROS 2 messages (PointCloud2 with any field layout, Odometry, Imu, NavSatFix,
//!   Twist, TFMessage, QuaternionStamped), bounds-checked, every failure a typed error.
//! - [`ros2`]: ROS 2 over Zenoh in the zenoh-bridge-ros2dds and rmw_zenoh key forms, and
//!   [`ros2::Ros2Bus`], the async adapter over a `zenoh::Session`.
//! - [`gnss`]: NMEA from serial, TCP and UDP, and gpsd's JSON protocol.
//! - [`source`]: the `KIND:ARGS` specs that name a source on the command line.

pub mod cdr;
pub mod gnss;
pub mod ros2;
pub mod sample;
pub mod source;

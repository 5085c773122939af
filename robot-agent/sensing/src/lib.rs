//! Sensor data types and real sensor input.
//!
//! - [`cloud`]: points and scans as every other crate sees them (simulated or real).
//! - [`pcd`], [`ply`]: point-cloud files (PCD v0.7 ascii/binary, binary little-endian PLY).
//! - [`sequence`]: recorded folders laid out like KITTI (`clouds/NNN.pcd` + `poses.txt`).
//! - [`velodyne`]: Velodyne VLP-16 packets (live UDP, pcap, ROS 2 bag) into scans.
//!
//! Nothing here knows whether data came from the simulator or a real sensor.
#![deny(missing_docs)]

pub mod cloud;
pub mod pcd;
pub mod ply;
pub mod sequence;
pub mod velodyne;

pub use cloud::{
    GnssFixSample, GnssHeadingSample, GnssSentence, ImuSample, OdomSample, Point, Scan,
};

//! ROS 2 over Zenoh: key naming for zenoh-bridge-ros2dds and rmw_zenoh ([`keys`]), rmw_zenoh's
//! sample attachment ([`attachment`]), and [`Ros2Bus`], a small async adapter over a
//! `zenoh::Session` that subscribes to topics as streams of decoded samples and publishes
//! `cmd_vel`.

pub mod attachment;
mod bus;
pub mod keys;

pub use attachment::Attachment;
pub use bus::{Ros2Bus, Ros2Error, Ros2Publisher, Subscription, TopicStats, TwistPublisher};
pub use keys::{KeyForm, Ros2Graph, RosType};

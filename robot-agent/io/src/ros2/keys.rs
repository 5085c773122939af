//! Where ROS 2 topics live in Zenoh's key space, in the two forms in use:
//!
//! - **bridge** (zenoh-bridge-ros2dds, robots on DDS): key `[NS/]TOPIC` (no leading slash), the
//!   payload the CDR sample with its 4-byte encapsulation header, no attachment.
//! - **rmw** (rmw_zenoh, the ROS 2 Zenoh middleware of Jazzy and later): key
//!   `<domain>/<ns/topic>/<dds type>/<type hash>`, e.g.
//!   `0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45…`; every sample carries an
//!   attachment (sequence number, source timestamp, 16-byte publisher GID); every node and
//!   publisher announces itself with a liveliness token
//!   `@ros2_lv/<domain>/<zid>/<nid>/<id>/<MP|MS|NN>/<enclave>/<ns>/<node>[/<topic>/<type>/<hash>/<qos>]`
//!   with `/` inside names written `%` and an empty name written `%`.
//!
//! Subscriptions in the rmw form match any type hash (`*`), so a Humble robot's
//! `TypeHashNotSupported` keys are received too; publications use the real RIHS01 hash, which
//! an rmw_zenoh subscriber's key must match exactly.

/// Which key form the robot's ROS 2 side uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyForm {
    /// zenoh-bridge-ros2dds.
    Bridge,
    /// rmw_zenoh.
    Rmw,
}

impl std::str::FromStr for KeyForm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "bridge" => Ok(KeyForm::Bridge),
            "rmw" => Ok(KeyForm::Rmw),
            other => Err(format!(
                "ROS 2 key form {other:?}: expected \"bridge\" or \"rmw\""
            )),
        }
    }
}

/// A ROS 2 message type as rmw_zenoh names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RosType {
    /// ROS name, `sensor_msgs/msg/PointCloud2`.
    pub name: &'static str,
    /// DDS name, `sensor_msgs::msg::dds_::PointCloud2_`.
    pub dds_name: &'static str,
    /// REP-2011 type hash of the Jazzy definition (checked against `rosbags` in tests/ros2_io.rs).
    pub hash: &'static str,
}

macro_rules! ros_type {
    ($c:ident, $pkg:literal, $msg:literal, $hash:literal) => {
        #[doc = concat!("`", $pkg, "/msg/", $msg, "`.")]
        pub const $c: RosType = RosType {
            name: concat!($pkg, "/msg/", $msg),
            dds_name: concat!($pkg, "::msg::dds_::", $msg, "_"),
            hash: $hash,
        };
    };
}

ros_type!(
    POINT_CLOUD2,
    "sensor_msgs",
    "PointCloud2",
    "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5"
);
ros_type!(
    ODOMETRY,
    "nav_msgs",
    "Odometry",
    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
);
ros_type!(
    IMU,
    "sensor_msgs",
    "Imu",
    "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b"
);
ros_type!(
    NAV_SAT_FIX,
    "sensor_msgs",
    "NavSatFix",
    "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404"
);
ros_type!(
    TWIST,
    "geometry_msgs",
    "Twist",
    "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
);
ros_type!(
    TF_MESSAGE,
    "tf2_msgs",
    "TFMessage",
    "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
);
ros_type!(
    QUATERNION_STAMPED,
    "geometry_msgs",
    "QuaternionStamped",
    "RIHS01_381add86c6c3160644d228ca342182c7fd6c7fab11c7a85ad817a9cc22dbac6e"
);
ros_type!(
    VELODYNE_SCAN,
    "velodyne_msgs",
    "VelodyneScan",
    "RIHS01_4e4edd7152e8bd604311d8b2e68e4c1b0771c8ce72700de79f6d1418aa242b3c"
);

/// Every type this crate decodes or encodes (`VelodyneScan`'s payload is decoded by
/// `sensing::velodyne::rosbag`).
pub const ALL_TYPES: [RosType; 8] = [
    POINT_CLOUD2,
    ODOMETRY,
    IMU,
    NAV_SAT_FIX,
    TWIST,
    TF_MESSAGE,
    QUATERNION_STAMPED,
    VELODYNE_SCAN,
];

/// Where the robot's ROS 2 graph is: key form, domain and namespace.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Ros2Graph {
    /// Key form.
    pub form: KeyForm,
    /// ROS_DOMAIN_ID (rmw form only).
    pub domain_id: u32,
    /// Namespace, e.g. `husky1` or `/husky1` (empty for none).
    pub namespace: String,
}

impl Ros2Graph {
    /// The fully qualified topic name without leading/trailing slashes: `husky1/cmd_vel`.
    /// A topic starting with `/` is absolute and ignores the namespace, as in ROS.
    pub fn topic_path(&self, topic: &str) -> String {
        let t = topic.trim_matches('/');
        let ns = self.namespace.trim_matches('/');
        if topic.starts_with('/') || ns.is_empty() {
            t.to_owned()
        } else {
            format!("{ns}/{t}")
        }
    }

    /// Key to subscribe to for a topic of type `ty`.
    pub fn subscribe_key(&self, topic: &str, ty: &RosType) -> String {
        match self.form {
            KeyForm::Bridge => self.topic_path(topic),
            KeyForm::Rmw => {
                format!(
                    "{}/{}/{}/*",
                    self.domain_id,
                    self.topic_path(topic),
                    ty.dds_name
                )
            }
        }
    }

    /// Key to publish a topic of type `ty` on.
    pub fn publish_key(&self, topic: &str, ty: &RosType) -> String {
        match self.form {
            KeyForm::Bridge => self.topic_path(topic),
            KeyForm::Rmw => {
                format!(
                    "{}/{}/{}/{}",
                    self.domain_id,
                    self.topic_path(topic),
                    ty.dds_name,
                    ty.hash
                )
            }
        }
    }

    /// The namespace as ROS writes it (`/husky1`, or `/` for none).
    fn ros_namespace(&self) -> String {
        format!("/{}", self.namespace.trim_matches('/'))
    }

    /// rmw_zenoh liveliness token of a node (`NN`).
    pub fn node_token(&self, zid: &str, node_id: u32, node: &str) -> String {
        format!(
            "@ros2_lv/{}/{zid}/{node_id}/{node_id}/NN/%/{}/{}",
            self.domain_id,
            mangle(&self.ros_namespace()),
            mangle(node)
        )
    }

    /// rmw_zenoh liveliness token of a publisher (`MP`) or subscription (`MS`) with the default
    /// QoS (reliable, volatile, keep last 10).
    pub fn endpoint_token(&self, e: Endpoint<'_>) -> String {
        let kind = if e.publisher { "MP" } else { "MS" };
        let topic = format!("/{}", self.topic_path(e.topic));
        format!(
            "@ros2_lv/{}/{}/{}/{}/{kind}/%/{}/{}/{}/{}/{}/{DEFAULT_QOS}",
            self.domain_id,
            e.zid,
            e.node_id,
            e.entity_id,
            mangle(&self.ros_namespace()),
            mangle(e.node),
            mangle(&topic),
            e.ty.dds_name,
            e.ty.hash,
        )
    }
}

/// What identifies a publisher or subscription in its liveliness token.
#[derive(Clone, Copy, Debug)]
pub struct Endpoint<'a> {
    /// Our Zenoh session id (hex).
    pub zid: &'a str,
    /// Node id within the session.
    pub node_id: u32,
    /// Entity id within the session.
    pub entity_id: u32,
    /// Node name.
    pub node: &'a str,
    /// Topic as given (relative or absolute).
    pub topic: &'a str,
    /// Message type.
    pub ty: &'a RosType,
    /// Publisher (true) or subscription.
    pub publisher: bool,
}

/// rmw_zenoh's QoS field for the default profile: every value left empty because it equals the
/// default (`reliability:durability:history,depth:deadline s,ns:lifespan s,ns:liveliness,lease s,ns`).
pub const DEFAULT_QOS: &str = "::,:,:,:,,";

/// A name as rmw_zenoh writes it inside a token: `/` becomes `%`, empty becomes `%`.
pub fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_in_both_forms() {
        let mut g = Ros2Graph {
            form: KeyForm::Bridge,
            domain_id: 0,
            namespace: String::new(),
        };
        assert_eq!(
            g.subscribe_key("velodyne_points", &POINT_CLOUD2),
            "velodyne_points"
        );
        assert_eq!(g.subscribe_key("/imu/data", &IMU), "imu/data");
        g.namespace = "/husky1/".into();
        assert_eq!(g.publish_key("cmd_vel", &TWIST), "husky1/cmd_vel");
        assert_eq!(g.publish_key("/cmd_vel", &TWIST), "cmd_vel");
        g.form = KeyForm::Rmw;
        g.namespace.clear();
        assert_eq!(
            g.publish_key("cmd_vel", &TWIST),
            "0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
        );
        g.domain_id = 7;
        assert_eq!(
            g.subscribe_key("fix", &NAV_SAT_FIX),
            "7/fix/sensor_msgs::msg::dds_::NavSatFix_/*"
        );
    }

    #[test]
    fn liveliness_tokens() {
        let g = Ros2Graph {
            form: KeyForm::Rmw,
            domain_id: 0,
            namespace: String::new(),
        };
        assert_eq!(
            g.node_token("abc123", 0, "terranav"),
            "@ros2_lv/0/abc123/0/0/NN/%/%/terranav"
        );
        let t = g.endpoint_token(Endpoint {
            zid: "abc123",
            node_id: 0,
            entity_id: 3,
            node: "terranav",
            topic: "cmd_vel",
            ty: &TWIST,
            publisher: true,
        });
        assert_eq!(
            t,
            format!("@ros2_lv/0/abc123/0/3/MP/%/%/terranav/%cmd_vel/geometry_msgs::msg::dds_::Twist_/{}/::,:,:,:,,", TWIST.hash)
        );
    }
}

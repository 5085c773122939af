//! The channels of a robot's recording: one per input, the runtime's commands in and out, and
//! its outputs, each with its schema. `config/foxglove/terranav-layout.json` shows them.

use crate::runtime::stamps::Topic;
use record::schemas::{foxglove, terranav};
use record::{ChannelId, Recorder, Schema};

/// Frame of the LiDAR's clouds (its mount on `base_link` is in `/tf_static`).
pub const LIDAR_FRAME: &str = "lidar";
/// Frame of the depth camera's clouds.
pub const DEPTH_FRAME: &str = "depth_camera";
/// The map frame (ENU at the datum).
pub const MAP_FRAME: &str = "map";

/// The inputs, each on its own channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InputKind {
    /// LiDAR sweeps.
    Lidar,
    /// Depth-camera frames.
    Depth,
    /// Wheel odometry.
    Odom,
    /// IMU.
    Imu,
    /// NMEA sentences.
    Nmea,
    /// Decoded fixes.
    Fix,
    /// Headings.
    Heading,
}

impl InputKind {
    /// Every kind.
    pub const ALL: [InputKind; 7] = [
        InputKind::Lidar,
        InputKind::Depth,
        InputKind::Odom,
        InputKind::Imu,
        InputKind::Nmea,
        InputKind::Fix,
        InputKind::Heading,
    ];

    /// Its topic in the recording.
    pub fn topic(self) -> &'static str {
        match self {
            InputKind::Lidar => "/lidar/points",
            InputKind::Depth => "/depth/points",
            InputKind::Odom => "/odom",
            InputKind::Imu => "/imu",
            InputKind::Nmea => "/gnss/nmea",
            InputKind::Fix => "/gnss/fix",
            InputKind::Heading => "/gnss/heading",
        }
    }

    /// Its schema.
    pub fn schema(self) -> Schema {
        match self {
            InputKind::Lidar | InputKind::Depth => foxglove::point_cloud(),
            InputKind::Odom => foxglove::odometry(),
            InputKind::Imu => terranav::imu(),
            InputKind::Nmea => terranav::nmea_sentence(),
            InputKind::Fix => foxglove::location_fix(),
            InputKind::Heading => terranav::heading(),
        }
    }

    /// The kind of a recorded topic.
    pub fn of_topic(topic: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.topic() == topic)
    }

    /// The kind of a runtime input.
    pub fn of(input: &crate::runtime::Input) -> Self {
        use crate::runtime::Input;
        match input {
            Input::Scan(_) => InputKind::Lidar,
            Input::Depth(_) => InputKind::Depth,
            Input::Odom(_) => InputKind::Odom,
            Input::Imu(_) => InputKind::Imu,
            Input::Gnss(_) => InputKind::Nmea,
            Input::Fix(_) => InputKind::Fix,
            Input::Heading(_) => InputKind::Heading,
        }
    }

    /// The runtime's stream of this kind.
    pub fn stream(self) -> Topic {
        match self {
            InputKind::Lidar => Topic::Lidar,
            InputKind::Depth => Topic::Depth,
            InputKind::Odom => Topic::Odom,
            InputKind::Imu => Topic::Imu,
            InputKind::Nmea | InputKind::Fix => Topic::Gnss,
            InputKind::Heading => Topic::Heading,
        }
    }
}

/// Commands as they reached the agent (`terranav.Command`): what a replay re-applies.
pub const COMMANDS: &str = "/commands";
/// The base command of each control period (`terranav.BaseCommand`): when a replay runs control.
pub const CMD_VEL: &str = "/cmd_vel";

/// Every channel of a robot's recording.
#[derive(Clone, Debug)]
pub struct Channels {
    /// Per input kind, in [`InputKind::ALL`] order.
    pub inputs: [ChannelId; 7],
    /// [`COMMANDS`].
    pub commands: ChannelId,
    /// [`CMD_VEL`].
    pub cmd_vel: ChannelId,
    /// `/tf`: map -> base_link (`foxglove.FrameTransform`).
    pub tf: ChannelId,
    /// `/tf_static`: the sensor mounts (`foxglove.FrameTransforms`).
    pub tf_static: ChannelId,
    /// `/localisation/pose` (`foxglove.PoseInFrame`).
    pub pose: ChannelId,
    /// `/localisation/fix` (`foxglove.LocationFix`): the robot on a map.
    pub fix: ChannelId,
    /// `/map/grid` (`foxglove.Grid`): the traversability grid around the robot.
    pub grid: ChannelId,
    /// `/map/tiles` (`terranav.Tile`): tiles as sent to the station.
    pub tiles: ChannelId,
    /// `/planning/path` (`foxglove.SceneUpdate`).
    pub path: ChannelId,
    /// `/mission/goal` (`foxglove.SceneUpdate`).
    pub goal: ChannelId,
    /// `/mission/route` (`foxglove.SceneUpdate`).
    pub route: ChannelId,
    /// `/status` (`terranav.Status`).
    pub status: ChannelId,
    /// `/session` (`terranav.Session`).
    pub session: ChannelId,
    /// `/log` (`foxglove.Log`): refusals, faults, undecodable inputs.
    pub log: ChannelId,
}

impl Channels {
    /// Declares every channel on `rec`.
    pub fn declare(rec: &mut Recorder) -> Self {
        let inputs = InputKind::ALL.map(|k| rec.channel(k.topic(), &k.schema()));
        Self {
            inputs,
            commands: rec.channel(COMMANDS, &terranav::command()),
            cmd_vel: rec.channel(CMD_VEL, &terranav::base_command()),
            tf: rec.channel("/tf", &foxglove::frame_transform()),
            tf_static: rec.channel("/tf_static", &foxglove::frame_transforms()),
            pose: rec.channel("/localisation/pose", &foxglove::pose_in_frame()),
            fix: rec.channel("/localisation/fix", &foxglove::location_fix()),
            grid: rec.channel("/map/grid", &foxglove::grid()),
            tiles: rec.channel("/map/tiles", &terranav::tile()),
            path: rec.channel("/planning/path", &foxglove::scene_update()),
            goal: rec.channel("/mission/goal", &foxglove::scene_update()),
            route: rec.channel("/mission/route", &foxglove::scene_update()),
            status: rec.channel("/status", &terranav::status()),
            session: rec.channel("/session", &terranav::session()),
            log: rec.channel("/log", &foxglove::log()),
        }
    }

    /// The channel of an input kind.
    pub fn input(&self, k: InputKind) -> ChannelId {
        self.inputs[InputKind::ALL.iter().position(|x| *x == k).unwrap_or(0)]
    }
}

//! What the agent is told to do, in its own types: the bus translates wire commands into these
//! (and checks them against `common::command` first), so the agent never sees a wire message and
//! a replay or a test can drive it without one.

use common::command::{Refusal, RefusalCode};
use common::msg::Datum;
use serde::{Deserialize, Serialize};

/// A command with the time it arrived, seconds on the agent's clock.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Command {
    /// Arrival time, seconds (the same clock as the sensor data).
    pub t_s: f64,
    /// What to do.
    pub kind: CommandKind,
}

impl Command {
    /// `kind` arriving at `t_s`.
    pub fn at(t_s: f64, kind: CommandKind) -> Self {
        Self { t_s, kind }
    }
}

/// Where a goal is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum GoalTarget {
    /// In the map frame, metres.
    Map {
        /// x (east), metres.
        x_m: f64,
        /// y (north), metres.
        y_m: f64,
    },
    /// WGS-84, degrees; the height defaults to the robot's.
    Geodetic {
        /// Latitude, degrees.
        lat_deg: f64,
        /// Longitude, degrees.
        lon_deg: f64,
        /// Ellipsoidal height, metres.
        h_m: Option<f64>,
    },
}

/// Direction of a repeat.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Direction {
    /// Back to where the route was taught from (return home).
    Reverse,
    /// Again from start to end.
    Forward,
}

/// One taught waypoint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoutePoint {
    /// Map x, metres.
    pub x_m: f64,
    /// Map y, metres.
    pub y_m: f64,
    /// Latitude, degrees, when the map is anchored.
    pub lat_deg: Option<f64>,
    /// Longitude, degrees, when the map is anchored.
    pub lon_deg: Option<f64>,
    /// Ellipsoidal height, metres, when known.
    pub h_m: Option<f64>,
    /// Heading when taught, radians.
    pub yaw_rad: f64,
    /// When taught, Unix milliseconds.
    pub t_unix_ms: u64,
}

/// A taught route.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaughtRoute {
    /// Route id.
    pub route_id: String,
    /// Name given by the operator.
    pub name: String,
    /// Robot that taught it.
    pub robot: String,
    /// Session it was taught in.
    pub session_id: String,
    /// Datum of the frame of `points` (None: a SLAM-only frame).
    pub datum: Option<Datum>,
    /// Waypoints in driving order.
    pub points: Vec<RoutePoint>,
}

/// The commands the agent understands (as JSON: tagged by `kind`, in a recording).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum CommandKind {
    /// Go to a goal.
    Goal {
        /// Id chosen by the sender, echoed in the status.
        id: u32,
        /// Where.
        target: GoalTarget,
        /// Reached within this distance, metres (0: the robot's default).
        tolerance_m: f64,
    },
    /// Teleop: drive at (v, omega) while the operator holds the deadman.
    Drive {
        /// Sequence number, increasing (0: not sequenced).
        seq: u32,
        /// Forward speed, m/s.
        v_mps: f64,
        /// Turn rate, rad/s.
        omega_rps: f64,
        /// The operator holds the deadman.
        deadman: bool,
    },
    /// Stop now and end the mission.
    Stop {
        /// Why, for the status.
        reason: String,
    },
    /// Speed limit (clamped to the controller's own).
    SpeedLimit {
        /// m/s.
        v_mps: f64,
    },
    /// Start teaching a route: the operator drives, the agent records.
    Record {
        /// Route name.
        name: String,
    },
    /// End teaching; the route is handed out once ([`crate::Agent::take_taught_route`]).
    StopRecording,
    /// Follow a taught route.
    Repeat {
        /// The route.
        route: TaughtRoute,
        /// Which way.
        direction: Direction,
    },
    /// Pause a repeat.
    Pause,
    /// Resume a paused repeat.
    Resume,
    /// Cancel a repeat.
    Cancel,
    /// The zones to obey from now on (replaces the set in force).
    Zones {
        /// The station's version of the set.
        version: u64,
        /// The session whose map frame the polygons are in.
        session_id: String,
        /// The zones, in the map frame.
        zones: Vec<crate::zones::ZoneShape>,
    },
}

impl CommandKind {
    /// The command's kind as one word, for logs and refusal messages.
    pub fn name(&self) -> &'static str {
        match self {
            CommandKind::Goal { .. } => "goal",
            CommandKind::Drive { .. } => "drive",
            CommandKind::Stop { .. } => "stop",
            CommandKind::SpeedLimit { .. } => "speed",
            CommandKind::Record { .. }
            | CommandKind::StopRecording
            | CommandKind::Repeat { .. }
            | CommandKind::Pause
            | CommandKind::Resume
            | CommandKind::Cancel => "route",
            CommandKind::Zones { .. } => "zones",
        }
    }
}

/// A refusal by the agent: `kind: reason` with its code.
pub(crate) fn refusal(code: RefusalCode, kind: &str, reason: impl std::fmt::Display) -> Refusal {
    Refusal::new(code, format!("{kind}: {reason}"))
}

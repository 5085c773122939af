//! What the agent tells the world, in its own types (the bus turns them into wire messages).

use crate::localiser::{FixKind, PoseMap, SlamHealth};
use crate::mission::{Mode, Phase};

/// The pose estimate at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseEstimate {
    /// Time, seconds.
    pub t_s: f64,
    /// `map<-base_link`.
    pub pose: PoseMap,
    /// Forward speed from odometry, m/s.
    pub v_mps: f64,
    /// Turn rate from odometry, rad/s.
    pub omega_rps: f64,
    /// GNSS fix quality.
    pub fix: FixKind,
    /// Latitude, longitude (degrees) and ellipsoidal height (metres) through the datum.
    pub lla: Option<(f64, f64, f64)>,
}

/// Progress along a route being repeated.
#[derive(Clone, Debug, PartialEq)]
pub struct RouteProgress {
    /// Route id.
    pub route_id: String,
    /// Route name.
    pub name: String,
    /// Index of the next waypoint.
    pub waypoint: usize,
    /// Waypoints (taught and spliced).
    pub waypoints: usize,
    /// Distance left along the route, metres.
    pub distance_left_m: f64,
    /// Detours spliced in so far.
    pub detours: usize,
}

/// The agent's state for operators.
#[derive(Clone, Debug, PartialEq)]
pub struct AgentStatus {
    /// Time, seconds.
    pub t_s: f64,
    /// Mode.
    pub mode: Mode,
    /// An operator's drive is in force (teleop, or teaching while driving).
    pub driving: bool,
    /// Phase of the mission.
    pub phase: Phase,
    /// Why, for humans.
    pub reason: String,
    /// The goal, map frame, metres.
    pub goal_m: Option<(f64, f64)>,
    /// The goal's id.
    pub goal_id: u32,
    /// GNSS fix quality.
    pub fix: FixKind,
    /// Navigating on SLAM and odometry only because GNSS was lost.
    pub gnss_lost: bool,
    /// SLAM health.
    pub slam: SlamHealth,
    /// Speed limit in force, m/s.
    pub speed_limit_mps: f64,
    /// The controller's own top speed, m/s.
    pub speed_max_mps: f64,
    /// Version of the zone set in force (0: none).
    pub zones_version: u64,
    /// The zone acting on the robot now, for humans.
    pub zone: Option<String>,
    /// A route is being recorded.
    pub recording: bool,
    /// Route progress while repeating.
    pub route: Option<RouteProgress>,
    /// The last error or refusal.
    pub last_error: Option<String>,
    /// Commands refused since start.
    pub commands_refused: u32,
}

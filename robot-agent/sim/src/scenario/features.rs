//! The scenario's features: curbs and steps, platforms, stairs, ramps, holes, walls, poles, trees,
//! boxes, parked cars, walkers and GNSS-denied areas.

use super::Rect;
use serde::Deserialize;

/// A curb or step: a raised rectangle, or a raised strip along a polyline.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepSpec {
    /// Raised rectangle (either this or `points`).
    pub rect: Option<Rect>,
    /// Raised strip centre line (either this or `rect`).
    pub points: Option<Vec<[f64; 2]>>,
    /// Strip width when `points` is given, metres.
    #[serde(default = "default_step_width")]
    pub width_m: f64,
    /// Height above the local terrain, metres.
    pub height_m: f64,
}

fn default_step_width() -> f64 {
    0.3
}

/// A flat-topped platform with vertical drop-offs.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlatformSpec {
    /// Footprint.
    pub rect: Rect,
    /// Top height above the local terrain, metres.
    pub height_m: f64,
}

/// A flight of stairs rising along `yaw_deg` from its bottom edge centre.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StairsSpec {
    /// Bottom edge centre x, metres.
    pub x_m: f64,
    /// Bottom edge centre y, metres.
    pub y_m: f64,
    /// Direction of ascent, degrees.
    pub yaw_deg: f64,
    /// Width, metres.
    pub width_m: f64,
    /// Number of steps.
    pub steps: u32,
    /// Rise per step, metres.
    pub step_height_m: f64,
    /// Tread depth, metres.
    pub step_depth_m: f64,
    /// Flat landing at the top, metres.
    #[serde(default)]
    pub landing_m: f64,
}

/// A plane ramp rising along `yaw_deg` from its bottom edge centre.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RampSpec {
    /// Bottom edge centre x, metres.
    pub x_m: f64,
    /// Bottom edge centre y, metres.
    pub y_m: f64,
    /// Direction of ascent, degrees.
    pub yaw_deg: f64,
    /// Slope, degrees.
    pub slope_deg: f64,
    /// Width, metres.
    pub width_m: f64,
    /// Horizontal length of the sloped part, metres.
    pub length_m: f64,
    /// Flat landing at the top, metres.
    #[serde(default)]
    pub landing_m: f64,
}

/// A hole (open manhole, pit) with vertical walls.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HoleSpec {
    /// Footprint.
    pub rect: Rect,
    /// Depth below the local terrain, metres.
    pub depth_m: f64,
}

/// A wall along a polyline.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    /// Centre line, metres.
    pub points: Vec<[f64; 2]>,
    /// Thickness, metres.
    #[serde(default = "default_wall_thickness")]
    pub thickness_m: f64,
    /// Height above ground, metres.
    pub height_m: f64,
}

fn default_wall_thickness() -> f64 {
    0.25
}

/// A vertical pole (lamp post, bollard).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoleSpec {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Radius, metres.
    #[serde(default = "default_pole_radius")]
    pub radius_m: f64,
    /// Height, metres.
    #[serde(default = "default_pole_height")]
    pub height_m: f64,
}

fn default_pole_radius() -> f64 {
    0.08
}
fn default_pole_height() -> f64 {
    4.0
}

/// A tree: a trunk up to the canopy base, and an ellipsoidal canopy above it.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TreeSpec {
    /// x, metres.
    pub x_m: f64,
    /// y, metres.
    pub y_m: f64,
    /// Trunk radius, metres.
    #[serde(default = "default_trunk_radius")]
    pub trunk_radius_m: f64,
    /// Height of the canopy's lowest point above ground, metres.
    #[serde(default = "default_canopy_base")]
    pub canopy_base_m: f64,
    /// Canopy horizontal radius, metres.
    #[serde(default = "default_canopy_radius")]
    pub canopy_radius_m: f64,
    /// Canopy vertical extent, metres.
    #[serde(default = "default_canopy_height")]
    pub canopy_height_m: f64,
}

fn default_trunk_radius() -> f64 {
    0.2
}
fn default_canopy_base() -> f64 {
    2.2
}
fn default_canopy_radius() -> f64 {
    2.5
}
fn default_canopy_height() -> f64 {
    3.0
}

/// A box (crate, bench block, debris).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Footprint.
    pub rect: Rect,
    /// Height above ground, metres.
    pub height_m: f64,
}

/// A parked car: a body from 0.2 m above ground to 1 m, and a cabin on top.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CarSpec {
    /// Centre x, metres.
    pub x_m: f64,
    /// Centre y, metres.
    pub y_m: f64,
    /// Heading, degrees.
    #[serde(default)]
    pub yaw_deg: f64,
    /// Length, metres.
    #[serde(default = "default_car_length")]
    pub length_m: f64,
    /// Width, metres.
    #[serde(default = "default_car_width")]
    pub width_m: f64,
    /// Roof height, metres.
    #[serde(default = "default_car_height")]
    pub height_m: f64,
}

fn default_car_length() -> f64 {
    4.5
}
fn default_car_width() -> f64 {
    1.8
}
fn default_car_height() -> f64 {
    1.5
}

/// How a walker repeats its polyline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum WalkMode {
    /// Walk back to the first point and start again.
    #[default]
    Loop,
    /// Walk back along the polyline.
    PingPong,
}

/// A pedestrian walking a polyline.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WalkerSpec {
    /// Vertices (x, y), metres.
    pub points: Vec<[f64; 2]>,
    /// Walking speed, m/s.
    #[serde(default = "default_walk_speed")]
    pub speed_mps: f64,
    /// Loop or ping-pong.
    #[serde(default)]
    pub mode: WalkMode,
    /// Distance along the route at t = 0, metres.
    #[serde(default)]
    pub phase_m: f64,
    /// Body radius, metres.
    #[serde(default = "default_walker_radius")]
    pub radius_m: f64,
    /// Body height, metres.
    #[serde(default = "default_walker_height")]
    pub height_m: f64,
}

/// What the GNSS receiver still produces inside a `gnss_denied` area.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DeniedFix {
    /// No position at all (GGA quality 0).
    #[default]
    None,
    /// An autonomous single-point fix without RTK (GGA quality 1, metres of error).
    Single,
}

/// An area where RTK is unavailable (trees, buildings): a simple polygon in the map frame.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssDeniedSpec {
    /// Corners (x, y), metres (ENU of the datum).
    pub points: Vec<[f64; 2]>,
    /// What the receiver produces inside.
    #[serde(default)]
    pub fix: DeniedFix,
}

impl GnssDeniedSpec {
    /// The corners as (x, y) tuples.
    pub fn polygon(&self) -> Vec<(f64, f64)> {
        self.points.iter().map(|p| (p[0], p[1])).collect()
    }
}

fn default_walk_speed() -> f64 {
    1.3
}
fn default_walker_radius() -> f64 {
    0.25
}
fn default_walker_height() -> f64 {
    1.75
}

//! The one contract every command must satisfy, whoever sends or receives it.
//!
//! The HTTP API and the station CLI check a command here before they send it, and the robot checks
//! it here again when it arrives (a peer may not be our station). A refusal is a [`Refusal`]: a
//! stable machine code ([`RefusalCode::as_str`], what API clients match on) and a sentence for
//! the operator. The robot's own state-dependent refusals (no datum for a GNSS goal, not
//! recording) use the same codes.
//!
//! Checks that need to know where the robot is (a GNSS goal 4 000 km away because latitude and
//! longitude were swapped, a map goal far outside anything mapped) take a [`RobotContext`]; a
//! sender that does not know the robot's position passes [`RobotContext::default`] and those
//! checks are left to the robot, which always knows.
//!
//! Every command travels with a [`CmdHeader`] (sender, sequence, time): the sender stamps it with
//! a [`CommandStamper`], the robot checks it with a [`ReplayGuard`] before anything else, so a
//! command captured and sent again later is refused even when it comes over an authorised link.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::msg::{CmdHeader, DriveCmd, GoalCmd, GoalTarget, RouteCmd, SpeedCmd, ZoneKind, ZoneSet};
use serde::{Deserialize, Serialize};

/// Why a command was refused: stable codes, never renamed (API clients and tests match on them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum RefusalCode {
    /// The payload could not be decoded (another schema, garbage, trailing bytes).
    Undecodable,
    /// The robot id is not of the form `[a-z0-9-]+`.
    BadRobotId,
    /// The station knows no robot of that id.
    UnknownRobot,
    /// The robot is offline: the command would be lost.
    RobotOffline,
    /// A number is NaN or infinite.
    NotFinite,
    /// Goal tolerance outside 0-100 m.
    ToleranceOutOfRange,
    /// Latitude outside -90..90 degrees.
    LatitudeOutOfRange,
    /// Longitude outside -180..180 degrees.
    LongitudeOutOfRange,
    /// Goal height outside -1000..10000 m.
    HeightOutOfRange,
    /// Latitude and longitude both 0: an unset position, not a goal.
    NullIsland,
    /// A GNSS goal farther than `max_goal_distance_m` from the robot (often: latitude and
    /// longitude swapped).
    GoalTooFar,
    /// A map goal farther than `max_goal_distance_m` from the robot and from everything mapped.
    GoalOffMap,
    /// A GNSS goal while the robot's map frame has no datum.
    NoDatum,
    /// Drive speed beyond the limit.
    SpeedOutOfRange,
    /// Drive turn rate beyond the limit.
    TurnRateOutOfRange,
    /// A speed limit that is not positive.
    BadSpeedLimit,
    /// A route name that is empty or longer than 200 characters.
    BadRouteName,
    /// A route without (enough) points.
    RouteTooShort,
    /// A route with non-finite points.
    BadRoutePoints,
    /// A route recorded in another frame, and this session cannot convert it (no datum).
    RouteFrameMismatch,
    /// Stop recording, but nothing is being recorded.
    NotRecording,
    /// The robot is recording a route: stop recording first.
    Teaching,
    /// Pause, resume or cancel without a route being repeated.
    NotRepeating,
    /// The robot has no pose yet (no scan processed).
    NoPose,
    /// A command replayed or out of order (older sequence or stale time).
    Replayed,
    /// A goal inside a keep-out zone.
    GoalInKeepOut,
    /// A zone that is not a usable polygon (too few corners, not finite, crossing itself) or a
    /// slow zone without a positive speed.
    BadZone,
    /// A zone set for another session's map frame.
    ZoneFrameMismatch,
    /// A command sent to a read-only monitor station (`serve --monitor`): it sends no commands.
    MonitorReadOnly,
}

impl RefusalCode {
    /// The stable code text, e.g. `goal_too_far`.
    pub fn as_str(self) -> &'static str {
        match self {
            RefusalCode::Undecodable => "undecodable",
            RefusalCode::BadRobotId => "bad_robot_id",
            RefusalCode::UnknownRobot => "unknown_robot",
            RefusalCode::RobotOffline => "robot_offline",
            RefusalCode::NotFinite => "not_finite",
            RefusalCode::ToleranceOutOfRange => "tolerance_out_of_range",
            RefusalCode::LatitudeOutOfRange => "latitude_out_of_range",
            RefusalCode::LongitudeOutOfRange => "longitude_out_of_range",
            RefusalCode::HeightOutOfRange => "height_out_of_range",
            RefusalCode::NullIsland => "null_island",
            RefusalCode::GoalTooFar => "goal_too_far",
            RefusalCode::GoalOffMap => "goal_off_map",
            RefusalCode::NoDatum => "no_datum",
            RefusalCode::SpeedOutOfRange => "speed_out_of_range",
            RefusalCode::TurnRateOutOfRange => "turn_rate_out_of_range",
            RefusalCode::BadSpeedLimit => "bad_speed_limit",
            RefusalCode::BadRouteName => "bad_route_name",
            RefusalCode::RouteTooShort => "route_too_short",
            RefusalCode::BadRoutePoints => "bad_route_points",
            RefusalCode::RouteFrameMismatch => "route_frame_mismatch",
            RefusalCode::NotRecording => "not_recording",
            RefusalCode::Teaching => "teaching",
            RefusalCode::NotRepeating => "not_repeating",
            RefusalCode::NoPose => "no_pose",
            RefusalCode::Replayed => "replayed",
            RefusalCode::GoalInKeepOut => "goal_in_keep_out",
            RefusalCode::BadZone => "bad_zone",
            RefusalCode::ZoneFrameMismatch => "zone_frame_mismatch",
            RefusalCode::MonitorReadOnly => "monitor_read_only",
        }
    }
}

impl std::fmt::Display for RefusalCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A refused command: a stable code and what to tell the operator.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error, Serialize, Deserialize)]
#[error("{message} [{code}]")]
pub struct Refusal {
    /// Machine-readable reason.
    pub code: RefusalCode,
    /// Human-readable reason, prefixed with the command kind, e.g. `goal: latitude 91 out of range`.
    pub message: String,
}

impl Refusal {
    /// A refusal with `code` and `message`.
    pub fn new(code: RefusalCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
        }
    }
}

/// The limits a robot enforces (it announces them in its session so senders check the same).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CommandLimits {
    /// Largest accepted |v| of a drive command, m/s.
    pub max_speed_mps: f32,
    /// Largest accepted |omega| of a drive command, rad/s.
    pub max_omega_rps: f32,
    /// A goal farther than this from the robot is refused (for a map goal: also farther than
    /// this from everything mapped), metres.
    pub max_goal_distance_m: f64,
}

impl Default for CommandLimits {
    fn default() -> Self {
        Self {
            max_speed_mps: 2.0,
            max_omega_rps: 2.0,
            max_goal_distance_m: 1000.0,
        }
    }
}

/// An axis-aligned rectangle of the map frame, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoundsM {
    /// Lower-left corner (x, y).
    pub min_m: (f64, f64),
    /// Upper-right corner (x, y).
    pub max_m: (f64, f64),
}

impl BoundsM {
    /// Distance from `p` to the rectangle (0 inside), metres.
    pub fn distance_m(&self, p: (f64, f64)) -> f64 {
        let dx = (self.min_m.0 - p.0).max(p.0 - self.max_m.0).max(0.0);
        let dy = (self.min_m.1 - p.1).max(p.1 - self.max_m.1).max(0.0);
        dx.hypot(dy)
    }
}

/// What the checker knows about the robot a command is for; `None` fields skip the checks that
/// need them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotContext {
    /// The robot's position, map frame, metres.
    pub position_m: Option<(f64, f64)>,
    /// The robot's position, WGS-84 degrees (lat, lon).
    pub lat_lon_deg: Option<(f64, f64)>,
    /// What the robot (or the merged map of its datum) has mapped, map frame.
    pub mapped: Option<BoundsM>,
}

fn refuse<T>(code: RefusalCode, message: String) -> Result<T, Refusal> {
    Err(Refusal { code, message })
}

/// Great-circle distance between two WGS-84 positions (haversine on the mean radius), metres.
/// Good to 0.5 %, which is all a "farther than a kilometre" check needs.
pub fn ground_distance_m(a: (f64, f64), b: (f64, f64)) -> f64 {
    const R_M: f64 = 6_371_008.8;
    let (la1, la2) = (a.0.to_radians(), b.0.to_radians());
    let dla = la2 - la1;
    let dlo = (b.1 - a.1).to_radians();
    let h = (dla / 2.0).sin().powi(2) + la1.cos() * la2.cos() * (dlo / 2.0).sin().powi(2);
    2.0 * R_M * h.sqrt().min(1.0).asin()
}

/// Checks a goal.
pub fn check_goal(g: &GoalCmd, limits: &CommandLimits, ctx: &RobotContext) -> Result<(), Refusal> {
    if !(g.tolerance_m.is_finite() && (0.0..=100.0).contains(&g.tolerance_m)) {
        return refuse(
            RefusalCode::ToleranceOutOfRange,
            format!("goal: tolerance {} m out of range 0-100", g.tolerance_m),
        );
    }
    let max_m = limits.max_goal_distance_m;
    match g.target {
        GoalTarget::Map { x_m, y_m } => {
            if !(x_m.is_finite() && y_m.is_finite()) {
                return refuse(
                    RefusalCode::NotFinite,
                    "goal: coordinates are not finite".into(),
                );
            }
            if let Some(robot) = ctx.position_m {
                let from_robot = (x_m - robot.0).hypot(y_m - robot.1);
                let from_map = ctx
                    .mapped
                    .map_or(f64::INFINITY, |b| b.distance_m((x_m, y_m)));
                if from_robot > max_m && from_map > max_m {
                    return refuse(
                        RefusalCode::GoalOffMap,
                        format!(
                            "goal: ({x_m:.1}, {y_m:.1}) is {from_robot:.0} m from the robot and {} from anything mapped, beyond the {max_m:.0} m limit",
                            if from_map.is_finite() { format!("{from_map:.0} m") } else { "far".into() }
                        ),
                    );
                }
            }
        }
        GoalTarget::Gnss {
            lat_deg,
            lon_deg,
            h_m,
        } => {
            if !(lat_deg.is_finite() && (-90.0..=90.0).contains(&lat_deg)) {
                return refuse(
                    RefusalCode::LatitudeOutOfRange,
                    format!("goal: latitude {lat_deg} out of range -90..90"),
                );
            }
            if !(lon_deg.is_finite() && (-180.0..=180.0).contains(&lon_deg)) {
                return refuse(
                    RefusalCode::LongitudeOutOfRange,
                    format!("goal: longitude {lon_deg} out of range -180..180"),
                );
            }
            if let Some(h) = h_m {
                if !(h.is_finite() && (-1000.0..=10_000.0).contains(&h)) {
                    return refuse(
                        RefusalCode::HeightOutOfRange,
                        format!("goal: height {h} m out of range -1000..10000"),
                    );
                }
            }
            if lat_deg.abs() < 1e-7 && lon_deg.abs() < 1e-7 {
                return refuse(
                    RefusalCode::NullIsland,
                    "goal: latitude and longitude are both 0 (an unset position, not a goal)"
                        .into(),
                );
            }
            if let Some(robot) = ctx.lat_lon_deg {
                let d = ground_distance_m(robot, (lat_deg, lon_deg));
                if d > max_m {
                    let swapped = ground_distance_m(robot, (lon_deg, lat_deg));
                    let hint = if lon_deg.abs() <= 90.0 && swapped <= max_m {
                        format!(
                            "; latitude and longitude look swapped ({lon_deg}, {lat_deg} is {swapped:.0} m away)"
                        )
                    } else {
                        String::new()
                    };
                    return refuse(
                        RefusalCode::GoalTooFar,
                        format!(
                            "goal: ({lat_deg}, {lon_deg}) is {:.1} km from the robot, beyond the {max_m:.0} m limit{hint}",
                            d / 1000.0
                        ),
                    );
                }
            }
        }
    }
    Ok(())
}

/// Checks a teleop drive command.
pub fn check_drive(d: &DriveCmd, limits: &CommandLimits) -> Result<(), Refusal> {
    if !(d.v_mps.is_finite() && d.v_mps.abs() <= limits.max_speed_mps) {
        return refuse(
            RefusalCode::SpeedOutOfRange,
            format!(
                "drive: speed {} m/s beyond the limit {} m/s",
                d.v_mps, limits.max_speed_mps
            ),
        );
    }
    if !(d.omega_rps.is_finite() && d.omega_rps.abs() <= limits.max_omega_rps) {
        return refuse(
            RefusalCode::TurnRateOutOfRange,
            format!(
                "drive: turn rate {} rad/s beyond the limit {} rad/s",
                d.omega_rps, limits.max_omega_rps
            ),
        );
    }
    Ok(())
}

/// Checks a speed limit.
pub fn check_speed(s: &SpeedCmd) -> Result<(), Refusal> {
    if !(s.limit_mps.is_finite() && s.limit_mps > 0.0) {
        return refuse(
            RefusalCode::BadSpeedLimit,
            format!("speed: limit {} m/s must be positive", s.limit_mps),
        );
    }
    Ok(())
}

/// Checks a route command.
pub fn check_route(r: &RouteCmd) -> Result<(), Refusal> {
    match r {
        RouteCmd::Record { name } if name.trim().is_empty() || name.chars().count() > 200 => {
            refuse(
                RefusalCode::BadRouteName,
                "route: name must have 1-200 characters".into(),
            )
        }
        RouteCmd::Repeat { route, .. } => {
            if route.points.len() < 2 {
                return refuse(
                    RefusalCode::RouteTooShort,
                    format!(
                        "route: route {} has {} points, at least 2 are needed",
                        route.route_id,
                        route.points.len()
                    ),
                );
            }
            if route.points.iter().any(|p| {
                !(p.x_m.is_finite()
                    && p.y_m.is_finite()
                    && p.yaw_rad.is_finite()
                    && p.lat_deg.is_none_or(|v| v.is_finite() && v.abs() <= 90.0)
                    && p.lon_deg.is_none_or(|v| v.is_finite() && v.abs() <= 180.0)
                    && p.h_m.is_none_or(f64::is_finite))
            }) {
                return refuse(
                    RefusalCode::BadRoutePoints,
                    format!("route: route {} has non-finite points", route.route_id),
                );
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Stamps a sender's commands: one random sender id, a counter that only goes up.
#[derive(Debug)]
pub struct CommandStamper {
    sender: u64,
    seq: AtomicU64,
}

impl CommandStamper {
    /// A stamper for the sender `sender` (random per process, e.g. from the Zenoh session id).
    pub fn new(sender: u64) -> Self {
        Self {
            sender,
            seq: AtomicU64::new(0),
        }
    }

    /// The header of the next command, sent at `now_unix_ms`.
    pub fn next(&self, now_unix_ms: u64) -> CmdHeader {
        CmdHeader {
            sender: self.sender,
            seq: self.seq.fetch_add(1, Ordering::Relaxed) + 1,
            t_unix_ms: now_unix_ms,
        }
    }
}

/// How fresh a command must be when it arrives, against the robot's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReplayWindow {
    /// Older commands are refused, milliseconds. Bounds how long the robot must remember a
    /// sender, and how long a robot restarted after a capture is exposed to its replay.
    pub max_age_ms: u64,
    /// Commands stamped further ahead of the robot's clock are refused, milliseconds (clocks of
    /// station and robot may differ by this much; more means a forged or pre-made command).
    pub max_ahead_ms: u64,
}

impl Default for ReplayWindow {
    fn default() -> Self {
        Self {
            max_age_ms: 30_000,
            max_ahead_ms: 5_000,
        }
    }
}

/// Most senders remembered at once; beyond it the one heard from longest ago is forgotten.
const MAX_SENDERS: usize = 1024;

/// The robot's memory of who sent what: refuses a command whose sequence number its sender has
/// already used, or whose time is outside the [`ReplayWindow`]. Pure: the caller passes the clock.
#[derive(Clone, Debug, Default)]
pub struct ReplayGuard {
    window: ReplayWindow,
    /// Per sender: last accepted sequence number and when it arrived (robot clock, ms).
    senders: BTreeMap<u64, (u64, u64)>,
}

impl ReplayGuard {
    /// A guard with `window`.
    pub fn new(window: ReplayWindow) -> Self {
        Self {
            window,
            senders: BTreeMap::new(),
        }
    }

    /// Accepts (and remembers) `h` arriving at `now_unix_ms`, or refuses it with
    /// [`RefusalCode::Replayed`]. `kind` names the command in the refusal (`goal`, `drive` ...).
    pub fn check(&mut self, kind: &str, h: &CmdHeader, now_unix_ms: u64) -> Result<(), Refusal> {
        let w = self.window;
        if h.t_unix_ms.saturating_add(w.max_age_ms) < now_unix_ms {
            return refuse(
                RefusalCode::Replayed,
                format!(
                    "{kind}: sent {:.1} s ago, more than the {:.0} s a command may take (replayed?)",
                    (now_unix_ms - h.t_unix_ms) as f64 / 1000.0,
                    w.max_age_ms as f64 / 1000.0
                ),
            );
        }
        if h.t_unix_ms > now_unix_ms.saturating_add(w.max_ahead_ms) {
            return refuse(
                RefusalCode::Replayed,
                format!(
                    "{kind}: stamped {:.1} s ahead of the robot's clock (more than {:.0} s: clocks apart, or forged)",
                    (h.t_unix_ms - now_unix_ms) as f64 / 1000.0,
                    w.max_ahead_ms as f64 / 1000.0
                ),
            );
        }
        if let Some(&(last, _)) = self.senders.get(&h.sender) {
            if h.seq <= last {
                return refuse(
                    RefusalCode::Replayed,
                    format!(
                        "{kind}: sequence {} of sender {:016x} already used (last {last}): replayed",
                        h.seq, h.sender
                    ),
                );
            }
        }
        // A sender silent for longer than a command may be old cannot be replayed any more (its
        // commands would be refused by time), so it can be forgotten.
        let horizon = w.max_age_ms.saturating_add(w.max_ahead_ms);
        self.senders
            .retain(|_, &mut (_, seen)| seen.saturating_add(horizon) >= now_unix_ms);
        if self.senders.len() >= MAX_SENDERS && !self.senders.contains_key(&h.sender) {
            if let Some(oldest) = self
                .senders
                .iter()
                .min_by_key(|(_, &(_, seen))| seen)
                .map(|(&k, _)| k)
            {
                self.senders.remove(&oldest);
            }
        }
        self.senders.insert(h.sender, (h.seq, now_unix_ms));
        Ok(())
    }

    /// Senders remembered now.
    pub fn senders(&self) -> usize {
        self.senders.len()
    }
}

/// Checks a goal, in the same map frame as `zones`, against the keep-out zones: a goal inside
/// one is refused with the zone's name (the robot would never be allowed to reach it).
pub fn check_goal_zones(goal_m: (f64, f64), zones: &[crate::msg::Zone]) -> Result<(), Refusal> {
    for z in zones {
        if z.kind == ZoneKind::KeepOut && crate::zone::contains(&z.polygon_m, goal_m) {
            return refuse(
                RefusalCode::GoalInKeepOut,
                format!(
                    "goal: ({:.1}, {:.1}) is inside keep-out zone {:?}",
                    goal_m.0, goal_m.1, z.name
                ),
            );
        }
    }
    Ok(())
}

/// Longest zone name, characters.
pub const MAX_ZONE_NAME: usize = 200;
/// Most corners of one zone polygon.
pub const MAX_ZONE_CORNERS: usize = 1000;
/// Most zones in one set.
pub const MAX_ZONES: usize = 500;

/// Checks a zone set: every polygon has 3 to [`MAX_ZONE_CORNERS`] finite corners, encloses an
/// area and does not cross itself; slow zones have a positive, finite speed.
pub fn check_zones(set: &ZoneSet) -> Result<(), Refusal> {
    if set.zones.len() > MAX_ZONES {
        return refuse(
            RefusalCode::BadZone,
            format!("zones: {} zones, at most {MAX_ZONES}", set.zones.len()),
        );
    }
    for z in &set.zones {
        if z.name.chars().count() > MAX_ZONE_NAME {
            return refuse(
                RefusalCode::BadZone,
                format!(
                    "zones: zone {} has a name longer than {MAX_ZONE_NAME} characters",
                    z.zone_id
                ),
            );
        }
        if let ZoneKind::Slow { speed_mps } = z.kind {
            if !(speed_mps.is_finite() && speed_mps > 0.0) {
                return refuse(
                    RefusalCode::BadZone,
                    format!(
                        "zones: slow zone {:?} needs a positive speed, got {speed_mps} m/s",
                        z.name
                    ),
                );
            }
        }
        crate::zone::check_polygon(&z.polygon_m).map_err(|e| {
            Refusal::new(
                RefusalCode::BadZone,
                format!("zones: zone {:?}: {e}", z.name),
            )
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const VIENNA: (f64, f64) = (48.2082, 16.3738);

    fn gnss(lat: f64, lon: f64) -> GoalCmd {
        GoalCmd {
            goal_id: 1,
            target: GoalTarget::Gnss {
                lat_deg: lat,
                lon_deg: lon,
                h_m: None,
            },
            tolerance_m: 0.0,
        }
    }

    fn map(x: f64, y: f64) -> GoalCmd {
        GoalCmd {
            goal_id: 1,
            target: GoalTarget::Map { x_m: x, y_m: y },
            tolerance_m: 0.0,
        }
    }

    fn code(r: Result<(), Refusal>) -> Option<RefusalCode> {
        r.err().map(|e| e.code)
    }

    #[test]
    fn swapped_lat_lon_is_too_far_and_says_so() {
        let ctx = RobotContext {
            lat_lon_deg: Some(VIENNA),
            ..RobotContext::default()
        };
        let l = CommandLimits::default();
        assert_eq!(code(check_goal(&gnss(48.2085, 16.3741), &l, &ctx)), None);
        let e = check_goal(&gnss(16.3741, 48.2085), &l, &ctx).unwrap_err();
        assert_eq!(e.code, RefusalCode::GoalTooFar);
        assert!(e.message.contains("swapped"), "{e}");
        // Without the robot's position only the ranges can be checked.
        let blind = RobotContext::default();
        assert_eq!(code(check_goal(&gnss(16.3741, 48.2085), &l, &blind)), None);
    }

    #[test]
    fn null_island_and_ranges_are_refused() {
        let l = CommandLimits::default();
        let c = RobotContext::default();
        assert_eq!(
            code(check_goal(&gnss(0.0, 0.0), &l, &c)),
            Some(RefusalCode::NullIsland)
        );
        assert_eq!(
            code(check_goal(&gnss(91.0, 0.0), &l, &c)),
            Some(RefusalCode::LatitudeOutOfRange)
        );
        assert_eq!(
            code(check_goal(&gnss(10.0, f64::NAN), &l, &c)),
            Some(RefusalCode::LongitudeOutOfRange)
        );
        assert_eq!(
            code(check_goal(&map(f64::INFINITY, 0.0), &l, &c)),
            Some(RefusalCode::NotFinite)
        );
        let mut g = map(1.0, 1.0);
        g.tolerance_m = -1.0;
        assert_eq!(
            code(check_goal(&g, &l, &c)),
            Some(RefusalCode::ToleranceOutOfRange)
        );
    }

    #[test]
    fn map_goals_far_from_robot_and_map_are_refused() {
        let l = CommandLimits::default();
        let ctx = RobotContext {
            position_m: Some((0.0, 0.0)),
            mapped: Some(BoundsM {
                min_m: (-50.0, -50.0),
                max_m: (1500.0, 50.0),
            }),
            ..RobotContext::default()
        };
        assert_eq!(code(check_goal(&map(900.0, 0.0), &l, &ctx)), None);
        // Far from the robot but on the mapped stretch: fine (a long drive back).
        assert_eq!(code(check_goal(&map(1400.0, 0.0), &l, &ctx)), None);
        assert_eq!(
            code(check_goal(&map(0.0, 5000.0), &l, &ctx)),
            Some(RefusalCode::GoalOffMap)
        );
    }

    #[test]
    fn zones_are_checked_and_goals_inside_keep_out_refused() {
        use crate::msg::Zone;
        let z = |kind, poly: Vec<(f64, f64)>| Zone {
            zone_id: "z".into(),
            name: "pond".into(),
            kind,
            polygon_m: poly,
        };
        let sq = vec![(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)];
        let ok = ZoneSet {
            version: 1,
            session_id: "s".into(),
            zones: vec![z(ZoneKind::KeepOut, sq.clone())],
        };
        assert_eq!(check_zones(&ok), Ok(()));
        let e = check_goal_zones((1.0, 1.0), &ok.zones).unwrap_err();
        assert_eq!(e.code, RefusalCode::GoalInKeepOut);
        assert!(e.message.contains("pond"), "{e}");
        assert_eq!(check_goal_zones((3.0, 1.0), &ok.zones), Ok(()));
        let slow = ZoneSet {
            zones: vec![z(ZoneKind::Slow { speed_mps: 0.2 }, sq.clone())],
            ..ok.clone()
        };
        assert_eq!(
            check_goal_zones((1.0, 1.0), &slow.zones),
            Ok(()),
            "slow zones take goals"
        );
        for bad in [
            z(ZoneKind::Slow { speed_mps: 0.0 }, sq.clone()),
            z(ZoneKind::KeepOut, vec![(0.0, 0.0), (1.0, 0.0)]),
        ] {
            let set = ZoneSet {
                zones: vec![bad],
                ..ok.clone()
            };
            assert_eq!(check_zones(&set).unwrap_err().code, RefusalCode::BadZone);
        }
        assert_eq!(RefusalCode::GoalInKeepOut.as_str(), "goal_in_keep_out");
    }

    #[test]
    fn codes_are_stable_text() {
        assert_eq!(RefusalCode::GoalTooFar.as_str(), "goal_too_far");
        assert_eq!(
            serde_json::to_string(&RefusalCode::NullIsland).unwrap(),
            "\"null_island\""
        );
        let r = Refusal::new(RefusalCode::NoDatum, "goal: no datum");
        assert_eq!(r.to_string(), "goal: no datum [no_datum]");
    }

    #[test]
    fn replays_are_refused_fresh_commands_pass() {
        let t0 = 1_790_000_000_000;
        let stamper = CommandStamper::new(42);
        let mut g = ReplayGuard::new(ReplayWindow::default());
        let a = stamper.next(t0);
        let b = stamper.next(t0 + 10);
        assert!(g.check("goal", &a, t0 + 5).is_ok());
        // The same command again, from the same or any link: refused.
        let e = g.check("goal", &a, t0 + 6).unwrap_err();
        assert_eq!(e.code, RefusalCode::Replayed);
        assert!(e.message.contains("already used"), "{e}");
        assert!(g.check("goal", &b, t0 + 12).is_ok());
        // An older one after a newer one: refused too.
        assert!(g.check("goal", &a, t0 + 13).is_err());
        // Another sender counts on its own.
        let other = CommandStamper::new(7).next(t0 + 14);
        assert!(g.check("stop", &other, t0 + 15).is_ok());
        // Captured and sent a minute later by a sender the robot has forgotten: refused by time.
        let mut fresh = ReplayGuard::default();
        let e = fresh.check("goal", &a, t0 + 60_000).unwrap_err();
        assert!(e.message.contains("ago"), "{e}");
        // Stamped far in the future (a pre-made command): refused.
        let e = fresh
            .check("goal", &stamper.next(t0 + 60_000), t0)
            .unwrap_err();
        assert!(e.message.contains("ahead"), "{e}");
    }

    #[test]
    fn replay_guard_forgets_silent_senders_and_stays_bounded() {
        let t0 = 1_790_000_000_000;
        let mut g = ReplayGuard::default();
        for s in 0..(MAX_SENDERS as u64 + 10) {
            let h = CmdHeader {
                sender: s,
                seq: 1,
                t_unix_ms: t0,
            };
            assert!(g.check("stop", &h, t0).is_ok());
        }
        assert_eq!(g.senders(), MAX_SENDERS);
        let later = t0 + 40_000;
        let h = CmdHeader {
            sender: 1 << 40,
            seq: 1,
            t_unix_ms: later,
        };
        assert!(g.check("stop", &h, later).is_ok());
        assert_eq!(g.senders(), 1, "silent senders forgotten");
    }

    #[test]
    fn ground_distance_is_right_to_half_a_percent() {
        // One degree of latitude is 111.2 km.
        let d = ground_distance_m((48.0, 16.0), (49.0, 16.0));
        assert!((d - 111_195.0).abs() < 600.0, "{d}");
    }
}

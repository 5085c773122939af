//! Between the wire (`common::msg`) and the agent's own types: the only place that knows both.

use super::Command as WireCommand;
use agent::command::{
    CommandKind, Direction, GoalTarget as AgentTarget, RoutePoint as AgentPoint, TaughtRoute,
};
use agent::localiser::{FixKind, FrameKind};
use agent::mission::{Mode as AgentMode, Phase};
use agent::status::{AgentStatus, PoseEstimate};
use agent::zones::{ZoneRule, ZoneShape};
use common::msg::{
    FixState, GoalTarget, MapFrame, MissionState, Mode, Pose, Route, RouteCmd, RouteDirection,
    RoutePoint, RouteProgress, SlamHealth, Status, ZoneKind, ZoneSet,
};

/// The agent command of a validated wire command; `None` for a refusal (the bus already
/// counted it; hand it to [`agent::Agent::note_refusal`]).
pub fn command_to_agent(cmd: WireCommand) -> Option<CommandKind> {
    Some(match cmd {
        WireCommand::Goal(g) => CommandKind::Goal {
            id: g.goal_id,
            target: match g.target {
                GoalTarget::Map { x_m, y_m } => AgentTarget::Map { x_m, y_m },
                GoalTarget::Gnss {
                    lat_deg,
                    lon_deg,
                    h_m,
                } => AgentTarget::Geodetic {
                    lat_deg,
                    lon_deg,
                    h_m,
                },
            },
            tolerance_m: f64::from(g.tolerance_m),
        },
        WireCommand::Drive(d) => CommandKind::Drive {
            seq: d.seq,
            v_mps: f64::from(d.v_mps),
            omega_rps: f64::from(d.omega_rps),
            deadman: d.deadman,
        },
        WireCommand::Stop(s) => CommandKind::Stop { reason: s.reason },
        WireCommand::Speed(s) => CommandKind::SpeedLimit {
            v_mps: f64::from(s.limit_mps),
        },
        WireCommand::Route(r) => match r {
            RouteCmd::Record { name } => CommandKind::Record { name },
            RouteCmd::StopRecording => CommandKind::StopRecording,
            RouteCmd::Repeat { route, direction } => CommandKind::Repeat {
                route: route_to_agent(&route),
                direction: match direction {
                    RouteDirection::Forward => Direction::Forward,
                    RouteDirection::Reverse => Direction::Reverse,
                },
            },
            RouteCmd::Pause => CommandKind::Pause,
            RouteCmd::Resume => CommandKind::Resume,
            RouteCmd::Cancel => CommandKind::Cancel,
        },
        WireCommand::Zones(set) => zones_to_agent(set),
        WireCommand::Refused(_) => return None,
    })
}

/// A wire zone set as the agent's zones command.
pub fn zones_to_agent(set: ZoneSet) -> CommandKind {
    CommandKind::Zones {
        version: set.version,
        session_id: set.session_id,
        zones: set
            .zones
            .into_iter()
            .map(|z| ZoneShape {
                id: z.zone_id,
                name: z.name,
                rule: match z.kind {
                    ZoneKind::KeepOut => ZoneRule::KeepOut,
                    ZoneKind::Slow { speed_mps } => ZoneRule::Slow(f64::from(speed_mps)),
                },
                polygon_m: z.polygon_m,
            })
            .collect(),
    }
}

/// A wire route as the agent's taught route.
pub fn route_to_agent(r: &Route) -> TaughtRoute {
    TaughtRoute {
        route_id: r.route_id.clone(),
        name: r.name.clone(),
        robot: r.robot.clone(),
        session_id: r.session_id.clone(),
        datum: r.datum,
        points: r
            .points
            .iter()
            .map(|p| AgentPoint {
                x_m: p.x_m,
                y_m: p.y_m,
                lat_deg: p.lat_deg,
                lon_deg: p.lon_deg,
                h_m: p.h_m,
                yaw_rad: f64::from(p.yaw_rad),
                t_unix_ms: p.t_unix_ms,
            })
            .collect(),
    }
}

/// The agent's taught route on the wire.
pub fn route_to_wire(r: &TaughtRoute) -> Route {
    Route {
        route_id: r.route_id.clone(),
        name: r.name.clone(),
        robot: r.robot.clone(),
        session_id: r.session_id.clone(),
        datum: r.datum,
        points: r
            .points
            .iter()
            .map(|p| RoutePoint {
                x_m: p.x_m,
                y_m: p.y_m,
                lat_deg: p.lat_deg,
                lon_deg: p.lon_deg,
                h_m: p.h_m,
                yaw_rad: p.yaw_rad as f32,
                t_unix_ms: p.t_unix_ms,
            })
            .collect(),
    }
}

/// The fix quality on the wire.
pub fn fix_to_wire(f: FixKind) -> FixState {
    match f {
        FixKind::None => FixState::NoFix,
        FixKind::Single => FixState::Single,
        FixKind::Dgps => FixState::Dgps,
        FixKind::RtkFloat => FixState::RtkFloat,
        FixKind::RtkFixed => FixState::RtkFixed,
    }
}

/// The frame kind on the wire.
pub fn frame_to_wire(f: FrameKind) -> MapFrame {
    match f {
        FrameKind::EnuAtDatum => MapFrame::EnuAtDatum,
        FrameKind::FirstPose => MapFrame::FirstPose,
    }
}

/// The pose message of an estimate, stamped `t_unix_ms`, number `seq`.
pub fn pose_to_wire(p: &PoseEstimate, t_unix_ms: u64, seq: u32) -> Pose {
    let (roll, pitch, yaw) = p.pose.iso.rotation.euler_angles();
    let t = p.pose.iso.translation.vector;
    Pose {
        t_unix_ms,
        seq,
        x_m: t.x,
        y_m: t.y,
        z_m: t.z,
        yaw_rad: yaw as f32,
        pitch_rad: pitch as f32,
        roll_rad: roll as f32,
        v_mps: p.v_mps as f32,
        omega_rps: p.omega_rps as f32,
        fix: fix_to_wire(p.fix),
        lat_lon_deg: p.lla.map(|l| (l.0, l.1)),
    }
}

/// What the runtime adds to the agent's status: what only it counts.
#[derive(Clone, Copy, Debug, Default)]
pub struct RuntimeCounters {
    /// Payloads that failed to decode since start.
    pub decode_errors: u32,
    /// Commands refused as replays since start.
    pub commands_replayed: u32,
    /// Collisions (simulator truth) since start.
    pub collisions: u32,
    /// Sweeps per second.
    pub scan_hz: f32,
    /// Plans per second.
    pub plan_hz: f32,
}

/// The status message of the agent's status, stamped `t_unix_ms`.
pub fn status_to_wire(s: &AgentStatus, t_unix_ms: u64, c: RuntimeCounters) -> Status {
    // Teaching is teleop on the wire, with `recording` set.
    let mode = match s.mode {
        AgentMode::Idle => Mode::Idle,
        AgentMode::Goal => Mode::Goal,
        AgentMode::Teleop => Mode::Teleop,
        AgentMode::Teach if s.driving => Mode::Teleop,
        AgentMode::Teach => Mode::Idle,
        AgentMode::Repeat => Mode::Repeat,
    };
    Status {
        t_unix_ms,
        mode,
        mission: phase_to_wire(s.phase),
        reason: s.reason.clone(),
        goal_m: s.goal_m,
        goal_id: s.goal_id,
        fix: fix_to_wire(s.fix),
        gnss_lost: s.gnss_lost,
        slam: SlamHealth {
            ok: s.slam.ok,
            inlier_ratio: s.slam.inlier_ratio as f32,
            iterations: s.slam.iterations.min(u32::from(u16::MAX)) as u16,
            degenerate: s.slam.degenerate,
            failures: s.slam.failures,
        },
        speed_limit_mps: s.speed_limit_mps as f32,
        speed_max_mps: s.speed_max_mps as f32,
        zones_version: s.zones_version,
        zone: s.zone.clone(),
        recording: s.recording,
        route: s.route.as_ref().map(|r| RouteProgress {
            route_id: r.route_id.clone(),
            name: r.name.clone(),
            waypoint: r.waypoint as u32,
            waypoints: r.waypoints as u32,
            distance_left_m: r.distance_left_m as f32,
            detours: r.detours as u32,
        }),
        last_error: s.last_error.clone(),
        commands_refused: s.commands_refused,
        commands_replayed: c.commands_replayed,
        decode_errors: c.decode_errors,
        collisions: c.collisions,
        scan_hz: c.scan_hz,
        plan_hz: c.plan_hz,
    }
}

fn phase_to_wire(p: Phase) -> MissionState {
    match p {
        Phase::Idle => MissionState::Idle,
        Phase::Planning => MissionState::Planning,
        Phase::Driving => MissionState::Driving,
        Phase::Blocked => MissionState::Blocked,
        Phase::NoPath => MissionState::NoPath,
        Phase::Reached => MissionState::Reached,
        Phase::Stopped => MissionState::Stopped,
        Phase::Paused => MissionState::Paused,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::msg::Datum;

    #[test]
    fn routes_round_trip_through_the_agent() {
        let r = Route {
            route_id: "r".into(),
            name: "home".into(),
            robot: "husky-1".into(),
            session_id: "s".into(),
            datum: Some(Datum {
                lat_deg: 48.0,
                lon_deg: 11.0,
                h_m: 500.0,
            }),
            points: vec![RoutePoint {
                x_m: 1.0,
                y_m: -2.0,
                lat_deg: Some(48.0),
                lon_deg: None,
                h_m: Some(3.0),
                yaw_rad: 0.25,
                t_unix_ms: 9,
            }],
        };
        assert_eq!(route_to_wire(&route_to_agent(&r)), r);
    }
}

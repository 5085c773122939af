//! Wire messages of the terranav key space.
//!
//! Every payload is `postcard(SCHEMA_VERSION as varint) ++ postcard(message)`; [`encode`] and
//! [`decode`] are the only way in and out, so a peer on another schema is refused with a typed
//! error instead of being misread. Tile payloads carry the tile codec of [`crate::grid`], which
//! has its own header and version.
//!
//! Units are SI and radians; positions are in the robot's `map` frame (ENU at the session datum
//! when GNSS is available) unless the name says otherwise. Times are Unix milliseconds.

use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// Version of every message layout in this module. Bump on any incompatible change.
///
/// 2: zones (keep-out and slow) travel to the robot as a [`ZoneSet`].
/// 3: commands travel in a [`Cmd`] envelope (sender, sequence, time) so a replay is refused;
/// [`Status::commands_replayed`].
pub const SCHEMA_VERSION: u16 = 3;

/// Why a payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The payload is empty or ends before the schema version.
    #[error("payload too short ({0} bytes)")]
    Truncated(usize),
    /// The sender speaks another schema version.
    #[error("schema version {got}, this build speaks {want}")]
    SchemaMismatch {
        /// Version found in the payload.
        got: u16,
        /// Version this build speaks.
        want: u16,
    },
    /// The bytes are not a valid message of the expected type.
    #[error("undecodable payload: {0}")]
    Malformed(String),
    /// The message decoded but bytes were left over.
    #[error("{0} trailing bytes after the message")]
    TrailingBytes(usize),
}

/// Encodes a message with the schema version in front.
pub fn encode<T: Serialize>(msg: &T) -> Vec<u8> {
    let mut out = postcard::to_allocvec(&SCHEMA_VERSION).expect("u16 always encodes");
    // postcard serialisation into a Vec only fails for unsupported serde types, which our
    // messages do not use; the round-trip tests cover every message.
    out.extend(postcard::to_allocvec(msg).expect("terranav messages always encode"));
    out
}

/// Encodes a command in its envelope (what goes on `terranav/<robot>/cmd/*`).
pub fn encode_cmd<T: Serialize>(header: CmdHeader, cmd: &T) -> Vec<u8> {
    encode(&Cmd { header, cmd })
}

/// Decodes a command envelope from `terranav/<robot>/cmd/*`.
pub fn decode_cmd<T: DeserializeOwned>(bytes: &[u8]) -> Result<(CmdHeader, T), DecodeError> {
    decode::<Cmd<T>>(bytes).map(|c| (c.header, c.cmd))
}

/// Decodes a message, checking the schema version and that nothing is left over.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, DecodeError> {
    let (version, rest): (u16, &[u8]) =
        postcard::take_from_bytes(bytes).map_err(|_| DecodeError::Truncated(bytes.len()))?;
    if version != SCHEMA_VERSION {
        return Err(DecodeError::SchemaMismatch {
            got: version,
            want: SCHEMA_VERSION,
        });
    }
    let (msg, rest): (T, &[u8]) =
        postcard::take_from_bytes(rest).map_err(|e| DecodeError::Malformed(e.to_string()))?;
    if !rest.is_empty() {
        return Err(DecodeError::TrailingBytes(rest.len()));
    }
    Ok(msg)
}

/// A point on Earth, WGS-84 (ellipsoidal height).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Datum {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, metres.
    pub h_m: f64,
}

/// How the robot's `map` frame is anchored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum MapFrame {
    /// ENU at the session datum: GNSS goals work and tiles line up with other robots on the same datum.
    EnuAtDatum,
    /// The first SLAM pose (no GNSS fix or heading at start): GNSS goals are refused.
    FirstPose,
}

/// `terranav/<robot>/session`: one run of the robot agent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// Unique id of the session (robot id + start time, or random).
    pub session_id: String,
    /// The robot this session belongs to.
    pub robot: String,
    /// Session start, Unix milliseconds.
    pub start_unix_ms: u64,
    /// How the map frame is anchored.
    pub frame: MapFrame,
    /// The datum of the map frame, when anchored by GNSS.
    pub datum: Option<Datum>,
    /// Edge length of one grid cell, metres.
    pub cell_size_m: f32,
    /// Cells per tile side.
    pub tile_cells: u16,
    /// `sim:<scenario>` for a simulated robot, `real` otherwise.
    pub source: String,
    /// Version of the robot agent.
    pub agent_version: String,
}

/// GNSS fix state as reported with every pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum FixState {
    /// No receiver or no fix.
    #[default]
    NoFix,
    /// Autonomous (GGA quality 1).
    Single,
    /// Differential (GGA quality 2).
    Dgps,
    /// RTK float (GGA quality 5).
    RtkFloat,
    /// RTK fixed (GGA quality 4).
    RtkFixed,
}

impl FixState {
    /// Maps a GGA fix quality (0-8) to a fix state.
    pub fn from_gga_quality(q: u8) -> Self {
        match q {
            1 => FixState::Single,
            2 | 3 | 9 => FixState::Dgps,
            4 => FixState::RtkFixed,
            5 => FixState::RtkFloat,
            _ => FixState::NoFix,
        }
    }
}

/// `terranav/<robot>/pose`: pose of `base_link` in `map`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Time of the pose, Unix milliseconds.
    pub t_unix_ms: u64,
    /// Sequence number, +1 per published pose.
    pub seq: u32,
    /// Position east / x, metres.
    pub x_m: f64,
    /// Position north / y, metres.
    pub y_m: f64,
    /// Height, metres.
    pub z_m: f64,
    /// Heading (counter-clockwise from x/east), radians.
    pub yaw_rad: f32,
    /// Pitch, radians.
    pub pitch_rad: f32,
    /// Roll, radians.
    pub roll_rad: f32,
    /// Forward speed, m/s.
    pub v_mps: f32,
    /// Turn rate, rad/s.
    pub omega_rps: f32,
    /// GNSS fix state.
    pub fix: FixState,
    /// Latitude and longitude of the pose through the datum, degrees, when the map is anchored.
    pub lat_lon_deg: Option<(f64, f64)>,
}

/// `terranav/<robot>/path`: the path being followed, map frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct Path {
    /// Time of planning, Unix milliseconds.
    pub t_unix_ms: u64,
    /// Id of the goal or route this path serves.
    pub goal_id: u32,
    /// Way points (x, y), metres; empty when there is no path.
    pub points_m: Vec<(f32, f32)>,
}

/// What the robot is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Mode {
    /// Waiting for a command.
    #[default]
    Idle,
    /// Going to a goal.
    Goal,
    /// Driven by the operator.
    Teleop,
    /// Following a recorded route.
    Repeat,
}

/// State of the current mission.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum MissionState {
    /// No mission.
    #[default]
    Idle,
    /// Computing a path.
    Planning,
    /// Following the path.
    Driving,
    /// Stopped by the safety stop or a blocked path; will go on when clear.
    Blocked,
    /// No path exists to the goal.
    NoPath,
    /// Goal reached.
    Reached,
    /// Stopped by the operator.
    Stopped,
    /// Paused by the operator (route repeat).
    Paused,
}

/// Teach-and-repeat progress.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RouteProgress {
    /// Route id.
    pub route_id: String,
    /// Route name, as the operator gave it.
    pub name: String,
    /// Index of the next waypoint (0-based).
    pub waypoint: u32,
    /// Number of waypoints.
    pub waypoints: u32,
    /// Distance left along the route, metres.
    pub distance_left_m: f32,
    /// Detours spliced in so far.
    pub detours: u32,
}

/// SLAM health.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct SlamHealth {
    /// False when the last scan fell back to the prior.
    pub ok: bool,
    /// Inlier ratio of the last registration, 0-1.
    pub inlier_ratio: f32,
    /// ICP iterations of the last registration.
    pub iterations: u16,
    /// Geometry degenerate in some direction.
    pub degenerate: bool,
    /// Scans that fell back to the prior since start.
    pub failures: u32,
}

/// `terranav/<robot>/status`: mission state and health, published at about 2 Hz and on change.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct Status {
    /// Time, Unix milliseconds.
    pub t_unix_ms: u64,
    /// Mode.
    pub mode: Mode,
    /// Mission state.
    pub mission: MissionState,
    /// Why the mission is in its state (human readable), e.g. "goal is beyond a drop-off".
    pub reason: String,
    /// Current goal in the map frame, metres.
    pub goal_m: Option<(f64, f64)>,
    /// Id of the current goal.
    pub goal_id: u32,
    /// GNSS fix state.
    pub fix: FixState,
    /// True when navigating on SLAM/odometry only because GNSS was lost.
    pub gnss_lost: bool,
    /// SLAM health.
    pub slam: SlamHealth,
    /// Speed limit in force, m/s.
    pub speed_limit_mps: f32,
    /// The robot's own top speed (what no speed limit can exceed), m/s.
    pub speed_max_mps: f32,
    /// Version of the zone set in force ([`ZoneSet::version`]; 0: none received).
    pub zones_version: u64,
    /// The zone acting on the robot now, for humans, e.g. "slow zone gate: 0.20 m/s".
    pub zone: Option<String>,
    /// True while a route is being recorded.
    pub recording: bool,
    /// Route progress while repeating.
    pub route: Option<RouteProgress>,
    /// Last command refused, with the reason, e.g. "goal: GNSS goal refused: map frame has no datum".
    pub last_error: Option<String>,
    /// Commands refused since start.
    pub commands_refused: u32,
    /// Of those, commands refused as replays (a sequence number already seen, or sent too long
    /// ago / too far ahead of the robot's clock) since start.
    pub commands_replayed: u32,
    /// Payloads that failed to decode since start.
    pub decode_errors: u32,
    /// Collisions (simulator truth) since start.
    pub collisions: u32,
    /// Scans processed per second.
    pub scan_hz: f32,
    /// Plans per second.
    pub plan_hz: f32,
}

/// What every command carries besides its content, so that a command captured and sent again
/// later is refused (`common::command::ReplayGuard`), whatever link it comes over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CmdHeader {
    /// Random id of the sending process (a station, a CLI call): each sender counts on its own.
    pub sender: u64,
    /// The sender's command counter: +1 per command, never repeated.
    pub seq: u64,
    /// When it was sent, Unix milliseconds, on the sender's clock.
    pub t_unix_ms: u64,
}

/// `terranav/<robot>/cmd/*`: a command with its [`CmdHeader`] ([`encode_cmd`], [`decode_cmd`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cmd<T> {
    /// Sender, sequence, time.
    pub header: CmdHeader,
    /// The command itself ([`GoalCmd`], [`RouteCmd`], [`DriveCmd`], [`StopCmd`], [`SpeedCmd`]).
    pub cmd: T,
}

/// Where a goal is.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum GoalTarget {
    /// In the robot's map frame, metres.
    Map {
        /// x (east), metres.
        x_m: f64,
        /// y (north), metres.
        y_m: f64,
    },
    /// WGS-84; converted through the datum.
    Gnss {
        /// Latitude, degrees.
        lat_deg: f64,
        /// Longitude, degrees.
        lon_deg: f64,
        /// Ellipsoidal height, metres; the robot's height when absent.
        h_m: Option<f64>,
    },
}

/// `terranav/<robot>/cmd/goal`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GoalCmd {
    /// Id chosen by the sender, echoed in status and path.
    pub goal_id: u32,
    /// Target.
    pub target: GoalTarget,
    /// Distance at which the goal counts as reached, metres (0 = robot default).
    pub tolerance_m: f32,
}

/// Direction of a route repeat.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RouteDirection {
    /// Back to where recording started (return home).
    Reverse,
    /// Again from start to end.
    Forward,
}

/// One recorded route point.
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
    /// Heading when recorded, radians.
    pub yaw_rad: f32,
    /// Time recorded, Unix milliseconds.
    pub t_unix_ms: u64,
}

/// A taught route.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Route {
    /// Route id.
    pub route_id: String,
    /// Name given by the operator.
    pub name: String,
    /// Robot that recorded it.
    pub robot: String,
    /// Session it was recorded in.
    pub session_id: String,
    /// Datum of the map frame of `points` (None: SLAM-only frame).
    pub datum: Option<Datum>,
    /// The waypoints in driving order.
    pub points: Vec<RoutePoint>,
}

/// `terranav/<robot>/cmd/route`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum RouteCmd {
    /// Start recording a route.
    Record {
        /// Name for the route.
        name: String,
    },
    /// Stop recording; the robot publishes the route on `terranav/<robot>/route`.
    StopRecording,
    /// Follow a route.
    Repeat {
        /// The route (sent whole so the robot needs no store).
        route: Route,
        /// Direction.
        direction: RouteDirection,
    },
    /// Pause a repeat.
    Pause,
    /// Resume a paused repeat.
    Resume,
    /// Cancel a repeat.
    Cancel,
}

/// `terranav/<robot>/cmd/drive`: teleop. Silence longer than the deadman timeout stops the robot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriveCmd {
    /// Sequence number, increasing; older ones are ignored.
    pub seq: u32,
    /// Forward speed, m/s.
    pub v_mps: f32,
    /// Turn rate, rad/s.
    pub omega_rps: f32,
    /// The operator holds the deadman: false means stop.
    pub deadman: bool,
}

/// `terranav/<robot>/cmd/stop`: stop now and cancel the mission.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct StopCmd {
    /// Why, for the log.
    pub reason: String,
}

/// `terranav/<robot>/cmd/speed`: speed limit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpeedCmd {
    /// Maximum forward speed, m/s (clamped to the robot's own limit).
    pub limit_mps: f32,
}

/// What a zone does to robots.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ZoneKind {
    /// Never planned through; a goal inside is refused; a robot inside leaves by the shortest way.
    KeepOut,
    /// Speed capped while the robot is in (or about to enter) the zone.
    Slow {
        /// Speed cap, m/s.
        speed_mps: f32,
    },
}

/// One zone: a simple polygon in the map frame of its [`ZoneSet`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Zone {
    /// Id chosen by the station.
    pub zone_id: String,
    /// Name given by the operator.
    pub name: String,
    /// What it does.
    pub kind: ZoneKind,
    /// Polygon corners (x, y), metres, in order, not closed (the last joins the first).
    pub polygon_m: Vec<(f64, f64)>,
}

/// `terranav/<robot>/zones`: every zone the robot must obey, in its own map frame. The station
/// publishes it when zones change and when the robot's session appears, and answers queries on
/// the key (late joiners). A new set replaces the old one whole.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub struct ZoneSet {
    /// Increases with every change at the station.
    pub version: u64,
    /// Session whose map frame the polygons are in (a robot refuses a set for another session).
    pub session_id: String,
    /// The zones.
    pub zones: Vec<Zone>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rt<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(m: T) {
        let b = encode(&m);
        assert_eq!(decode::<T>(&b).unwrap(), m);
    }

    fn route() -> Route {
        Route {
            route_id: "r1".into(),
            name: "home".into(),
            robot: "husky-1".into(),
            session_id: "s".into(),
            datum: Some(Datum {
                lat_deg: 48.1,
                lon_deg: 11.5,
                h_m: 500.0,
            }),
            points: vec![RoutePoint {
                x_m: 1.0,
                y_m: 2.0,
                lat_deg: Some(48.1),
                lon_deg: Some(11.5),
                h_m: None,
                yaw_rad: 0.5,
                t_unix_ms: 7,
            }],
        }
    }

    #[test]
    fn fixed_messages_round_trip() {
        rt(Session {
            session_id: "husky-1-1".into(),
            robot: "husky-1".into(),
            start_unix_ms: 1_700_000_000_000,
            frame: MapFrame::EnuAtDatum,
            datum: Some(Datum {
                lat_deg: 48.1,
                lon_deg: 11.5,
                h_m: 500.0,
            }),
            cell_size_m: 0.2,
            tile_cells: 64,
            source: "sim:park".into(),
            agent_version: "0.1.0".into(),
        });
        rt(Status::default());
        rt(Path {
            t_unix_ms: 1,
            goal_id: 2,
            points_m: vec![(1.0, 2.0), (3.0, 4.5)],
        });
        rt(GoalCmd {
            goal_id: 3,
            target: GoalTarget::Gnss {
                lat_deg: 1.0,
                lon_deg: 2.0,
                h_m: None,
            },
            tolerance_m: 0.0,
        });
        rt(RouteCmd::Repeat {
            route: route(),
            direction: RouteDirection::Reverse,
        });
        rt(RouteCmd::Record { name: "x".into() });
        rt(StopCmd {
            reason: "operator".into(),
        });
        rt(SpeedCmd { limit_mps: 0.3 });
        rt(route());
        rt(ZoneSet {
            version: 3,
            session_id: "s".into(),
            zones: vec![
                Zone {
                    zone_id: "z1".into(),
                    name: "pond".into(),
                    kind: ZoneKind::KeepOut,
                    polygon_m: vec![(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)],
                },
                Zone {
                    zone_id: "z2".into(),
                    name: "gate".into(),
                    kind: ZoneKind::Slow { speed_mps: 0.2 },
                    polygon_m: vec![(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)],
                },
            ],
        });
    }

    #[test]
    fn commands_travel_in_their_envelope() {
        let h = CmdHeader {
            sender: 0xfeed,
            seq: 7,
            t_unix_ms: 1_790_000_000_000,
        };
        let b = encode_cmd(h, &SpeedCmd { limit_mps: 0.4 });
        assert_eq!(
            decode_cmd::<SpeedCmd>(&b).unwrap(),
            (h, SpeedCmd { limit_mps: 0.4 })
        );
        // A bare command (schema 1 style, no header) is not a command any more.
        assert!(decode_cmd::<SpeedCmd>(&encode(&SpeedCmd { limit_mps: 0.4 })).is_err());
        let s = Status {
            commands_replayed: 3,
            ..Status::default()
        };
        assert_eq!(decode::<Status>(&encode(&s)).unwrap().commands_replayed, 3);
    }

    #[test]
    fn wrong_schema_and_garbage_are_typed_errors() {
        let mut b = encode(&StopCmd::default());
        b[0] = 9;
        assert!(matches!(
            decode::<StopCmd>(&b),
            Err(DecodeError::SchemaMismatch { got: 9, .. })
        ));
        assert!(matches!(
            decode::<StopCmd>(&[]),
            Err(DecodeError::Truncated(0))
        ));
        let mut b = encode(&SpeedCmd { limit_mps: 1.0 });
        b.push(0);
        assert!(matches!(
            decode::<SpeedCmd>(&b),
            Err(DecodeError::TrailingBytes(1))
        ));
        let b = encode(&SpeedCmd { limit_mps: 1.0 });
        assert!(matches!(decode::<Pose>(&b), Err(DecodeError::Malformed(_))));
    }

    proptest! {
        #[test]
        fn pose_round_trips(x in -1e6f64..1e6, y in -1e6f64..1e6, z in -1e3f64..1e4, yaw in -4f32..4.0,
                            seq in any::<u32>(), t in any::<u64>(), q in 0u8..10, ll in proptest::option::of((-90f64..90.0, -180f64..180.0))) {
            rt(Pose { t_unix_ms: t, seq, x_m: x, y_m: y, z_m: z, yaw_rad: yaw, pitch_rad: -yaw, roll_rad: yaw / 2.0,
                      v_mps: 0.5, omega_rps: -0.1, fix: FixState::from_gga_quality(q), lat_lon_deg: ll });
        }

        #[test]
        fn drive_round_trips(seq in any::<u32>(), v in -2f32..2.0, w in -1f32..1.0, d in any::<bool>()) {
            rt(DriveCmd { seq, v_mps: v, omega_rps: w, deadman: d });
        }

        #[test]
        fn goal_round_trips(id in any::<u32>(), x in -1e5f64..1e5, y in -1e5f64..1e5, gnss in any::<bool>()) {
            let target = if gnss { GoalTarget::Gnss { lat_deg: x / 1e4, lon_deg: y / 1e4, h_m: Some(x) } } else { GoalTarget::Map { x_m: x, y_m: y } };
            rt(GoalCmd { goal_id: id, target, tolerance_m: 0.5 });
        }

        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode::<Pose>(&bytes);
            let _ = decode::<Status>(&bytes);
            let _ = decode::<Session>(&bytes);
            let _ = decode::<GoalCmd>(&bytes);
            let _ = decode::<RouteCmd>(&bytes);
            let _ = decode::<Route>(&bytes);
            let _ = decode::<Path>(&bytes);
            let _ = decode_cmd::<GoalCmd>(&bytes);
            let _ = decode_cmd::<DriveCmd>(&bytes);
            let _ = decode::<ZoneSet>(&bytes);
        }
    }
}

//! The agent's command handling: goals placed in the map frame, teleop, teaching and repeats,
//! zone sets; refusals counted and shown (split from `agent.rs`, no behaviour of its own).

use super::{Agent, TEACH_VIEWS_KEPT};
use crate::command::{refusal, Command, CommandKind, Direction, GoalTarget, TaughtRoute};
use crate::driver::Teleop;
use crate::localiser::gnss::GnssGoal;
use crate::mission::navigate::Goal;
use crate::mission::repeat::RouteFollower;
use crate::mission::teach::RouteRecorder;
use crate::mission::{Event, Outcome, Repeat};
use crate::zones::ZoneMap;
use common::command::{Refusal, RefusalCode};
use common::msg::Datum;

impl Agent {
    // ---- commands ----

    /// One command; a refusal is counted, shown in the status and logged here (once).
    pub fn on_command(&mut self, cmd: Command) -> Result<(), Refusal> {
        let kind = cmd.kind.name();
        let r = self.command(cmd);
        match &r {
            Err(e) => self.count_refusal(e),
            // A refusal of this kind of command is history once one is accepted: an operator
            // whose next goal was taken must not keep reading that the last one was refused.
            Ok(()) => {
                if self
                    .last_error
                    .as_deref()
                    .is_some_and(|e| e.starts_with(&format!("{kind}:")))
                {
                    self.last_error = None;
                }
            }
        }
        r
    }

    /// A refusal made before the command reached the agent (the bus's checks): shown in the
    /// status. `counted`: the bus counted it already.
    pub fn note_refusal(&mut self, r: &Refusal) {
        self.count_refusal(r);
    }

    fn count_refusal(&mut self, r: &Refusal) {
        self.commands_refused += 1;
        self.last_error = Some(r.to_string());
        tracing::warn!("refused: {r}");
    }

    fn command(&mut self, cmd: Command) -> Result<(), Refusal> {
        let t_s = cmd.t_s;
        let kind_name = cmd.kind.name();
        let event = match cmd.kind {
            CommandKind::Goal {
                id,
                target,
                tolerance_m,
            } => Event::Goal(self.place_goal(t_s, id, target, tolerance_m)?),
            CommandKind::Drive {
                seq,
                v_mps,
                omega_rps,
                deadman,
            } => Event::Drive(Teleop {
                t_s,
                seq,
                v_mps,
                omega_rps,
                deadman,
            }),
            CommandKind::Stop { reason } => Event::Stop(reason),
            CommandKind::SpeedLimit { v_mps } => {
                self.driver.set_speed_limit(v_mps);
                return Ok(());
            }
            CommandKind::Record { name } => {
                let mut rec = RouteRecorder::new(self.cfg.teach.clone(), name);
                if let Some(p) = self.localiser.pose_now() {
                    rec.offer(p.planar, self.localiser.lla_of(&p), self.unix_ms(t_s));
                }
                Event::Record(rec)
            }
            CommandKind::StopRecording => Event::StopRecording,
            CommandKind::Repeat { route, direction } => {
                Event::Repeat(Box::new(self.start_repeat(&route, direction)?))
            }
            CommandKind::Pause => Event::Pause,
            CommandKind::Resume => Event::Resume,
            CommandKind::Cancel => Event::Cancel,
            CommandKind::Zones {
                version,
                session_id,
                zones,
            } => {
                if session_id != self.id.session_id {
                    return Err(refusal(
                        RefusalCode::ZoneFrameMismatch,
                        "zones",
                        format!(
                            "zone set {version} is for session {session_id}, this is {}",
                            self.id.session_id
                        ),
                    ));
                }
                if version < self.zones.version {
                    // Only a station may send zones (the access rules), but an old set captured
                    // and sent again must not lift keep-out zones drawn since.
                    return Err(refusal(
                        RefusalCode::Replayed,
                        "zones",
                        format!(
                            "zone set {version} is older than the set {} in force",
                            self.zones.version
                        ),
                    ));
                }
                tracing::info!("zones: set {version}, {} zones", zones.len());
                self.zones = ZoneMap { version, zones };
                // The path in hand may cross a new keep-out zone: check it with the next sweep.
                self.path_dirty = true;
                return Ok(());
            }
        };
        match self.mission.transition(event) {
            Ok(Outcome::Done) => Ok(()),
            Ok(Outcome::Recorded(rec)) => {
                self.finish_teaching(t_s, rec);
                Ok(())
            }
            Err(e) => {
                debug_assert!(e.message.starts_with(kind_name), "{e}");
                Err(e)
            }
        }
    }

    /// A goal in the map frame: as given, or through the datum for lat/lon.
    fn place_goal(
        &self,
        t_s: f64,
        id: u32,
        target: GoalTarget,
        tolerance_m: f64,
    ) -> Result<Goal, Refusal> {
        let pose = self
            .localiser
            .pose_now()
            .map(|p| p.planar)
            .unwrap_or_default();
        let (goal_map, gnss) = match target {
            GoalTarget::Map { x_m, y_m } => ((x_m, y_m), None),
            GoalTarget::Geodetic {
                lat_deg,
                lon_deg,
                h_m,
            } => {
                let fix = self.localiser.fix(t_s);
                let g = GnssGoal::new(
                    lat_deg,
                    lon_deg,
                    h_m,
                    self.localiser.local_frame(),
                    (pose.x_m, pose.y_m),
                    fix.as_ref(),
                )
                .map_err(|e| {
                    let code = match e {
                        crate::localiser::gnss::GnssGoalError::NoDatum => RefusalCode::NoDatum,
                        _ => RefusalCode::LatitudeOutOfRange,
                    };
                    refusal(code, "goal", e)
                })?;
                (g.goal_map, Some(g))
            }
        };
        self.zones.check_goal(goal_map)?;
        Ok(Goal {
            id,
            goal_map,
            tolerance_m,
            gnss,
        })
    }

    /// Sets up a repeat of `route` in this session's map frame.
    fn start_repeat(&self, route: &TaughtRoute, direction: Direction) -> Result<Repeat, Refusal> {
        if route.points.len() < 2 {
            return Err(refusal(
                RefusalCode::RouteTooShort,
                "route",
                "fewer than 2 waypoints",
            ));
        }
        let pts = self.route_in_map(route)?;
        let ordered: Vec<(f64, f64)> = match direction {
            Direction::Forward => pts,
            Direction::Reverse => pts.into_iter().rev().collect(),
        };
        let pose = self
            .localiser
            .pose_now()
            .map(|p| p.planar)
            .unwrap_or_default();
        let view = self
            .teach_views
            .iter()
            .find(|(id, _)| *id == route.route_id && route.session_id == self.id.session_id)
            .map(|(_, v)| v.clone());
        Ok(Repeat {
            follower: RouteFollower::new(self.cfg.repeat.clone(), &ordered, &pose),
            route_id: route.route_id.clone(),
            name: route.name.clone(),
            paused: false,
            last: None,
            view,
        })
    }

    /// The route's waypoints in this session's map frame: through lat/lon when both have a
    /// datum, as taught when the route was taught in this session's frame.
    fn route_in_map(&self, route: &TaughtRoute) -> Result<Vec<(f64, f64)>, Refusal> {
        let local = self.localiser.local_frame().copied();
        let same_session = route.session_id == self.id.session_id;
        let all_geodetic = route
            .points
            .iter()
            .all(|p| p.lat_deg.is_some() && p.lon_deg.is_some());
        match (local, all_geodetic) {
            (Some(l), true) if !same_session || route.datum != Some(l.datum()) => Ok(route
                .points
                .iter()
                .map(|p| {
                    let e = l.lla_to_enu(&Datum {
                        lat_deg: p.lat_deg.unwrap_or_default(),
                        lon_deg: p.lon_deg.unwrap_or_default(),
                        h_m: p.h_m.unwrap_or(l.datum().h_m),
                    });
                    (e.x, e.y)
                })
                .collect()),
            _ if same_session || route.datum.is_none() => {
                Ok(route.points.iter().map(|p| (p.x_m, p.y_m)).collect())
            }
            _ => Err(refusal(
                RefusalCode::RouteFrameMismatch,
                "route",
                "taught in another frame and this session has no datum",
            )),
        }
    }

    /// Ends teaching: the route and its teach-time view.
    fn finish_teaching(&mut self, t_s: f64, rec: RouteRecorder) {
        let now = self.localiser.pose_now();
        let pose = now.map(|p| p.planar).unwrap_or_default();
        let lla = now.and_then(|p| self.localiser.lla_of(&p));
        let name = rec.name().to_string();
        let points = rec.finish(pose, lla, self.unix_ms(t_s));
        let route_id = format!("{}-{}", self.id.session_id, self.unix_ms(t_s));
        let line: Vec<(f64, f64)> = points.iter().map(|p| (p.x_m, p.y_m)).collect();
        let view = self.terrain.capture_teach_view(&line);
        tracing::info!(
            "teach: route {route_id}, {} waypoints, {} cells of teach-time traversability kept",
            points.len(),
            view.len()
        );
        if self.teach_views.len() >= TEACH_VIEWS_KEPT {
            self.teach_views.remove(0);
        }
        self.teach_views.push((route_id.clone(), view));
        self.taught = Some(TaughtRoute {
            route_id,
            name,
            robot: self.id.robot.clone(),
            session_id: self.id.session_id.clone(),
            datum: self.localiser.frame().and_then(|f| f.1),
            points,
        });
    }

    /// The route taught last, once, after teaching ended.
    pub fn take_taught_route(&mut self) -> Option<TaughtRoute> {
        self.taught.take()
    }
}

//! What a base that follows waypoints by itself (a navigation computer) is to drive: the route of
//! the mission in force, as latitude/longitude through the map frame's datum, where the agent is
//! along it, and the speed. Read from the agent each control period; no I/O, no clock.
//!
//! A repeat's route is the follower's waypoints (taught points with the detours spliced in, in
//! driving order); a goal's is its planned path. Teleop and idle give no route: such a base then
//! holds the robot (a navigation computer cannot be steered by velocities).

use agent::mission::Mode;
use agent::Agent;
use nalgebra::Vector3;

/// The route a navigation computer is to follow now.
#[derive(Clone, Debug, PartialEq)]
pub struct RouteOrder {
    /// Session time, seconds.
    pub t_s: f64,
    /// Names the mission; a new name is a new route, to be followed from the agent's next
    /// waypoint (`repeat:ROUTE#N`, `goal:ID#N`, N counting the missions of this run).
    pub mission: String,
    /// Every waypoint of the mission's route in driving order, (latitude, longitude) degrees.
    pub waypoints_deg: Vec<(f64, f64)>,
    /// Index in `waypoints_deg` of the waypoint the agent is heading for.
    pub next: usize,
    /// Speed limit, percent of the controller's maximum speed; 0 holds the robot.
    pub speed_pct: u8,
    /// Why the robot is held (`speed_pct` 0), for logs and reports.
    pub hold: Option<&'static str>,
}

/// Follows the agent's missions from one control period to the next, to tell a new mission from
/// the same one with a changed route.
#[derive(Debug, Default)]
pub struct RouteWatch {
    mission: Option<String>,
    missions: u32,
    warned_no_datum: bool,
}

impl RouteWatch {
    /// The route order at session time `t_s`; `base_stopped`: a sensor fault stops the base.
    /// `None` when no mission with a route is in force, or the map frame has no datum yet (a
    /// navigation computer works in latitude/longitude; logged once).
    pub fn order(&mut self, agent: &Agent, t_s: f64, base_stopped: bool) -> Option<RouteOrder> {
        let Some((key, map_points, next, mission_hold)) = mission_route(agent) else {
            self.mission = None;
            return None;
        };
        if self.mission.as_deref() != Some(key.as_str()) {
            self.missions += 1;
            self.mission = Some(key.clone());
        }
        let Some(frame) = agent.localiser().local_frame() else {
            if !self.warned_no_datum {
                tracing::warn!(
                    "{key}: the map frame has no datum, so the navigation computer gets no \
                     waypoints (it works in latitude/longitude): give --datum or an RTK GNSS"
                );
                self.warned_no_datum = true;
            }
            return None;
        };
        let waypoints_deg = map_points
            .iter()
            .map(|(x, y)| {
                let d = frame.enu_to_lla(&Vector3::new(*x, *y, 0.0));
                (d.lat_deg, d.lon_deg)
            })
            .collect();
        let hold = if base_stopped {
            Some("a sensor fault stops the base")
        } else if agent.driver().stop_ahead(t_s) {
            Some("safety stop")
        } else {
            mission_hold
        };
        let v_max = agent.config().control.v_max_mps;
        let speed_pct = match hold {
            Some(_) => 0,
            None if v_max > 0.0 => {
                (100.0 * agent.driver().speed_limit_mps() / v_max).clamp(0.0, 100.0) as u8
            }
            None => 0,
        };
        Some(RouteOrder {
            t_s,
            mission: format!("{key}#{}", self.missions),
            waypoints_deg,
            next,
            speed_pct,
            hold,
        })
    }
}

/// The mission's name, route (map frame), next waypoint and hold reason, if it has a route.
type MissionRoute = (String, Vec<(f64, f64)>, usize, Option<&'static str>);

fn mission_route(agent: &Agent) -> Option<MissionRoute> {
    match agent.mode() {
        Mode::Repeat => {
            let r = agent.mission().repeat()?;
            let pose = agent.localiser().pose_now()?.planar;
            let (next, _, _) = r.follower.progress(&pose);
            let points = r.follower.waypoints().iter().map(|w| w.p).collect();
            let hold = if r.paused {
                Some("repeat paused")
            } else if r.follower.holding() {
                Some("the route ahead is blocked")
            } else {
                None
            };
            let key = format!("repeat:{}:{}", r.route_id, r.follower.taught_len());
            Some((key, points, next, hold))
        }
        Mode::Goal => {
            let nav = agent.mission().nav();
            let goal = nav.goal()?;
            let path = nav.path();
            if path.len() < 2 {
                return None;
            }
            let hold = (!nav.is_driving()).then_some("the goal is blocked or being planned");
            Some((format!("goal:{}", goal.id), path.to_vec(), 0, hold))
        }
        Mode::Idle | Mode::Teleop | Mode::Teach => None,
    }
}

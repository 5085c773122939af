//! Runs one mission on one robot: sends each waypoint as a goal, watches the robot's status
//! for that goal being reached (the status carries the id of the goal it last worked on),
//! does the waypoint's actions (speed limit, wait, pause for the operator), then sends the
//! next. Fails, with the reason, when the robot refuses a waypoint, finds no path to it, is
//! stopped by the operator or given another goal.
//!
//! Pure: [`Run::step`] takes the time and what the station knows of the robot, and returns the
//! commands to send. The station's loop does the sending. A station that goes away leaves the
//! robot finishing its current leg and waiting there; the run goes on when the station is back
//! only if the station kept running (runs live in its memory).

use common::msg::{GoalTarget, MissionState, Pose, Status};
use serde::Serialize;

use super::{Mission, MissionFrame};

/// "No path" that lasts this long fails the run, seconds (the robot itself gives up after 10).
pub const NO_PATH_FAIL_S: f64 = 12.0;
/// A waypoint goal the robot has not taken up after this long is sent again, seconds.
pub const RESEND_AFTER_S: f64 = 5.0;
/// Tolerance of waypoint goals, metres.
pub const WAYPOINT_TOLERANCE_M: f32 = 0.4;

/// Where the run is.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum RunPhase {
    /// The first goal goes out with the next step.
    Starting,
    /// Driving to waypoint `index`.
    Going {
        /// The goal id sent.
        goal_id: u32,
        /// When sent, Unix ms.
        sent_unix_ms: u64,
        /// The robot's status has shown this goal.
        taken: bool,
        /// Since when the robot reports no path, Unix ms.
        no_path_since: Option<u64>,
    },
    /// Waiting at a waypoint until this time.
    Waiting {
        /// Unix ms.
        until_unix_ms: u64,
    },
    /// Waiting for the operator to continue.
    Paused,
    /// Every waypoint visited.
    Finished,
    /// Failed, with the reason.
    Failed {
        /// Why.
        reason: String,
    },
    /// Cancelled by the operator.
    Cancelled,
}

/// A command the run wants sent.
#[derive(Clone, Debug, PartialEq)]
pub enum RunAction {
    /// A goal.
    Goal {
        /// Id.
        goal_id: u32,
        /// Where.
        target: GoalTarget,
    },
    /// A speed limit.
    Speed(f32),
    /// Stop the robot.
    Stop,
}

/// How to send waypoints to this robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SendAs {
    /// The mission's own map x/y (the robot is on the mission's datum).
    MapXy,
    /// Lat/lon (a GNSS mission, or a robot on another datum).
    Gnss,
}

/// One mission running on one robot.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    /// The robot.
    pub robot: String,
    /// The mission.
    pub mission: Mission,
    /// The waypoint being driven to (or acted at).
    pub index: usize,
    /// Where the run is.
    pub phase: RunPhase,
    /// Started, Unix ms.
    pub started_unix_ms: u64,
    /// Ended, Unix ms.
    pub ended_unix_ms: Option<u64>,
    /// When each waypoint was reached, Unix ms.
    pub reached_unix_ms: Vec<Option<u64>>,
    /// Distance left along the waypoints, metres (from the last pose).
    pub distance_left_m: f64,
    /// Estimated time to the end, seconds.
    pub eta_s: Option<f64>,
    #[serde(skip)]
    send_as: SendAs,
}

/// What the station knows of the robot now.
#[derive(Clone, Copy, Debug)]
pub struct RobotNow<'a> {
    /// Online.
    pub online: bool,
    /// Last status.
    pub status: Option<&'a Status>,
    /// Last pose (in the mission's frame when `SendAs::MapXy`).
    pub pose: Option<&'a Pose>,
}

impl Run {
    /// A run of `mission` on `robot`, sending waypoints as `send_as`; the first goal goes out
    /// with the first [`Run::step`].
    pub fn new(robot: &str, mission: Mission, send_as: SendAs, now_ms: u64) -> Self {
        let n = mission.waypoints.len();
        Self {
            robot: robot.to_string(),
            index: 0,
            phase: RunPhase::Starting,
            started_unix_ms: now_ms,
            ended_unix_ms: None,
            reached_unix_ms: vec![None; n],
            distance_left_m: mission.length_m(),
            eta_s: None,
            mission,
            send_as,
        }
    }

    /// Whether the run has ended.
    pub fn ended(&self) -> bool {
        matches!(
            self.phase,
            RunPhase::Finished | RunPhase::Failed { .. } | RunPhase::Cancelled
        )
    }

    fn target(&self, i: usize) -> GoalTarget {
        let w = &self.mission.waypoints[i];
        match (self.send_as, self.mission.frame, w.lat_deg, w.lon_deg) {
            (SendAs::Gnss, _, Some(lat), Some(lon))
            | (_, MissionFrame::Gnss, Some(lat), Some(lon)) => GoalTarget::Gnss {
                lat_deg: lat,
                lon_deg: lon,
                h_m: None,
            },
            _ => GoalTarget::Map {
                x_m: w.x_m,
                y_m: w.y_m,
            },
        }
    }

    fn send(&mut self, now_ms: u64, next_id: &mut dyn FnMut() -> u32) -> RunAction {
        let goal_id = next_id();
        self.phase = RunPhase::Going {
            goal_id,
            sent_unix_ms: now_ms,
            taken: false,
            no_path_since: None,
        };
        RunAction::Goal {
            goal_id,
            target: self.target(self.index),
        }
    }

    fn fail(&mut self, reason: String, now_ms: u64) {
        self.phase = RunPhase::Failed { reason };
        self.ended_unix_ms = Some(now_ms);
    }

    /// Moves on to the next waypoint (or finishes).
    fn next(&mut self, now_ms: u64, next_id: &mut dyn FnMut() -> u32) -> Vec<RunAction> {
        self.index += 1;
        if self.index >= self.mission.waypoints.len() {
            self.phase = RunPhase::Finished;
            self.ended_unix_ms = Some(now_ms);
            return Vec::new();
        }
        vec![self.send(now_ms, next_id)]
    }

    /// The operator says go on (after a pause).
    pub fn resume(&mut self, now_ms: u64, next_id: &mut dyn FnMut() -> u32) -> Vec<RunAction> {
        if self.phase == RunPhase::Paused {
            self.next(now_ms, next_id)
        } else {
            Vec::new()
        }
    }

    /// The operator cancels the run: the robot is stopped.
    pub fn cancel(&mut self, now_ms: u64) -> Vec<RunAction> {
        if self.ended() {
            return Vec::new();
        }
        self.phase = RunPhase::Cancelled;
        self.ended_unix_ms = Some(now_ms);
        vec![RunAction::Stop]
    }

    /// Advances the run at `now_ms`; `next_id` hands out goal ids. Returns the commands to send.
    pub fn step(
        &mut self,
        now_ms: u64,
        robot: RobotNow<'_>,
        next_id: &mut dyn FnMut() -> u32,
    ) -> Vec<RunAction> {
        self.update_progress(robot);
        let mut out = Vec::new();
        match self.phase.clone() {
            RunPhase::Starting => out.push(self.send(now_ms, next_id)),
            RunPhase::Waiting { until_unix_ms } if now_ms >= until_unix_ms => {
                if self.mission.waypoints[self.index].pause {
                    self.phase = RunPhase::Paused;
                } else {
                    out.extend(self.next(now_ms, next_id));
                }
            }
            RunPhase::Going {
                goal_id,
                sent_unix_ms,
                taken,
                no_path_since,
            } => {
                let Some(s) = robot.status.filter(|_| robot.online) else {
                    // Offline: the robot drives its leg on its own; wait for it.
                    return out;
                };
                let ours = s.goal_id == goal_id;
                let taken = taken || ours;
                if ours && s.mission == MissionState::Reached {
                    out.extend(self.arrive(now_ms, next_id));
                } else if taken && !ours && s.mode == common::msg::Mode::Goal {
                    self.fail(
                        format!(
                            "another goal ({}) replaced waypoint {}",
                            s.goal_id,
                            self.index + 1
                        ),
                        now_ms,
                    );
                } else if taken && s.mission == MissionState::Stopped {
                    self.fail(
                        format!("stopped at waypoint {}: {}", self.index + 1, s.reason),
                        now_ms,
                    );
                } else if ours && s.mission == MissionState::NoPath {
                    let since = no_path_since.unwrap_or(now_ms);
                    if (now_ms - since) as f64 / 1000.0 >= NO_PATH_FAIL_S {
                        self.fail(
                            format!("no path to waypoint {}: {}", self.index + 1, s.reason),
                            now_ms,
                        );
                    } else {
                        self.phase = RunPhase::Going {
                            goal_id,
                            sent_unix_ms,
                            taken,
                            no_path_since: Some(since),
                        };
                    }
                } else if !taken {
                    let waited_s = now_ms.saturating_sub(sent_unix_ms) as f64 / 1000.0;
                    let refused = s
                        .last_error
                        .as_deref()
                        .filter(|e| e.starts_with("goal:") && waited_s > 0.5);
                    if let Some(e) = refused {
                        self.fail(format!("waypoint {} refused: {e}", self.index + 1), now_ms);
                    } else if waited_s >= RESEND_AFTER_S {
                        // Lost on the way (a reconnect): send it again under a new id.
                        out.push(self.send(now_ms, next_id));
                    }
                } else {
                    self.phase = RunPhase::Going {
                        goal_id,
                        sent_unix_ms,
                        taken,
                        no_path_since: None,
                    };
                }
            }
            _ => {}
        }
        out
    }

    fn arrive(&mut self, now_ms: u64, next_id: &mut dyn FnMut() -> u32) -> Vec<RunAction> {
        let w = self.mission.waypoints[self.index].clone();
        self.reached_unix_ms[self.index] = Some(now_ms);
        let mut out = Vec::new();
        if let Some(v) = w.speed_mps {
            out.push(RunAction::Speed(v));
        }
        if w.wait_s > 0.0 {
            self.phase = RunPhase::Waiting {
                until_unix_ms: now_ms + (w.wait_s * 1000.0) as u64,
            };
        } else if w.pause {
            self.phase = RunPhase::Paused;
        } else {
            out.extend(self.next(now_ms, next_id));
        }
        out
    }

    fn update_progress(&mut self, robot: RobotNow<'_>) {
        let wps = &self.mission.waypoints;
        if self.ended() || self.index >= wps.len() {
            self.distance_left_m = 0.0;
            self.eta_s = Some(0.0);
            return;
        }
        let here = robot
            .pose
            .filter(|_| self.send_as == SendAs::MapXy)
            .map(|p| (p.x_m, p.y_m));
        let first = match (here, &self.phase) {
            (Some(h), RunPhase::Going { .. }) => {
                (wps[self.index].x_m - h.0).hypot(wps[self.index].y_m - h.1)
            }
            _ => 0.0,
        };
        let rest: f64 = wps[self.index..]
            .windows(2)
            .map(|w| (w[1].x_m - w[0].x_m).hypot(w[1].y_m - w[0].y_m))
            .sum();
        self.distance_left_m = first + rest;
        let v = robot
            .status
            .map(|s| {
                s.speed_limit_mps.min(if s.speed_max_mps > 0.0 {
                    s.speed_max_mps
                } else {
                    f32::MAX
                })
            })
            .filter(|v| *v > 0.05)
            .map(|v| 0.8 * f64::from(v));
        let waits: f64 = wps[self.index..].iter().map(|w| w.wait_s).sum();
        self.eta_s = v.map(|v| self.distance_left_m / v + waits);
    }
}

#[cfg(test)]
mod tests {
    use super::super::Waypoint;
    use super::*;
    use common::msg::Mode;

    fn mission(n: usize) -> Mission {
        Mission {
            mission_id: "m".into(),
            name: "four".into(),
            datum_id: "d0".into(),
            frame: MissionFrame::Map,
            waypoints: (0..n)
                .map(|i| Waypoint {
                    x_m: 2.0 * i as f64 + 2.0,
                    y_m: 0.0,
                    lat_deg: None,
                    lon_deg: None,
                    speed_mps: None,
                    wait_s: 0.0,
                    pause: false,
                })
                .collect(),
            saved_unix_ms: 0,
        }
    }

    fn st(goal_id: u32, mission: MissionState) -> Status {
        Status {
            mode: if mission == MissionState::Reached {
                Mode::Idle
            } else {
                Mode::Goal
            },
            mission,
            goal_id,
            speed_limit_mps: 0.5,
            speed_max_mps: 0.5,
            ..Status::default()
        }
    }

    fn now<'a>(s: &'a Status) -> RobotNow<'a> {
        RobotNow {
            online: true,
            status: Some(s),
            pose: None,
        }
    }

    fn goal_of(a: &[RunAction]) -> u32 {
        match a.last() {
            Some(RunAction::Goal { goal_id, .. }) => *goal_id,
            other => panic!("expected a goal, got {other:?}"),
        }
    }

    #[test]
    fn visits_waypoints_in_order_with_their_actions() {
        let mut m = mission(4);
        m.waypoints[1].speed_mps = Some(0.3);
        m.waypoints[1].wait_s = 2.0;
        m.waypoints[2].pause = true;
        let mut ids = 100..;
        let mut next = || ids.next().unwrap();
        let mut run = Run::new("r", m, SendAs::MapXy, 0);
        let idle = Status::default();
        let g0 = goal_of(&run.step(0, now(&idle), &mut next));
        assert_eq!(g0, 100);
        assert!(run
            .step(100, now(&st(g0, MissionState::Driving)), &mut next)
            .is_empty());
        let a = run.step(5000, now(&st(g0, MissionState::Reached)), &mut next);
        let g1 = goal_of(&a);
        assert_eq!((run.index, g1), (1, 101));
        let a = run.step(9000, now(&st(g1, MissionState::Reached)), &mut next);
        assert_eq!(a, vec![RunAction::Speed(0.3)], "speed, then the wait");
        assert!(matches!(run.phase, RunPhase::Waiting { .. }));
        assert!(run
            .step(10_000, now(&st(g1, MissionState::Reached)), &mut next)
            .is_empty());
        let g2 = goal_of(&run.step(11_000, now(&st(g1, MissionState::Reached)), &mut next));
        run.step(12_000, now(&st(g2, MissionState::Driving)), &mut next);
        assert!(run
            .step(15_000, now(&st(g2, MissionState::Reached)), &mut next)
            .is_empty());
        assert_eq!(run.phase, RunPhase::Paused);
        let g3 = goal_of(&run.resume(20_000, &mut next));
        assert_eq!(run.index, 3);
        run.step(21_000, now(&st(g3, MissionState::Reached)), &mut next);
        assert_eq!(run.phase, RunPhase::Finished);
        assert!(run.reached_unix_ms.iter().all(Option::is_some));
    }

    #[test]
    fn refusals_stops_and_no_path_fail_the_run() {
        let mut ids = 1..;
        let mut next = || ids.next().unwrap();
        let mut run = Run::new("r", mission(2), SendAs::MapXy, 0);
        let g = goal_of(&run.step(0, now(&Status::default()), &mut next));
        let refused = Status {
            last_error: Some("goal: (1.0, 1.0) is inside keep-out zone \"pond\"".into()),
            ..Status::default()
        };
        run.step(1000, now(&refused), &mut next);
        assert!(
            matches!(&run.phase, RunPhase::Failed { reason } if reason.contains("keep-out")),
            "{:?}",
            run.phase
        );

        let mut run = Run::new("r", mission(2), SendAs::MapXy, 0);
        let g = goal_of(&run.step(0, now(&Status::default()), &mut next)).max(g);
        run.step(100, now(&st(g, MissionState::Driving)), &mut next);
        run.step(200, now(&st(g, MissionState::Stopped)), &mut next);
        assert!(matches!(&run.phase, RunPhase::Failed { reason } if reason.contains("stopped")));

        let mut run = Run::new("r", mission(2), SendAs::MapXy, 0);
        let g = goal_of(&run.step(0, now(&Status::default()), &mut next));
        run.step(100, now(&st(g, MissionState::NoPath)), &mut next);
        run.step(5000, now(&st(g, MissionState::NoPath)), &mut next);
        assert!(!run.ended());
        run.step(12_200, now(&st(g, MissionState::NoPath)), &mut next);
        assert!(matches!(&run.phase, RunPhase::Failed { reason } if reason.contains("no path")));
        assert_eq!(run.cancel(13_000), vec![], "an ended run stays ended");
    }
}

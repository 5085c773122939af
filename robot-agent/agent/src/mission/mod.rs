//! Missions: one state machine over what the robot is doing, and the missions themselves — go
//! to a goal ([`navigate`]), teach a route ([`teach`]) and repeat it around new obstacles
//! ([`repeat`], with the teach-time view of [`teach_view`]).
//!
//! [`MissionMachine::transition`] is the only place the mode changes. Its rules:
//!
//! | in \ event | goal | drive | stop | record | stop recording | repeat | pause / resume / cancel |
//! | --- | --- | --- | --- | --- | --- | --- | --- |
//! | Idle | Goal | Teleop | Idle | Teach | refused | Repeat | refused |
//! | Goal | Goal (new) | Teleop | Idle | Teach | refused | Repeat | refused |
//! | Teleop | Goal | Teleop | Idle | Teach (still driving) | refused | Repeat | refused |
//! | Teach | refused | Teach (driving) | Teach (halted) | refused | Teleop or Idle | refused | refused |
//! | Repeat | Goal | Teleop | Idle | Teach | refused | Repeat (new) | paused / resumed / Idle |
//!
//! Internal events: a reached goal ends Goal, a finished route ends Repeat. A stop while
//! teaching halts the robot but keeps recording (an emergency stop must not lose the route);
//! the operator ends a recording explicitly. Drive commands with a sequence number not above the
//! last one are stale duplicates and change nothing.

pub mod navigate;
pub mod repeat;
pub mod teach;
pub mod teach_view;

use crate::command::refusal;
use crate::driver::Teleop;
use common::command::{Refusal, RefusalCode};
use navigate::{Goal, Navigator};
use repeat::{RepeatState, RouteFollower};
use teach::RouteRecorder;
use teach_view::TeachView;

/// The phase of the current mission, as the status reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Phase {
    /// No mission.
    #[default]
    Idle,
    /// Computing a path.
    Planning,
    /// Following the path.
    Driving,
    /// Stopped by the safety stop or a blocked path; goes on when clear.
    Blocked,
    /// No path exists to the goal.
    NoPath,
    /// Goal reached.
    Reached,
    /// Stopped by the operator (or ended by another mission).
    Stopped,
    /// Paused by the operator.
    Paused,
}

/// What the robot is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Mode {
    /// Waiting for a command.
    #[default]
    Idle,
    /// Going to a goal.
    Goal,
    /// Driven by the operator.
    Teleop,
    /// Recording a route while the operator drives.
    Teach,
    /// Following a taught route.
    Repeat,
}

/// A route being repeated.
#[derive(Debug)]
pub struct Repeat {
    /// The follower.
    pub follower: RouteFollower,
    /// Route id.
    pub route_id: String,
    /// Route name.
    pub name: String,
    /// Paused by the operator.
    pub paused: bool,
    /// The last cycle's outcome.
    pub last: Option<RepeatState>,
    /// The teach-time view, when the route was taught in this session.
    pub view: Option<TeachView>,
}

#[derive(Debug)]
struct Teach {
    recorder: RouteRecorder,
    teleop: Option<Teleop>,
}

#[derive(Debug)]
enum State {
    Idle,
    Goal,
    Teleop(Teleop),
    Teach(Teach),
    Repeat(Box<Repeat>),
}

/// What happens to the mission.
#[derive(Debug)]
pub enum Event {
    /// Go to a goal (already placed in the map frame).
    Goal(Goal),
    /// An operator's drive command.
    Drive(Teleop),
    /// Stop, with the operator's reason (empty: none given).
    Stop(String),
    /// Start teaching with this recorder.
    Record(RouteRecorder),
    /// End teaching.
    StopRecording,
    /// Repeat a route (the follower already set up in the map frame).
    Repeat(Box<Repeat>),
    /// Pause the repeat.
    Pause,
    /// Resume the repeat.
    Resume,
    /// Cancel the repeat.
    Cancel,
    /// The goal was reached (internal).
    GoalReached,
    /// The route's last waypoint was reached (internal).
    RouteFinished,
}

/// What a transition hands back.
#[derive(Debug)]
pub enum Outcome {
    /// Nothing beyond the new state.
    Done,
    /// Teaching ended with this recorder (finish it into a route).
    Recorded(RouteRecorder),
}

/// See the module docs.
#[derive(Debug)]
pub struct MissionMachine {
    state: State,
    nav: Navigator,
    /// The last repeat that ended (finished or cancelled), for reports of how it went.
    ended_repeat: Option<Box<Repeat>>,
}

impl MissionMachine {
    /// An idle machine over `nav`.
    pub fn new(nav: Navigator) -> Self {
        Self {
            state: State::Idle,
            nav,
            ended_repeat: None,
        }
    }

    /// The one transition function (see the table in the module docs).
    pub fn transition(&mut self, ev: Event) -> Result<Outcome, Refusal> {
        let state = std::mem::replace(&mut self.state, State::Idle);
        let (next, outcome) = match (state, ev) {
            (s @ State::Teach(_), Event::Goal(_)) => {
                self.state = s;
                return Err(refusal(
                    RefusalCode::Teaching,
                    "goal",
                    "the robot is recording a route: stop recording first",
                ));
            }
            (_, Event::Goal(goal)) => {
                self.nav.set_goal(goal);
                (State::Goal, Outcome::Done)
            }
            (State::Teach(mut t), Event::Drive(d)) => {
                if !stale(t.teleop.as_ref(), &d) {
                    if t.teleop.is_none() {
                        self.nav.stop("operator took over (teleop)");
                    }
                    t.teleop = Some(d);
                }
                (State::Teach(t), Outcome::Done)
            }
            (State::Teleop(last), Event::Drive(d)) => {
                let t = if stale(Some(&last), &d) { last } else { d };
                (State::Teleop(t), Outcome::Done)
            }
            (_, Event::Drive(d)) => {
                self.nav.stop("operator took over (teleop)");
                (State::Teleop(d), Outcome::Done)
            }
            (s, Event::Stop(reason)) => {
                self.nav.stop(if reason.is_empty() {
                    "stopped by the operator"
                } else {
                    &reason
                });
                match s {
                    State::Teach(t) => (State::Teach(Teach { teleop: None, ..t }), Outcome::Done),
                    _ => (State::Idle, Outcome::Done),
                }
            }
            (s @ State::Teach(_), Event::Record(_)) => {
                self.state = s;
                return Err(refusal(
                    RefusalCode::Teaching,
                    "route",
                    "already recording a route: stop recording first",
                ));
            }
            (s, Event::Record(recorder)) => {
                let teleop = match s {
                    State::Teleop(t) => Some(t),
                    State::Goal | State::Repeat(_) => {
                        self.nav.stop("recording a route: the operator drives");
                        None
                    }
                    _ => None,
                };
                (State::Teach(Teach { recorder, teleop }), Outcome::Done)
            }
            (State::Teach(t), Event::StopRecording) => {
                let next = match t.teleop {
                    Some(d) => State::Teleop(d),
                    None => State::Idle,
                };
                (next, Outcome::Recorded(t.recorder))
            }
            (s, Event::StopRecording) => {
                self.state = s;
                return Err(refusal(RefusalCode::NotRecording, "route", "not recording"));
            }
            (s @ State::Teach(_), Event::Repeat(_)) => {
                self.state = s;
                return Err(refusal(
                    RefusalCode::Teaching,
                    "route",
                    "the robot is recording a route: stop recording first",
                ));
            }
            (_, Event::Repeat(r)) => {
                self.nav.stop("route repeat started");
                (State::Repeat(r), Outcome::Done)
            }
            (State::Repeat(mut r), Event::Pause) => {
                r.paused = true;
                (State::Repeat(r), Outcome::Done)
            }
            (State::Repeat(mut r), Event::Resume) => {
                r.paused = false;
                (State::Repeat(r), Outcome::Done)
            }
            (State::Repeat(r), Event::Cancel) => {
                self.nav.stop("route repeat cancelled");
                self.ended_repeat = Some(r);
                (State::Idle, Outcome::Done)
            }
            (s, Event::Pause | Event::Resume | Event::Cancel) => {
                self.state = s;
                return Err(refusal(
                    RefusalCode::NotRepeating,
                    "route",
                    "no route is being repeated",
                ));
            }
            (State::Goal, Event::GoalReached) => (State::Idle, Outcome::Done),
            (State::Repeat(r), Event::RouteFinished) => {
                // Finished is done, not stopped: it must not look like the operator's STOP.
                self.nav.finish("route finished");
                self.ended_repeat = Some(r);
                (State::Idle, Outcome::Done)
            }
            (s, Event::GoalReached | Event::RouteFinished) => (s, Outcome::Done),
        };
        self.state = next;
        Ok(outcome)
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        match self.state {
            State::Idle => Mode::Idle,
            State::Goal => Mode::Goal,
            State::Teleop(_) => Mode::Teleop,
            State::Teach(_) => Mode::Teach,
            State::Repeat(_) => Mode::Repeat,
        }
    }

    /// The operator's drive in force (teleop, or teaching while driving).
    pub fn teleop(&self) -> Option<&Teleop> {
        match &self.state {
            State::Teleop(t) => Some(t),
            State::Teach(t) => t.teleop.as_ref(),
            _ => None,
        }
    }

    /// The route recorder, while teaching.
    pub fn recorder_mut(&mut self) -> Option<&mut RouteRecorder> {
        match &mut self.state {
            State::Teach(t) => Some(&mut t.recorder),
            _ => None,
        }
    }

    /// Whether a route is being recorded.
    pub fn recording(&self) -> bool {
        matches!(self.state, State::Teach(_))
    }

    /// The route being repeated.
    pub fn repeat(&self) -> Option<&Repeat> {
        match &self.state {
            State::Repeat(r) => Some(r),
            _ => None,
        }
    }

    /// The route being repeated, or else the last one that ended (reports read its detours).
    pub fn repeat_or_last(&self) -> Option<&Repeat> {
        self.repeat().or(self.ended_repeat.as_deref())
    }

    /// The route being repeated, mutable (the repeat cycle).
    pub fn repeat_mut(&mut self) -> Option<&mut Repeat> {
        match &mut self.state {
            State::Repeat(r) => Some(r),
            _ => None,
        }
    }

    /// The go-to-goal navigator (its phase and reason also tell how other missions ended).
    pub fn nav(&self) -> &Navigator {
        &self.nav
    }

    /// The navigator, mutable (planning, reaching, blocking).
    pub fn nav_mut(&mut self) -> &mut Navigator {
        &mut self.nav
    }

    /// The phase and reason for the status; `safety_stop`: the safety stop holds the robot.
    pub fn phase(&self, safety_stop: bool) -> (Phase, String) {
        match &self.state {
            State::Teleop(_)
            | State::Teach(Teach {
                teleop: Some(_), ..
            }) => (Phase::Driving, "teleop".into()),
            State::Repeat(r) if r.paused => (Phase::Paused, "route repeat paused".into()),
            State::Repeat(_) => (
                if safety_stop {
                    Phase::Blocked
                } else {
                    Phase::Driving
                },
                "repeating route".into(),
            ),
            _ => (self.nav.state(), self.nav.reason().to_string()),
        }
    }
}

/// Whether `d` is an older duplicate of `last` (sequence 0 is never stale).
fn stale(last: Option<&Teleop>, d: &Teleop) -> bool {
    last.is_some_and(|l| d.seq <= l.seq && d.seq != 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mission::teach::TeachConfig;

    fn machine() -> MissionMachine {
        MissionMachine::new(Navigator::new(
            navigate::NavConfig::default(),
            planning::PlannerConfig::default(),
        ))
    }

    fn drive(seq: u32, v: f64) -> Event {
        Event::Drive(Teleop {
            t_s: f64::from(seq),
            seq,
            v_mps: v,
            omega_rps: 0.0,
            deadman: true,
        })
    }

    fn goal() -> Event {
        Event::Goal(Goal {
            id: 1,
            goal_map: (5.0, 0.0),
            tolerance_m: 0.3,
            gnss: None,
        })
    }

    fn record() -> Event {
        Event::Record(RouteRecorder::new(TeachConfig::default(), "r"))
    }

    fn code(r: Result<Outcome, Refusal>) -> RefusalCode {
        r.unwrap_err().code
    }

    #[test]
    fn teleop_takes_over_a_goal_and_stale_drives_change_nothing() {
        let mut m = machine();
        m.transition(goal()).unwrap();
        assert_eq!(m.mode(), Mode::Goal);
        m.transition(drive(5, 0.4)).unwrap();
        assert_eq!(m.mode(), Mode::Teleop);
        assert_eq!(m.nav().state(), Phase::Stopped);
        m.transition(drive(3, -1.0)).unwrap();
        assert_eq!(m.teleop().unwrap().v_mps, 0.4, "older sequence ignored");
        m.transition(drive(0, 0.1)).unwrap();
        assert_eq!(
            m.teleop().unwrap().v_mps,
            0.1,
            "sequence 0 is not sequenced"
        );
        m.transition(Event::Stop(String::new())).unwrap();
        assert_eq!(m.mode(), Mode::Idle);
        assert_eq!(m.nav().reason(), "stopped by the operator");
    }

    #[test]
    fn teaching_survives_a_stop_and_refuses_other_missions() {
        let mut m = machine();
        m.transition(drive(1, 0.3)).unwrap();
        m.transition(record()).unwrap();
        assert_eq!(m.mode(), Mode::Teach);
        assert!(m.teleop().is_some(), "still driving");
        assert_eq!(code(m.transition(goal())), RefusalCode::Teaching);
        assert_eq!(code(m.transition(record())), RefusalCode::Teaching);
        m.transition(Event::Stop("e-stop".into())).unwrap();
        assert_eq!(m.mode(), Mode::Teach, "the recording goes on");
        assert!(m.teleop().is_none(), "halted");
        assert!(matches!(
            m.transition(Event::StopRecording).unwrap(),
            Outcome::Recorded(_)
        ));
        assert_eq!(m.mode(), Mode::Idle);
        assert_eq!(
            code(m.transition(Event::StopRecording)),
            RefusalCode::NotRecording
        );
    }

    #[test]
    fn route_controls_need_a_repeat() {
        let mut m = machine();
        for ev in [Event::Pause, Event::Resume, Event::Cancel] {
            assert_eq!(code(m.transition(ev)), RefusalCode::NotRepeating);
        }
        m.transition(goal()).unwrap();
        m.transition(Event::GoalReached).unwrap();
        assert_eq!(m.mode(), Mode::Idle);
    }

    #[test]
    fn a_finished_route_is_reached_not_stopped() {
        let mut m = machine();
        let follower = RouteFollower::new(
            repeat::RepeatConfig::default(),
            &[(0.0, 0.0), (5.0, 0.0)],
            &common::geom::Pose2::default(),
        );
        m.transition(Event::Repeat(Box::new(Repeat {
            follower,
            route_id: "r".into(),
            name: "lap".into(),
            paused: false,
            last: None,
            view: None,
        })))
        .unwrap();
        m.transition(Event::RouteFinished).unwrap();
        assert_eq!(m.phase(false).0, Phase::Reached);
        assert_eq!(m.phase(false).1, "route finished");
        m.transition(Event::Stop(String::new())).unwrap();
        assert_eq!(m.phase(false).0, Phase::Stopped, "STOP stays Stopped");
    }
}

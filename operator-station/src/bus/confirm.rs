//! Whether a command sent to a robot was taken, judged from the robot's own status, and when to
//! send it again. A put can be lost between two Zenoh sessions shortly after they connect (README,
//! Tests), and the CLI's commands come from a session opened a moment before, so a command counts
//! as delivered only once a status shows its effect. No I/O and no clock here: the caller feeds
//! statuses and the time in seconds ([`super::client::send_confirmed`] does it over Zenoh).

use common::msg::{MissionState, Mode, Status};

/// What the robot's status shows once it has taken a command.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Expect {
    /// The goal with this id is the robot's current goal (whatever became of it since: planning,
    /// driving, no path, reached).
    Goal {
        /// The goal's id.
        goal_id: u32,
    },
    /// The robot neither drives a mission nor is driven by the operator.
    Halted,
}

impl Expect {
    /// The word the robot's refusals of this command begin with (`common::command`'s kinds).
    fn kind(&self) -> &'static str {
        match self {
            Expect::Goal { .. } => "goal",
            Expect::Halted => "stop",
        }
    }
}

/// One status judged against what was expected.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Nothing yet shows the command taken or refused.
    Pending,
    /// The status shows the command's effect.
    Taken,
    /// The robot refused the command; its reason.
    Refused(String),
    /// The robot took a newer goal than the one it showed before the send, and not this
    /// command's: another sender commanded it since, and sending this again would undo that.
    Superseded {
        /// The goal the robot shows now.
        goal_id: u32,
    },
}

/// Judges `s` against `expect`. `baseline` is a status received before the first send: a refusal
/// counts only when the robot's refusal counter has grown past it and its last error is about
/// this kind of command and new, and, for a goal, another goal driven (not the baseline's nor
/// this one) means another sender's newer goal (without a baseline neither can be told from old
/// news, so the command stays pending).
pub fn judge(expect: &Expect, baseline: Option<&Status>, s: &Status) -> Verdict {
    let taken = match expect {
        Expect::Goal { goal_id } => s.goal_id == *goal_id,
        Expect::Halted => {
            s.mode != Mode::Teleop
                && !matches!(
                    s.mission,
                    MissionState::Planning | MissionState::Driving | MissionState::Blocked
                )
        }
    };
    if taken {
        return Verdict::Taken;
    }
    if let (Some(b), Some(e)) = (baseline, &s.last_error) {
        let new_refusal = s.commands_refused > b.commands_refused
            && (b.last_error.as_ref() != Some(e) || s.commands_refused > b.commands_refused + 1);
        if new_refusal && e.starts_with(expect.kind()) {
            return Verdict::Refused(e.clone());
        }
    }
    // Only a goal gives way: a stop is sent again whatever else happened (stopping is always
    // safe), and a robot repeating a route moves its own goal from waypoint to waypoint.
    match (expect, baseline) {
        (Expect::Goal { .. }, Some(b)) if s.mode == Mode::Goal && s.goal_id != b.goal_id => {
            Verdict::Superseded { goal_id: s.goal_id }
        }
        _ => Verdict::Pending,
    }
}

/// How often and how long to try.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Policy {
    /// Sends at most, the first included.
    pub attempts: u32,
    /// How long to wait for a status showing the command before sending it again, seconds.
    /// Robots publish their status every 0.5 s and at every change, so 2 s is four chances.
    pub confirm_s: f64,
}

impl Default for Policy {
    fn default() -> Self {
        Policy {
            attempts: 3,
            confirm_s: 2.0,
        }
    }
}

/// How a delivery ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// A status showed it taken after this many sends.
    Taken {
        /// Sends made.
        attempts: u32,
    },
    /// Another sender's newer goal took over before a status showed this command.
    Superseded {
        /// The goal the robot shows.
        goal_id: u32,
        /// Sends made.
        attempts: u32,
    },
    /// Refused by the robot.
    Refused {
        /// The robot's reason.
        reason: String,
        /// Sends made.
        attempts: u32,
    },
    /// Every send made and none shown in a status.
    Unconfirmed {
        /// Sends made.
        attempts: u32,
        /// Statuses received after the first send.
        statuses: u32,
    },
}

/// What the sender should do now.
#[derive(Clone, Debug, PartialEq)]
pub enum Step {
    /// Send the command (again), with a fresh sequence number.
    Send,
    /// Wait for statuses until this time, seconds.
    WaitUntil(f64),
    /// Stop: the delivery ended.
    Done(Outcome),
}

/// The sending of one command until the robot's status shows it.
#[derive(Clone, Debug)]
pub struct Delivery {
    expect: Expect,
    policy: Policy,
    baseline: Option<Status>,
    attempts: u32,
    last_send_s: f64,
    statuses: u32,
    outcome: Option<Verdict>,
    last: Option<Status>,
}

impl Delivery {
    /// A delivery of a command expected to show as `expect`; `baseline` is the robot's status
    /// before the first send, if one came.
    pub fn new(expect: Expect, policy: Policy, baseline: Option<Status>) -> Self {
        Delivery {
            expect,
            policy: Policy {
                attempts: policy.attempts.max(1),
                confirm_s: policy.confirm_s.max(0.1),
            },
            baseline,
            attempts: 0,
            last_send_s: f64::NEG_INFINITY,
            statuses: 0,
            outcome: None,
            last: None,
        }
    }

    /// Records a send at `now_s`.
    pub fn sent(&mut self, now_s: f64) {
        self.attempts += 1;
        self.last_send_s = now_s;
    }

    /// Takes a status received from the robot (those before the first send are ignored: they
    /// cannot show this command).
    pub fn status(&mut self, s: Status) {
        if self.attempts == 0 || self.outcome.is_some() {
            return;
        }
        self.statuses += 1;
        match judge(&self.expect, self.baseline.as_ref(), &s) {
            Verdict::Pending => {}
            v => self.outcome = Some(v),
        }
        self.last = Some(s);
    }

    /// The last status received after the first send.
    pub fn last_status(&self) -> Option<&Status> {
        self.last.as_ref()
    }

    /// What to do at `now_s`.
    pub fn step(&self, now_s: f64) -> Step {
        let attempts = self.attempts;
        match &self.outcome {
            Some(Verdict::Taken) => return Step::Done(Outcome::Taken { attempts }),
            Some(Verdict::Refused(reason)) => {
                return Step::Done(Outcome::Refused {
                    reason: reason.clone(),
                    attempts,
                })
            }
            Some(Verdict::Superseded { goal_id }) => {
                return Step::Done(Outcome::Superseded {
                    goal_id: *goal_id,
                    attempts,
                })
            }
            Some(Verdict::Pending) | None => {}
        }
        let due = self.last_send_s + self.policy.confirm_s;
        if now_s < due {
            Step::WaitUntil(due)
        } else if self.attempts < self.policy.attempts {
            Step::Send
        } else {
            Step::Done(Outcome::Unconfirmed {
                attempts,
                statuses: self.statuses,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(goal_id: u32, mission: MissionState, refused: u32, err: Option<&str>) -> Status {
        Status {
            goal_id,
            mission,
            mode: if matches!(mission, MissionState::Idle | MissionState::Stopped) {
                Mode::Idle
            } else {
                Mode::Goal
            },
            commands_refused: refused,
            last_error: err.map(str::to_string),
            ..Status::default()
        }
    }

    #[test]
    fn a_goal_is_taken_when_the_status_carries_its_id() {
        let base = status(7, MissionState::Reached, 0, None);
        let e = Expect::Goal { goal_id: 8 };
        assert_eq!(judge(&e, Some(&base), &base), Verdict::Pending);
        let s = status(8, MissionState::Planning, 0, None);
        assert_eq!(judge(&e, Some(&base), &s), Verdict::Taken);
        // What became of it does not matter: the robot took it.
        let s = status(8, MissionState::NoPath, 0, None);
        assert_eq!(judge(&e, Some(&base), &s), Verdict::Taken);
    }

    #[test]
    fn only_a_new_refusal_of_the_same_kind_counts() {
        let old = "goal: (900.0, 0.0) is inside keep-out zone \"pond\"";
        let base = status(7, MissionState::Idle, 1, Some(old));
        let e = Expect::Goal { goal_id: 8 };
        // The old refusal, still shown: not this goal's.
        assert_eq!(judge(&e, Some(&base), &base), Verdict::Pending);
        // A speed command refused meanwhile: not this goal's either.
        let s = status(
            7,
            MissionState::Idle,
            2,
            Some("speed: limit -1 m/s out of range"),
        );
        assert_eq!(judge(&e, Some(&base), &s), Verdict::Pending);
        let s = status(
            7,
            MissionState::Idle,
            2,
            Some("goal: ( 3.0, 4.0) in keep-out"),
        );
        assert_eq!(
            judge(&e, Some(&base), &s),
            Verdict::Refused("goal: ( 3.0, 4.0) in keep-out".into())
        );
        // The same words as the old refusal, but counted twice since: one of them is new.
        let s = status(7, MissionState::Idle, 3, Some(old));
        assert!(matches!(judge(&e, Some(&base), &s), Verdict::Refused(_)));
        // Without a baseline an old refusal cannot be told from a new one.
        assert_eq!(judge(&e, None, &s), Verdict::Pending);
    }

    #[test]
    fn another_senders_newer_goal_ends_a_goals_delivery_but_never_a_stops() {
        let base = status(7, MissionState::Stopped, 0, None);
        // The robot drives goal 9, neither the old one nor ours: someone else's, not undone.
        let e = Expect::Goal { goal_id: 8 };
        let s = status(9, MissionState::Driving, 0, None);
        assert_eq!(
            judge(&e, Some(&base), &s),
            Verdict::Superseded { goal_id: 9 }
        );
        let mut d = Delivery::new(e.clone(), Policy::default(), Some(base.clone()));
        d.sent(0.0);
        d.status(s.clone());
        assert_eq!(
            d.step(5.0),
            Step::Done(Outcome::Superseded {
                goal_id: 9,
                attempts: 1
            })
        );
        // A route being repeated moves its own goal id: not another sender.
        let repeating = Status {
            mode: Mode::Repeat,
            ..s.clone()
        };
        assert_eq!(judge(&e, Some(&base), &repeating), Verdict::Pending);
        // A stop is sent again even while someone else's goal drives the robot.
        assert_eq!(judge(&Expect::Halted, Some(&base), &s), Verdict::Pending);
        // Without a baseline a goal id says nothing about who sent it.
        assert_eq!(judge(&e, None, &s), Verdict::Pending);
    }

    #[test]
    fn halted_means_no_mission_driving_and_no_operator_driving() {
        let e = Expect::Halted;
        for (m, halted) in [
            (MissionState::Driving, false),
            (MissionState::Planning, false),
            (MissionState::Blocked, false),
            (MissionState::Stopped, true),
            (MissionState::Idle, true),
            (MissionState::Reached, true),
            (MissionState::Paused, true),
        ] {
            let s = status(1, m, 0, None);
            assert_eq!(judge(&e, None, &s) == Verdict::Taken, halted, "{m:?}");
        }
        let teleop = Status {
            mode: Mode::Teleop,
            ..status(1, MissionState::Idle, 0, None)
        };
        assert_eq!(judge(&e, None, &teleop), Verdict::Pending);
    }

    #[test]
    fn a_lost_send_is_sent_again_after_the_wait_and_the_second_is_confirmed() {
        let base = status(7, MissionState::Idle, 0, None);
        let mut d = Delivery::new(
            Expect::Goal { goal_id: 8 },
            Policy::default(),
            Some(base.clone()),
        );
        // Statuses before the first send say nothing about it.
        d.status(status(8, MissionState::Driving, 0, None));
        assert_eq!(d.step(0.0), Step::Send);
        d.sent(0.0);
        assert_eq!(d.step(0.5), Step::WaitUntil(2.0));
        // The first send was lost: statuses keep showing the old goal.
        d.status(base.clone());
        d.status(base.clone());
        assert_eq!(d.step(2.0), Step::Send);
        d.sent(2.0);
        d.status(status(8, MissionState::Planning, 0, None));
        assert_eq!(d.step(2.3), Step::Done(Outcome::Taken { attempts: 2 }));
        // Later statuses do not undo the outcome.
        d.status(base);
        assert_eq!(d.step(9.0), Step::Done(Outcome::Taken { attempts: 2 }));
        assert_eq!(d.last_status().unwrap().goal_id, 8);
    }

    #[test]
    fn gives_up_after_the_last_wait_and_says_how_many_statuses_came() {
        let mut d = Delivery::new(
            Expect::Halted,
            Policy {
                attempts: 2,
                confirm_s: 1.0,
            },
            None,
        );
        for t in [0.0, 1.0] {
            assert_eq!(d.step(t), Step::Send);
            d.sent(t);
            d.status(status(3, MissionState::Driving, 0, None));
        }
        assert_eq!(d.step(1.5), Step::WaitUntil(2.0));
        assert_eq!(
            d.step(2.0),
            Step::Done(Outcome::Unconfirmed {
                attempts: 2,
                statuses: 2
            })
        );
    }

    #[test]
    fn a_refusal_ends_the_delivery_without_sending_again() {
        let base = status(7, MissionState::Idle, 0, None);
        let mut d = Delivery::new(Expect::Goal { goal_id: 8 }, Policy::default(), Some(base));
        d.sent(0.0);
        d.status(status(
            7,
            MissionState::Idle,
            1,
            Some("goal: in keep-out zone"),
        ));
        assert_eq!(
            d.step(5.0),
            Step::Done(Outcome::Refused {
                reason: "goal: in keep-out zone".into(),
                attempts: 1
            })
        );
    }
}

//! Goals and stops the operator sent a robot through the station, sent again until the robot's
//! status shows them taken or refused. A put is lost when the robot has not yet declared its
//! command subscribers (it came up or reconnected a moment before) or in the window just after
//! two Zenoh sessions connect (README, Tests); mission runs resend their own waypoints
//! (`missions::runner`). One pending command per robot: any newer command sent to it replaces
//! it, so an old goal is never sent over the operator's next one. No I/O here: the station's
//! watch loop feeds the fleet's latest status and does the puts.

use std::time::Instant;

use common::keys::Topic;
use common::msg::{self, CmdHeader, GoalCmd, Status, StopCmd};

use crate::bus::confirm::{Delivery, Expect, Policy, Step};

/// A command that is sent again until the robot shows it.
#[derive(Clone, Debug)]
pub enum Command {
    /// A goal.
    Goal(GoalCmd),
    /// A stop.
    Stop(StopCmd),
}

impl Command {
    /// Its key's topic.
    pub fn topic(&self) -> Topic {
        match self {
            Command::Goal(_) => Topic::CmdGoal,
            Command::Stop(_) => Topic::CmdStop,
        }
    }

    /// Its payload in an envelope with `h`.
    pub fn payload(&self, h: CmdHeader) -> Vec<u8> {
        match self {
            Command::Goal(g) => msg::encode_cmd(h, g),
            Command::Stop(s) => msg::encode_cmd(h, s),
        }
    }

    /// "goal" or "stop", for the log.
    pub fn kind(&self) -> &'static str {
        match self {
            Command::Goal(_) => "goal",
            Command::Stop(_) => "stop",
        }
    }
}

/// One command sent once already, waiting for the robot's status to show it.
#[derive(Clone, Debug)]
pub struct Pending {
    /// The command.
    pub command: Command,
    delivery: Delivery,
    since: Instant,
    /// Stamp of the newest status fed (statuses are fed once each, newer ones only).
    fed_ms: u64,
}

impl Pending {
    /// `command`, sent at `now`; `before` is the robot's status when it was sent.
    pub fn sent(command: Command, before: Option<Status>, now: Instant) -> Self {
        let expect = match &command {
            Command::Goal(g) => Expect::Goal { goal_id: g.goal_id },
            Command::Stop(_) => Expect::Halted,
        };
        let fed_ms = before.as_ref().map_or(0, |s| s.t_unix_ms);
        let mut delivery = Delivery::new(expect, Policy::default(), before);
        delivery.sent(0.0);
        Pending {
            command,
            delivery,
            since: now,
            fed_ms,
        }
    }

    /// What to do at `now`, with the robot's latest status (fed when newer than the last).
    pub fn step(&mut self, latest: Option<&Status>, now: Instant) -> Step {
        if let Some(s) = latest.filter(|s| s.t_unix_ms > self.fed_ms) {
            self.fed_ms = s.t_unix_ms;
            self.delivery.status(s.clone());
        }
        self.delivery
            .step(now.duration_since(self.since).as_secs_f64())
    }

    /// Records that it was sent again at `now`.
    pub fn sent_again(&mut self, now: Instant) {
        self.delivery
            .sent(now.duration_since(self.since).as_secs_f64());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::confirm::Outcome;
    use common::msg::{GoalTarget, MissionState};
    use std::time::Duration;

    fn status(t_unix_ms: u64, goal_id: u32) -> Status {
        Status {
            t_unix_ms,
            goal_id,
            mission: MissionState::Driving,
            mode: common::msg::Mode::Goal,
            ..Status::default()
        }
    }

    #[test]
    fn a_goal_no_status_shows_is_sent_again_then_settles_when_one_does() {
        let t0 = Instant::now();
        let goal = GoalCmd {
            goal_id: 42,
            target: GoalTarget::Map { x_m: 3.0, y_m: 4.0 },
            tolerance_m: 0.0,
        };
        let mut p = Pending::sent(Command::Goal(goal), Some(status(1000, 41)), t0);
        assert_eq!(p.command.topic(), Topic::CmdGoal);
        let at = |s: f64| t0 + Duration::from_secs_f64(s);
        // The status from before the send, seen again, and newer ones with the old goal.
        assert!(matches!(
            p.step(Some(&status(1000, 41)), at(0.5)),
            Step::WaitUntil(_)
        ));
        assert!(matches!(
            p.step(Some(&status(1500, 41)), at(1.0)),
            Step::WaitUntil(_)
        ));
        assert_eq!(p.step(Some(&status(2000, 41)), at(2.0)), Step::Send);
        p.sent_again(at(2.0));
        assert!(matches!(
            p.step(Some(&status(2000, 41)), at(2.5)),
            Step::WaitUntil(_)
        ));
        assert_eq!(
            p.step(Some(&status(2600, 42)), at(2.6)),
            Step::Done(Outcome::Taken { attempts: 2 })
        );
    }

    #[test]
    fn a_stop_with_no_status_at_all_gives_up_after_three_sends() {
        let t0 = Instant::now();
        let mut p = Pending::sent(Command::Stop(StopCmd::default()), None, t0);
        let mut sends = 1;
        let mut t = 0.0;
        let end = loop {
            t += 0.25;
            match p.step(None, t0 + Duration::from_secs_f64(t)) {
                Step::Send => {
                    sends += 1;
                    p.sent_again(t0 + Duration::from_secs_f64(t));
                }
                Step::WaitUntil(_) => {}
                other => break other,
            }
        };
        assert_eq!(sends, 3);
        assert_eq!(
            end,
            Step::Done(Outcome::Unconfirmed {
                attempts: 3,
                statuses: 0
            })
        );
        assert!((5.9..=6.3).contains(&t), "{t}");
    }
}

//! Commands coming in: decoding a payload, the replay guard, and the checks against the contract.

use common::command::{self, Refusal, RefusalCode, ReplayGuard, RobotContext};
use common::keys::{self, RobotId, Topic};
use common::msg::{self, CmdHeader, DriveCmd, GoalCmd, RouteCmd, SpeedCmd, StopCmd, ZoneSet};

use super::CommandLimits;

/// A validated command, or the reason one was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Go to a goal.
    Goal(GoalCmd),
    /// Route teach / repeat.
    Route(RouteCmd),
    /// Teleop.
    Drive(DriveCmd),
    /// Stop now.
    Stop(StopCmd),
    /// Speed limit.
    Speed(SpeedCmd),
    /// The zones to obey (from the station).
    Zones(ZoneSet),
    /// A command that was refused (already counted by the bus); show it in the status.
    Refused(Refusal),
}
/// Checks a decoded command against the contract (`common::command`), with what the robot
/// knows about itself (`ctx`: its position and mapped area, for goals that are too far).
pub fn validate(cmd: &Command, limits: &CommandLimits, ctx: &RobotContext) -> Result<(), Refusal> {
    match cmd {
        Command::Goal(g) => command::check_goal(g, limits, ctx),
        Command::Drive(d) => command::check_drive(d, limits),
        Command::Speed(s) => command::check_speed(s),
        Command::Route(r) => command::check_route(r),
        Command::Zones(z) => command::check_zones(z),
        Command::Stop(_) | Command::Refused(_) => Ok(()),
    }
}

/// What became of one command payload.
#[derive(Clone, Debug, PartialEq)]
pub struct Parsed {
    /// The validated command, or [`Command::Refused`] with the reason.
    pub command: Command,
    /// The payload did not decode (counted apart from other refusals).
    pub undecodable: bool,
    /// Refused as a replay by the [`ReplayGuard`] (counted apart from other refusals).
    pub replayed: bool,
}

/// Decodes one command payload on `key`, checks its header against `guard` at `now_unix_ms` (the
/// robot's clock), then its content against the contract. `None` when the key is not a command of
/// this robot. Undecodable, replayed and invalid commands come back as `Refused`.
pub fn parse_command(
    robot: &RobotId,
    key: &str,
    payload: &[u8],
    limits: &CommandLimits,
    ctx: &RobotContext,
    guard: &mut ReplayGuard,
    now_unix_ms: u64,
) -> Option<Parsed> {
    let (rid, topic) = keys::parse(key).ok()?;
    if &rid != robot || !(topic.is_command() || topic == Topic::Zones) {
        return None;
    }
    let refused = |r: Refusal, undecodable: bool, replayed: bool| Parsed {
        command: Command::Refused(r),
        undecodable,
        replayed,
    };
    fn dec<T: serde::de::DeserializeOwned>(
        kind: &'static str,
        b: &[u8],
        f: fn(T) -> Command,
    ) -> Result<(&'static str, CmdHeader, Command), Refusal> {
        msg::decode_cmd::<T>(b)
            .map(|(h, c)| (kind, h, f(c)))
            .map_err(|e| Refusal::new(RefusalCode::Undecodable, format!("{kind}: {e}")))
    }
    let decoded = match topic {
        Topic::CmdGoal => dec("goal", payload, Command::Goal),
        Topic::CmdRoute => dec("route", payload, Command::Route),
        Topic::CmdDrive => dec("drive", payload, Command::Drive),
        Topic::CmdStop => dec("stop", payload, Command::Stop),
        Topic::CmdSpeed => dec("speed", payload, Command::Speed),
        Topic::Zones => {
            // A zone set is the station's state, not a command: it travels bare (pushed, or as
            // the answer to the robot's query, possibly long after it was drawn), only a station
            // may send it (the access rules), and its version orders it (the agent keeps the
            // newest), so it does not pass the replay guard.
            return Some(match msg::decode::<ZoneSet>(payload) {
                Err(e) => refused(
                    Refusal::new(RefusalCode::Undecodable, format!("zones: {e}")),
                    true,
                    false,
                ),
                Ok(set) => {
                    let cmd = Command::Zones(set);
                    match validate(&cmd, limits, ctx) {
                        Ok(()) => Parsed {
                            command: cmd,
                            undecodable: false,
                            replayed: false,
                        },
                        Err(r) => refused(r, false, false),
                    }
                }
            });
        }
        _ => return None,
    };
    Some(match decoded {
        Err(r) => refused(r, true, false),
        Ok((kind, header, cmd)) => match guard.check(kind, &header, now_unix_ms) {
            Err(r) => refused(r, false, true),
            Ok(()) => match validate(&cmd, limits, ctx) {
                Ok(()) => Parsed {
                    command: cmd,
                    undecodable: false,
                    replayed: false,
                },
                Err(r) => refused(r, false, false),
            },
        },
    })
}
#[cfg(test)]
mod tests {
    use super::*;
    use common::msg::GoalTarget;

    fn rid() -> RobotId {
        RobotId::new("husky-1").unwrap()
    }

    const NOW: u64 = 1_790_000_000_000;

    /// A command in its envelope, fresh at [`NOW`].
    fn env<T: serde::Serialize>(c: &T) -> Vec<u8> {
        let h = CmdHeader {
            sender: 1,
            seq: 1,
            t_unix_ms: NOW,
        };
        msg::encode_cmd(h, c)
    }

    fn parse(key: &str, b: &[u8]) -> Option<(Command, bool)> {
        let p = parse_command(
            &rid(),
            key,
            b,
            &CommandLimits::default(),
            &RobotContext::default(),
            &mut ReplayGuard::default(),
            NOW,
        )?;
        Some((p.command, p.undecodable))
    }

    #[test]
    fn valid_commands_pass() {
        let g = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Map {
                x_m: 3.0,
                y_m: -2.0,
            },
            tolerance_m: 0.5,
        };
        let (c, de) = parse("terranav/husky-1/cmd/goal", &env(&g)).unwrap();
        assert_eq!(c, Command::Goal(g));
        assert!(!de);
        let s = SpeedCmd { limit_mps: 0.7 };
        let (c, _) = parse("terranav/husky-1/cmd/speed", &env(&s)).unwrap();
        assert_eq!(c, Command::Speed(s));
    }

    #[test]
    fn bad_commands_are_refused_with_reasons() {
        let g = GoalCmd {
            goal_id: 1,
            target: GoalTarget::Gnss {
                lat_deg: 91.0,
                lon_deg: 0.0,
                h_m: None,
            },
            tolerance_m: 0.5,
        };
        let (c, de) = parse("terranav/husky-1/cmd/goal", &env(&g)).unwrap();
        assert!(
            matches!(c, Command::Refused(ref r) if r.code == RefusalCode::LatitudeOutOfRange),
            "{c:?}"
        );
        assert!(!de);
        let d = DriveCmd {
            seq: 1,
            v_mps: f32::NAN,
            omega_rps: 0.0,
            deadman: true,
        };
        let (c, _) = parse("terranav/husky-1/cmd/drive", &env(&d)).unwrap();
        assert!(matches!(c, Command::Refused(_)));
        let d = DriveCmd {
            seq: 1,
            v_mps: 5.0,
            omega_rps: 0.0,
            deadman: true,
        };
        let (c, _) = parse("terranav/husky-1/cmd/drive", &env(&d)).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.message.contains("speed")));
        // Schema 1, then a string that claims 9 bytes and has one invalid one.
        let (c, de) = parse("terranav/husky-1/cmd/stop", &[1, 9, 0xff]).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.code == RefusalCode::Undecodable));
        assert!(de);
        // Another schema version.
        let mut b = msg::encode(&StopCmd::default());
        b[0] = 7;
        let (c, de) = parse("terranav/husky-1/cmd/stop", &b).unwrap();
        assert!(matches!(c, Command::Refused(ref r) if r.message.contains("schema")));
        assert!(de);
        // Another robot's or a non-command key is not ours.
        assert!(parse(
            "terranav/husky-2/cmd/stop",
            &msg::encode(&StopCmd::default())
        )
        .is_none());
        assert!(parse("terranav/husky-1/pose", &[]).is_none());
    }

    #[test]
    fn a_command_sent_twice_is_refused_as_a_replay() {
        let mut guard = ReplayGuard::default();
        let b = env(&StopCmd::default());
        let mut go = |b: &[u8], now| {
            parse_command(
                &rid(),
                "terranav/husky-1/cmd/stop",
                b,
                &CommandLimits::default(),
                &RobotContext::default(),
                &mut guard,
                now,
            )
            .unwrap()
        };
        let first = go(&b, NOW + 3);
        assert!(matches!(first.command, Command::Stop(_)) && !first.replayed);
        let again = go(&b, NOW + 900);
        assert!(
            matches!(again.command, Command::Refused(ref r) if r.code == RefusalCode::Replayed),
            "{again:?}"
        );
        assert!(again.replayed && !again.undecodable);
        // A bare command without its envelope does not decode.
        let bare = go(&msg::encode(&StopCmd::default()), NOW + 901);
        assert!(bare.undecodable && !bare.replayed);
    }
}

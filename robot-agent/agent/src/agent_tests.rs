//! The agent's command and status contract, without sensors: zones refuse goals inside keep-out
//! (and sets for another session), a refusal leaves the status once a later command of its kind
//! is taken, and a teleop robot whose operator let go does not read "Driving".

use crate::command::{Command, CommandKind, GoalTarget};
use crate::mission::Phase;
use crate::zones::{ZoneRule, ZoneShape};
use crate::{Agent, AgentConfig, Identity};
use common::command::RefusalCode;

fn agent() -> Agent {
    Agent::new(
        AgentConfig::default(),
        Identity {
            robot: "husky-1".into(),
            session_id: "s1".into(),
            start_unix_ms: 0,
        },
    )
    .expect("default configuration")
}

fn zones(session: &str) -> CommandKind {
    CommandKind::Zones {
        version: 7,
        session_id: session.into(),
        zones: vec![ZoneShape {
            id: "z".into(),
            name: "pond".into(),
            rule: ZoneRule::KeepOut,
            polygon_m: vec![(4.0, -2.0), (6.0, -2.0), (6.0, 2.0), (4.0, 2.0)],
        }],
    }
}

fn goal(id: u32, x: f64, y: f64) -> CommandKind {
    CommandKind::Goal {
        id,
        target: GoalTarget::Map { x_m: x, y_m: y },
        tolerance_m: 0.0,
    }
}

#[test]
fn a_goal_inside_keep_out_is_refused_and_a_later_goal_clears_the_refusal() {
    let mut a = agent();
    let e = a.on_command(Command::at(0.0, zones("other"))).unwrap_err();
    assert_eq!(e.code, RefusalCode::ZoneFrameMismatch);
    a.on_command(Command::at(0.0, zones("s1"))).unwrap();
    assert_eq!(a.status(0.0).zones_version, 7);
    let mut old = zones("s1");
    if let CommandKind::Zones { version, zones, .. } = &mut old {
        *version = 6;
        zones.clear();
    }
    let e = a.on_command(Command::at(0.0, old)).unwrap_err();
    assert_eq!(
        e.code,
        RefusalCode::Replayed,
        "an older set never lifts a zone"
    );
    assert_eq!(a.status(0.0).zones_version, 7);
    let e = a
        .on_command(Command::at(1.0, goal(1, 5.0, 0.0)))
        .unwrap_err();
    assert_eq!(e.code, RefusalCode::GoalInKeepOut);
    assert!(e.message.contains("pond"), "{e}");
    let s = a.status(1.0);
    assert!(s.last_error.as_deref().unwrap_or("").contains("keep-out"));
    assert_eq!(s.commands_refused, 3);
    a.on_command(Command::at(2.0, goal(2, 9.0, 0.0))).unwrap();
    assert_eq!(
        a.status(2.0).last_error,
        None,
        "taken goal clears the refusal"
    );
    assert_eq!(a.status(2.0).goal_id, 2);
}

#[test]
fn a_released_teleop_robot_is_not_driving() {
    let mut a = agent();
    let drive = |seq, deadman| CommandKind::Drive {
        seq,
        v_mps: 0.3,
        omega_rps: 0.0,
        deadman,
    };
    a.on_command(Command::at(1.0, drive(1, true))).unwrap();
    assert_eq!(a.status(1.1).phase, Phase::Driving);
    // The deadman lapsed (no command for longer than deadman_s).
    assert_eq!(a.status(2.0).phase, Phase::Idle);
    assert!(!a.status(2.0).driving);
    // Released explicitly.
    a.on_command(Command::at(3.0, drive(2, false))).unwrap();
    assert_eq!(a.status(3.05).phase, Phase::Idle);
}

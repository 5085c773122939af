//! Whole missions on a small field in the simulator (slow: seconds each in release), checking
//! the outcomes the product promises.

use super::*;
use agent::command::{Command, CommandKind, GoalTarget};
use agent::mission::Phase;
use agent::AgentConfig;
use nalgebra::Vector3;

/// A 40 x 30 m field with a crate across the straight line to the goal.
pub(super) const FIELD: &str = r#"
name = "field"
datum = { lat_deg = 48.0, lon_deg = 11.0, h_m = 500.0 }
extent = { x_min_m = -10.0, x_max_m = 30.0, y_min_m = -15.0, y_max_m = 15.0 }
terrain = { undulation_amplitude_m = 0.05, grass_amplitude_m = 0.02 }
start = [{ x_m = 0.0, y_m = 0.0, yaw_deg = 0.0 }]
[[box]]
rect = { center_m = [8.0, 0.0], size_m = [1.0, 3.0] }
height_m = 0.8
[[tree]]
x_m = 5.0
y_m = 9.0
[[tree]]
x_m = 15.0
y_m = -9.0
[[tree]]
x_m = 24.0
y_m = 7.0
[[pole]]
x_m = 12.0
y_m = 5.0
[[pole]]
x_m = 20.0
y_m = -4.0
[[wall]]
points = [[-8.0, -12.0], [28.0, -12.0]]
height_m = 1.5
"#;

/// The field with a taught route (three legs, 30 m) for teach and repeat.
fn taught_field() -> sim::Scenario {
    let text = format!("{FIELD}\n[teach]\npoints = [[0.0, 0.0], [4.0, -6.0], [20.0, -6.0], [24.0, 0.0]]\nspeed_mps = 0.5\n");
    sim::Scenario::from_toml_str(&text, "<taught field>").unwrap()
}

#[test]
fn teach_and_repeat_detours_around_a_car_and_a_fallen_tree_and_rejoins() {
    // A car parked on the long leg and a fallen trunk (a low wall) across the diagonal one.
    let car: ObstacleFile = toml::from_str(
        "[[car]]\nx_m = 12.0\ny_m = -6.0\nyaw_deg = 0.0\nlength_m = 3.0\n\
         [[wall]]\npoints = [[23.04, -3.69], [20.96, -2.31]]\nthickness_m = 0.4\nheight_m = 0.4\n",
    )
    .unwrap();
    let opts = HeadlessOptions {
        timeout_s: 240.0,
        ..HeadlessOptions::default()
    };
    let rep = run_teach_repeat(&taught_field(), AgentConfig::default(), Some(&car), &opts).unwrap();
    eprintln!("{}", serde_json::to_string(&rep).unwrap());
    assert_eq!(rep.outcome, "reached", "{rep:?}");
    assert_eq!(rep.collisions, 0);
    assert_eq!(rep.detours, 2, "one detour per obstacle: {rep:?}");
    assert!(rep.rejoin_distance_m.iter().all(|d| *d <= 2.0), "{rep:?}");
    assert!(rep.final_error_m <= 0.3, "{rep:?}");
    // Issue 9: on free stretches RMS <= 5 cm, max <= 15 cm against the taught truth path.
    assert!(
        rep.tracking_rms_m <= 0.05 && rep.tracking_max_m <= 0.15,
        "{rep:?}"
    );
}

/// Up-axis error (degrees) of the agent on hilly ground: at the first scan, and the mean and
/// worst over the scans of a 20 m drive (each against the truth at mid-sweep, where the
/// de-skewed pose sits); also the true tilt at the start.
fn tilt_errors_on_hills(gravity: bool) -> (f64, f64, f64, f64) {
    let text = FIELD.replace(
        "terrain = { undulation_amplitude_m = 0.05, grass_amplitude_m = 0.02 }",
        "terrain = { undulation_amplitude_m = 0.4, undulation_wavelength_m = 12.0, grass_amplitude_m = 0.0 }",
    );
    let scenario = sim::Scenario::from_toml_str(&text, "<hills>").unwrap();
    let mut cfg = AgentConfig::default();
    cfg.slam.gravity.enabled = gravity;
    let mut rig = Rig::new(&scenario, cfg, &HeadlessOptions::default(), "hills").unwrap();
    let up_err = |rig: &Rig| {
        let truth = rig.sim.truth_pose_at(rig.t_s() - 0.05).unwrap().rotation;
        let est = rig.agent.localiser().pose_now().unwrap().iso.rotation;
        (est.inverse() * Vector3::z())
            .angle(&(truth.inverse() * Vector3::z()))
            .to_degrees()
    };
    let true_tilt = (rig.sim.truth_pose().rotation * Vector3::z())
        .angle(&Vector3::z())
        .to_degrees();
    while !rig.step().scan {}
    let first = up_err(&rig);
    let t = rig.t_s();
    rig.agent
        .on_command(Command::at(
            t,
            CommandKind::Goal {
                id: 1,
                target: GoalTarget::Map {
                    x_m: 20.0,
                    y_m: 3.0,
                },
                tolerance_m: 0.0,
            },
        ))
        .unwrap();
    let (mut worst, mut sum, mut n) = (0.0f64, 0.0, 0.0);
    while rig.t_s() < 90.0 && rig.agent.mission().nav().state() != Phase::Reached {
        if rig.step().scan && rig.t_s() > 2.0 {
            let e = up_err(&rig);
            worst = worst.max(e);
            sum += e;
            n += 1.0;
        }
    }
    assert_eq!(rig.agent.mission().nav().state(), Phase::Reached);
    (true_tilt, first, sum / n, worst)
}

#[test]
fn the_accelerometer_gives_the_frame_its_roll_on_hilly_ground() {
    let (tilt, first, mean, worst) = tilt_errors_on_hills(true);
    eprintln!("with IMU: start tilt {tilt:.2} deg; error at the first scan {first:.3}, while driving mean {mean:.3} worst {worst:.3}");
    assert!(
        tilt > 2.0,
        "the start must be on a slope for this test to mean anything: {tilt}"
    );
    assert!(
        first < 0.15,
        "start attitude from gravity: {first:.3} deg off"
    );
    assert!(
        mean < 0.2 && worst < 0.6,
        "attitude while driving: mean {mean:.3}, worst {worst:.3} deg off"
    );
    // The control: without the accelerometer the roll at the start is unknown (one antenna
    // baseline) and the GNSS track fit needs tens of metres to find it.
    let (_, first_blind, mean_blind, worst_blind) = tilt_errors_on_hills(false);
    eprintln!("without IMU: error at the first scan {first_blind:.3}, while driving mean {mean_blind:.3} worst {worst_blind:.3}");
    assert!(
        first_blind > 4.0 * first.max(0.05),
        "{first_blind} vs {first}"
    );
    assert!(mean_blind > 3.0 * mean, "{mean_blind} vs {mean}");
}

#[test]
fn a_pole_at_the_robots_shoulder_stops_it_then_is_detoured() {
    // A pole beside the long leg: its edge 0.38 m from the taught line, inside the safety
    // stop zone (half width 0.35 + 0.08) but outside the corridor the map is checked on
    // (narrowed here so that the map alone cannot see the pole in the way, as with a person
    // standing at the robot's shoulder whom the map has not caught).
    let narrow = || {
        let mut cfg = AgentConfig::default();
        cfg.repeat.corridor_margin_m = -0.25;
        cfg
    };
    let pole: ObstacleFile =
        toml::from_str("[[pole]]\nx_m = 12.0\ny_m = -5.54\nradius_m = 0.08\nheight_m = 1.5\n")
            .unwrap();
    let opts = HeadlessOptions {
        timeout_s: 150.0,
        ..HeadlessOptions::default()
    };
    let rep = run_teach_repeat(&taught_field(), narrow(), Some(&pole), &opts).unwrap();
    eprintln!("{}", serde_json::to_string(&rep).unwrap());
    assert_eq!(rep.outcome, "reached", "{rep:?}");
    assert_eq!(rep.collisions, 0);
    assert!(rep.detours >= 1, "{rep:?}");
    assert!(rep.final_error_m <= 0.3, "{rep:?}");
    // The control: a stop that never turns into a blockage waits at the pole for ever.
    let mut cfg = narrow();
    cfg.repeat.safety_stop_block_s = f64::INFINITY;
    // (Unhindered, the return takes 80 s.)
    let short = HeadlessOptions {
        timeout_s: 110.0,
        ..HeadlessOptions::default()
    };
    let stuck = run_teach_repeat(&taught_field(), cfg, Some(&pole), &short).unwrap();
    assert_eq!(stuck.outcome, "timeout", "{stuck:?}");
}

#[test]
fn drives_around_a_crate_to_a_map_goal() {
    let scenario = sim::Scenario::from_toml_str(FIELD, "<field>").unwrap();
    let rep = run_goal(
        &scenario,
        AgentConfig::default(),
        GoalTarget::Map {
            x_m: 16.0,
            y_m: 0.0,
        },
        &HeadlessOptions {
            timeout_s: 120.0,
            ..HeadlessOptions::default()
        },
    )
    .unwrap();
    eprintln!("{}", serde_json::to_string(&rep).unwrap());
    assert_eq!(rep.outcome, "reached", "{rep:?}");
    assert_eq!(rep.collisions, 0);
    assert!(rep.final_error_m < 0.5, "{}", rep.final_error_m);
    assert!(
        rep.path_length_m > 16.3,
        "went around the crate: {}",
        rep.path_length_m
    );
}

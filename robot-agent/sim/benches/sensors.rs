//! Sensor simulation cost: simulated VLP-16 sweeps per second (one full 10 Hz revolution,
//! 16 rings x 1800 azimuths = 28 800 rays) and simulated SR4000 depth frames per second
//! (176 x 144 = 25 344 rays), ray-cast against the built-in `park` world
//! (config/scenarios/park.toml: undulating grass, paths, curbs, 30 trees, benches, lamps,
//! 10 walkers). Goal: at least 100 VLP-16 scans/s on one core.
//!
//! Each iteration is one `Simulation::step` of one sensor period (0.1 s, cut by the simulator into
//! five 20 ms chunks) with only the measured sensor on (odometry and GNSS off), the robot standing
//! still. The sensor internals are crate-private, so this is the public path every user of the
//! simulator takes; the `sim_step_no_sensors` group measures what that step costs without any
//! sensor (plant, walkers), and it is small next to the ray casting.
//!
//! Poses in `park`:
//! - `park_path`: (-30, 0, 0 deg), on the main east-west path, where the evaluation drive ends.
//! - `park_busy`: (4.5, -7.0, -44 deg), on grass 3.6 m from a tree trunk (7.1, -9.5) that fills
//!   the depth camera's view, 3.5 m from the north-south walker lanes, near the central crossing.
//!
//! Baseline, same run: `flat_wall`, a flat world of the same 100 m x 100 m extent and 5 cm height
//! field with a single 6 m x 2 m wall 4 m ahead of the robot at (-30, 0, 0 deg) (seen by both
//! sensors), no grass, no walkers. The README's ratio is park / flat_wall time per scan.
//!
//! Throughput is one element per iteration, so criterion prints scans/s (frames/s).

use common::geom::Pose2;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sim::{Scenario, SimConfig, Simulation};
use std::hint::black_box;

/// One sensor period, seconds (both sensors run at 10 Hz).
const PERIOD_S: f64 = 0.1;

const FLAT_WALL: &str = r#"
name = "flat-wall"
datum = { lat_deg = 48.0, lon_deg = 11.0, h_m = 500.0 }
extent = { x_min_m = -50.0, x_max_m = 50.0, y_min_m = -50.0, y_max_m = 50.0 }
terrain = { resolution_m = 0.05, undulation_amplitude_m = 0.0, grass_amplitude_m = 0.0 }
start = [{ x_m = -30.0, y_m = 0.0, yaw_deg = 0.0 }]
[[wall]]
points = [[-26.0, -3.0], [-26.0, 3.0]]
height_m = 2.0
"#;

#[derive(Clone, Copy)]
enum Sensor {
    Lidar,
    Depth,
    None,
}

fn park() -> Scenario {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    Scenario::load(root.join("config/scenarios/park.toml")).expect("park scenario")
}

fn flat_wall() -> Scenario {
    Scenario::from_toml_str(FLAT_WALL, "<flat-wall>").expect("flat-wall scenario")
}

/// A standing robot with only `sensor` on, stepped past its first output; checks that every
/// step of one period yields exactly one scan (frame) and reports the points per output.
fn sim(scenario: &Scenario, pose: Pose2, sensor: Sensor, label: &str) -> Simulation {
    let mut cfg = SimConfig {
        start: Some(pose),
        ..SimConfig::default()
    };
    cfg.lidar.enabled = matches!(sensor, Sensor::Lidar);
    cfg.depth.enabled = matches!(sensor, Sensor::Depth);
    cfg.odom.enabled = false;
    cfg.gnss.enabled = false;
    let mut s = Simulation::new(scenario, cfg);
    let mut points = 0usize;
    const CHECK: usize = 20;
    for _ in 0..CHECK {
        let out = s.step(PERIOD_S, 0.0, 0.0);
        let produced = match sensor {
            Sensor::Lidar => out.scan,
            Sensor::Depth => out.depth,
            Sensor::None => continue,
        };
        let produced = produced.unwrap_or_else(|| panic!("{label}: a step without output"));
        points += produced.points.len();
    }
    assert_eq!(s.dropped_scans(), 0, "{label}: dropped scans");
    if !matches!(sensor, Sensor::None) {
        eprintln!("{label}: {} points per output on average", points / CHECK);
    }
    s
}

fn bench(c: &mut Criterion) {
    let park = park();
    let flat = flat_wall();
    let path_pose = Pose2::new(-30.0, 0.0, 0.0);
    let busy_pose = Pose2::new(4.5, -7.0, (-44.0f64).to_radians());
    let cases = [
        ("park_path", &park, path_pose),
        ("park_busy", &park, busy_pose),
        ("flat_wall", &flat, path_pose),
    ];

    for (group, sensor) in [
        ("vlp16_scan_16x1800", Sensor::Lidar),
        ("sr4000_frame_176x144", Sensor::Depth),
    ] {
        let mut g = c.benchmark_group(group);
        g.throughput(Throughput::Elements(1));
        for (name, scenario, pose) in cases {
            let mut s = sim(scenario, pose, sensor, &format!("{group}/{name}"));
            g.bench_function(name, |b| {
                b.iter(|| black_box(s.step(black_box(PERIOD_S), 0.0, 0.0)))
            });
        }
        g.finish();
    }

    let mut g = c.benchmark_group("sim_step_no_sensors");
    g.throughput(Throughput::Elements(1));
    for (name, scenario, pose) in cases {
        let mut s = sim(scenario, pose, Sensor::None, name);
        g.bench_function(name, |b| {
            b.iter(|| black_box(s.step(black_box(PERIOD_S), 0.0, 0.0)))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

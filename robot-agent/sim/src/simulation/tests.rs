use super::*;
use crate::plant::CollisionKind;
use common::geo::{parse_sentence, LocalFrame, Sentence};
use nalgebra::{Point3, Vector3};

fn scenario(extra: &str) -> Scenario {
    Scenario::from_toml_str(
        &format!(
            r#"
name = "simtest"
[datum]
lat_deg = 48.2
lon_deg = 16.4
h_m = 180.0
[extent]
x_min_m = -30.0
x_max_m = 30.0
y_min_m = -30.0
y_max_m = 30.0
[terrain]
undulation_amplitude_m = 0.1
undulation_wavelength_m = 20.0
grass_amplitude_m = 0.0
[[start]]
x_m = 0.0
y_m = 0.0
yaw_deg = 0.0
{extra}
"#
        ),
        "t",
    )
    .unwrap()
}

fn cfg(seed: u64) -> SimConfig {
    SimConfig {
        seed,
        ..Default::default()
    }
}

#[test]
fn the_imu_reads_gravity_in_the_body_frame_and_the_turns_centripetal_pull() {
    let sc = scenario("");
    let mut sim = Simulation::new(&sc, cfg(3));
    let mean_over = |sim: &mut Simulation, s: f64, v: f64, w: f64| {
        let mut sum = Vector3::zeros();
        let mut n = 0.0;
        let mut up_body = Vector3::zeros();
        for _ in 0..(s / 0.02) as usize {
            let out = sim.step(0.02, v, w);
            for i in &out.imu {
                sum += Vector3::from(i.accel_mps2);
                n += 1.0;
                up_body += sim.truth_pose().rotation.inverse() * Vector3::z();
            }
        }
        (sum / n, up_body / n, n)
    };
    // Standing on the undulating ground: gravity along the true body up axis, within the bias.
    let (f, up, n) = mean_over(&mut sim, 1.0, 0.0, 0.0);
    assert!((49.0..=51.0).contains(&n), "{n} samples in 1 s at 50 Hz");
    assert!(
        (f - up * 9.806_65).norm() < 0.05,
        "{f:?} vs {:?}",
        up * 9.806_65
    );
    // Driving a steady circle (0.5 m/s, 0.5 rad/s): 0.25 m/s^2 towards the centre (body +y).
    mean_over(&mut sim, 2.0, 0.5, 0.5);
    let (f, up, _) = mean_over(&mut sim, 2.0, 0.5, 0.5);
    let lateral = f - up * 9.806_65;
    assert!((lateral.y - 0.25).abs() < 0.05, "{lateral:?}");
    assert!(lateral.x.abs() < 0.05, "{lateral:?}");
}

#[test]
fn scans_are_full_rotations_with_sweep_times() {
    let mut sim = Simulation::new(&scenario(""), cfg(1));
    let mut scans = Vec::new();
    for _ in 0..25 {
        if let Some(s) = sim.step(0.02, 0.8, 0.1).scan {
            scans.push(s);
        }
    }
    // Sweeps start at 0.0, 0.1, ..., 0.4: five rotations are complete at t = 0.5 s.
    assert_eq!(scans.len(), 5, "10 Hz over 0.5 s");
    for (k, s) in scans.iter().enumerate() {
        assert!((s.stamp_s - 0.1 * k as f64).abs() < 1e-9);
        assert!(s.points.len() > 10_000, "{}", s.points.len());
        assert!(s
            .points
            .iter()
            .all(|p| (0.0..0.1).contains(&p.t_s) && p.ring < 16));
        let rings: std::collections::BTreeSet<u16> = s.points.iter().map(|p| p.ring).collect();
        assert!(rings.len() >= 8, "downward rings all hit ground: {rings:?}");
    }
    // Ring 0 is -15 deg: those points lie ~0.75 m below the sensor.
    let z: Vec<f32> = scans[0]
        .points
        .iter()
        .filter(|p| p.ring == 0)
        .map(|p| p.z)
        .collect();
    let mean = z.iter().sum::<f32>() / z.len() as f32;
    assert!((mean + 0.75).abs() < 0.1, "{mean}");
}

#[test]
fn same_seed_same_output() {
    let run = |seed| {
        let mut sim = Simulation::new(&scenario(""), cfg(seed));
        let mut out = Vec::new();
        for _ in 0..10 {
            if let Some(s) = sim.step(0.02, 0.5, 0.0).scan {
                out.push(s);
            }
        }
        out
    };
    assert_eq!(run(3), run(3));
    assert_ne!(run(3), run(4));
}

#[test]
fn recorded_poses_match_the_plant_truth() {
    let dir = tempfile::tempdir().unwrap();
    let mut sim = Simulation::new(&scenario(""), cfg(2));
    let mut rec = crate::record::Recorder::create(dir.path(), false).unwrap();
    // Truth of the LiDAR frame at every step end; stamps fall on multiples of 0.1 s = 5 steps.
    let mut truth = vec![sim.truth_pose() * sim.lidar_extrinsic()];
    for k in 0..150 {
        let w = if k < 75 { 0.3 } else { -0.4 };
        let out = sim.step(0.02, 0.7, w);
        rec.write_step(&sim, &out).unwrap();
        truth.push(sim.truth_pose() * sim.lidar_extrinsic());
    }
    let n = rec.scans();
    rec.finish(&sim).unwrap();
    let poses = sensing::sequence::read_poses(dir.path()).unwrap();
    let stamps = sensing::sequence::read_stamps(dir.path()).unwrap().unwrap();
    assert_eq!(poses.len(), n);
    assert_eq!(n, 30, "10 Hz over 3 s");
    assert_eq!(sensing::sequence::cloud_files(dir.path()).unwrap().len(), n);
    for (p, t) in poses.iter().zip(&stamps) {
        let k = (t / 0.02).round() as usize;
        let want = &truth[k];
        assert!(
            (p.translation.vector - want.translation.vector).norm() < 1e-6,
            "stamp {t}"
        );
        assert!(p.rotation.angle_to(&want.rotation) < 1e-6);
    }
    // The robot did move and turn.
    assert!((poses[28].translation.vector - poses[0].translation.vector).norm() > 1.5);
    let odom = sensing::sequence::read_odometry(dir.path())
        .unwrap()
        .unwrap();
    assert_eq!(odom.len(), 150);
}

#[test]
fn walkers_occlude_the_wall() {
    // Walker crossing in front of the robot at x = 5, wall at x = 10.
    let sc = scenario(
        "[[wall]]\npoints = [[10.0, -20.0], [10.0, 20.0]]\nheight_m = 3.0\n\
         [[walker]]\npoints = [[5.0, -6.5], [5.0, 6.5]]\nmode = \"ping_pong\"\n",
    );
    let mut sim = Simulation::new(&sc, cfg(1));
    let mut scan = None;
    // The walker is at y = 0 at t = 5 s; take the scan covering it.
    for _ in 0..260 {
        if let Some(s) = sim.step(0.02, 0.0, 0.0).scan {
            if (s.stamp_s - 5.0).abs() < 0.06 {
                scan = Some(s);
            }
        }
    }
    let scan = scan.unwrap();
    let w = sim.world().walkers_at(5.0)[0];
    assert!(w.y_m.abs() < 0.2, "{w:?}");
    // Horizontal-ish rings straight ahead: the walker at ~4.75 m, not the wall at 9.85 m.
    let ahead: Vec<f32> = scan
        .points
        .iter()
        .filter(|p| p.ring >= 7 && p.ring <= 10 && p.x > 0.0 && (p.y / p.x).abs() < 0.02)
        .map(|p| p.x)
        .collect();
    assert!(!ahead.is_empty());
    assert!(ahead.iter().all(|&x| (x - 4.77).abs() < 0.15), "{ahead:?}");
    // Aside the walker the wall is seen.
    let side = scan
        .points
        .iter()
        .filter(|p| p.ring == 8 && p.x > 0.0 && (p.y / p.x - 0.3).abs() < 0.02)
        .count();
    let wall = scan
        .points
        .iter()
        .filter(|p| {
            p.ring == 8 && p.x > 0.0 && (p.y / p.x - 0.3).abs() < 0.02 && (p.x - 9.8).abs() < 0.3
        })
        .count();
    assert!(side > 0 && wall == side, "{side} {wall}");
    // Walkers walk at walking speed.
    let a = sim.world().walkers_at(1.0)[0];
    let b = sim.world().walkers_at(2.0)[0];
    assert!(((b.y_m - a.y_m).abs() - 1.3).abs() < 1e-9);
}

#[test]
fn a_runner_passing_close_beside_a_standing_robot_waits_instead_of_brushing_it() {
    // A runner (2.5 m/s, radius 0.35 m) on a line 0.3 m from the robot's side, starting
    // 0.7 m behind its rear: where it will be a second later is farther from the robot than
    // where it is, so only the path between, past the robot's flank, comes close.
    let sc = scenario(
        "[[walker]]\npoints = [[-6.0, 0.65], [6.0, 0.65]]\nmode = \"ping_pong\"\nphase_m = 4.8\nspeed_mps = 2.5\nradius_m = 0.35\n",
    );
    let mut sim = Simulation::new(&sc, cfg(1));
    let mut hits = 0;
    for _ in 0..500 {
        hits += sim.step(0.02, 0.0, 0.0).collisions.len();
    }
    assert_eq!(hits, 0, "the walker walked into the robot");
    assert!(
        sim.walker_wait_s() > 5.0,
        "waited {} s",
        sim.walker_wait_s()
    );
}

#[test]
fn gnss_parses_back_to_the_truth() {
    let sc = scenario("[[wall]]\npoints = [[-20.0, 6.0], [20.0, 6.0]]\nheight_m = 6.0\n");
    let mut sim = Simulation::new(&sc, cfg(5));
    let frame = LocalFrame::new(sc.datum());
    let primary = Point3::from(Vector3::from(sim.robot().gnss.primary_xyz_m));
    let (mut n_gga, mut n_avr, mut max_err, mut max_yaw_err) = (0, 0, 0.0f64, 0.0f64);
    let mut qualities = Vec::new();
    for k in 0..600 {
        // Drive 4 s east, turn left for 2 s (~90 deg), then 6 s north toward the wall, which
        // starts 6 m away: RTK is lost within 4 m of it.
        let (v, w) = if k < 200 {
            (0.5, 0.0)
        } else if k < 300 {
            (0.0, 0.785)
        } else {
            (0.5, 0.0)
        };
        let out = sim.step(0.02, v, w);
        let truth = sim.truth_pose();
        for g in &out.gnss {
            match parse_sentence(&g.text).unwrap() {
                Sentence::Gga(gga) => {
                    n_gga += 1;
                    qualities.push(gga.quality);
                    if gga.quality == 4 {
                        let lla = common::msg::Datum {
                            lat_deg: gga.lat_deg.unwrap(),
                            lon_deg: gga.lon_deg.unwrap(),
                            h_m: gga.alt_hae_m().unwrap(),
                        };
                        let enu = frame.lla_to_enu(&lla);
                        let want = truth * primary;
                        max_err = max_err.max((enu.xy() - want.coords.xy()).norm());
                    }
                }
                Sentence::Avr(avr) => {
                    n_avr += 1;
                    if avr.quality == 3 {
                        let yaw_enu = (90.0 - avr.yaw_deg.unwrap()).to_radians();
                        let truth_yaw = Pose2::from_isometry3(&truth).yaw_rad;
                        max_yaw_err =
                            max_yaw_err.max(common::geom::wrap_angle(yaw_enu - truth_yaw).abs());
                    }
                }
                other => panic!("unexpected {other:?}"),
            }
        }
    }
    // 10 Hz over 12 s, counting the fix of the first step and the one at t = 12 s.
    assert_eq!(n_gga, 121);
    assert_eq!(n_avr, 121);
    assert!(max_err < 0.08, "RTK fixed error {max_err} m");
    assert!(max_yaw_err < 1f64.to_radians(), "{max_yaw_err}");
    assert_eq!(qualities[0], 4);
    assert!(
        qualities.iter().any(|&q| q == 1 || q == 0),
        "RTK lost near the wall: {qualities:?}"
    );
}

/// GGA qualities along a 12 s drive east at 1 m/s, with the primary antenna's true x.
fn gga_along_a_drive_east(sc: &Scenario) -> Vec<(f64, u8)> {
    // Only the receiver matters here: the scanners off keep the test to a fraction of a second.
    let mut c = cfg(2);
    c.lidar.enabled = false;
    c.depth.enabled = false;
    let mut sim = Simulation::new(sc, c);
    let primary = Point3::from(Vector3::from(sim.robot().gnss.primary_xyz_m));
    let mut out = Vec::new();
    for _ in 0..600 {
        let step = sim.step(0.02, 1.0, 0.0);
        let x = (sim.truth_pose() * primary).x;
        for g in &step.gnss {
            if let Sentence::Gga(gga) = parse_sentence(&g.text).unwrap() {
                out.push((x, gga.quality));
            }
        }
    }
    out
}

#[test]
fn gnss_denied_areas_switch_rtk_off_inside() {
    // A 3 m wide strip across the drive, 3..6 m east of the start.
    let area = "[[gnss_denied]]\npoints = [[3.0, -10.0], [6.0, -10.0], [6.0, 10.0], [3.0, 10.0]]\n";
    let none = gga_along_a_drive_east(&scenario(area));
    let inside = |x: f64| (3.05..5.95).contains(&x);
    assert!(none.iter().filter(|(x, _)| inside(*x)).count() >= 20);
    for (x, q) in &none {
        if inside(*x) {
            assert_eq!(*q, 0, "fix inside the denied area at x = {x}");
        } else if *x < 2.95 {
            assert_eq!(*q, 4, "RTK before the area at x = {x}");
        } else if *x > 6.05 {
            // RTK comes back through float, as after any loss.
            assert!(*q == 5 || *q == 4, "x = {x}: quality {q}");
        }
    }
    assert!(none.iter().any(|(x, q)| *x > 6.05 && *q == 5));
    // The degraded variant: a single-point fix, no RTK.
    let single = gga_along_a_drive_east(&scenario(&format!("{area}fix = \"single\"\n")));
    assert!(single
        .iter()
        .filter(|(x, _)| inside(*x))
        .all(|(_, q)| *q == 1));
    // Without the area the same drive keeps RTK fixed.
    assert!(gga_along_a_drive_east(&scenario(""))
        .iter()
        .all(|(_, q)| *q == 4));
    // A degenerate polygon is refused with its field named.
    let err = Scenario::from_toml_str(
        "name = \"x\"\n[datum]\nlat_deg = 48.0\nlon_deg = 16.0\nh_m = 0.0\n[extent]\nx_min_m = -1.0\nx_max_m = 1.0\ny_min_m = -1.0\ny_max_m = 1.0\n\
             [[gnss_denied]]\npoints = [[0.0, 0.0], [1.0, 0.0]]\n",
        "t",
    )
    .unwrap_err();
    assert!(err.to_string().contains("gnss_denied[0].points"), "{err}");
}

#[test]
fn odometry_reads_two_percent_long() {
    let mut sim = Simulation::new(&scenario(""), cfg(1));
    let mut last = None;
    for _ in 0..500 {
        if let Some(o) = sim.step(0.02, 1.0, 0.0).odom {
            last = Some(o);
        }
    }
    let o = last.unwrap();
    let odom_m = o.pose_odom.x_m.hypot(o.pose_odom.y_m);
    let truth_m = sim.truth_pose2().x_m;
    assert!(
        (odom_m / truth_m - 1.02).abs() < 0.005,
        "{odom_m} vs {truth_m}"
    );
    assert!(o.pose_odom.yaw_rad.abs() > 0.005, "yaw drift");
}

#[test]
fn depth_frames_see_the_ground_ahead() {
    let mut sim = Simulation::new(&scenario(""), cfg(1));
    let out = sim.step(0.02, 0.0, 0.0);
    let d = out.depth.unwrap();
    assert!(d.points.len() > 20_000, "{}", d.points.len());
    assert!(d.points.iter().all(|p| p.range_m() <= 5.0 && p.x > 0.0));
    // Map-frame z of the points: ground, within the terrain's undulation.
    let cam = sim.truth_pose() * sim.depth_extrinsic();
    for p in d.points.iter().step_by(97) {
        let q = cam * Point3::new(p.x as f64, p.y as f64, p.z as f64);
        let g = sim.world().ground_height(q.x, q.y).unwrap();
        assert!((q.z - g).abs() < 0.05, "{} vs {g}", q.z);
    }
}

#[test]
fn added_obstacle_blocks_the_robot() {
    let mut sim = Simulation::new(&scenario(""), cfg(1));
    sim.add_obstacles(&[Obstacle::Car(crate::scenario::CarSpec {
        x_m: 6.0,
        y_m: 0.0,
        yaw_deg: 90.0,
        length_m: 4.5,
        width_m: 1.8,
        height_m: 1.5,
    })]);
    let mut events = Vec::new();
    for _ in 0..600 {
        events.extend(sim.step(0.02, 0.8, 0.0).collisions);
    }
    assert_eq!(events.len(), 1, "{events:?}");
    assert_eq!(events[0].kind, CollisionKind::Obstacle);
    assert!(sim.truth_pose2().x_m < 6.0 - 0.9 - 0.5 + 0.01);
    assert_eq!(sim.collision_count(), 1);
}

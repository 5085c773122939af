//! Pose graph tests: synthetic loops, GNSS outages and loop verification.

use super::*;
use crate::config::FilterConfig;
use crate::filters::normals_and_density;
use crate::place::tests::{pose, scan, world};
use crate::se3;
use nalgebra::Vector6;
use rand::{rngs::StdRng, Rng, SeedableRng};

/// Truth poses along a closed square of side `side_m`, one every `step_m`, turning left at the
/// corners; the last pose is the first again.
fn square(side_m: f64, step_m: f64) -> Vec<Isometry3<f64>> {
    let per_side = (side_m / step_m).round() as usize;
    let mut out = Vec::new();
    let mut t = Isometry3::identity();
    for _ in 0..4 {
        for _ in 0..per_side {
            out.push(t);
            t *= se3::from_xyz_rpy([step_m, 0.0, 0.0], [0.0, 0.0, 0.0]);
        }
        t *= se3::from_xyz_rpy([0.0, 0.0, 0.0], [0.0, 0.0, std::f64::consts::FRAC_PI_2]);
    }
    out.push(out[0]);
    out
}

/// Odometry drifting from the truth: each step gets a yaw bias, a scale error and noise.
fn drifted(truth: &[Isometry3<f64>], yaw_bias_rad: f64, seed: u64) -> Vec<Isometry3<f64>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut out = vec![truth[0]];
    for w in truth.windows(2) {
        let step = w[0].inverse() * w[1];
        let noise = Vector6::from_fn(|k, _| {
            if k < 3 {
                rng.random_range(-0.0005..0.0005)
            } else {
                rng.random_range(-0.005..0.005)
            }
        });
        let scaled = Isometry3::from_parts(
            (step.translation.vector * 1.005).into(),
            step.rotation * UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_bias_rad),
        );
        out.push(out.last().unwrap() * scaled * se3::exp(&noise));
    }
    out
}

fn position_errors(g: &PoseGraph, truth: &[Isometry3<f64>]) -> Vec<f64> {
    g.keyframes()
        .iter()
        .zip(truth)
        .map(|(k, t)| (k.pose.translation.vector - t.translation.vector).norm())
        .collect()
}

/// The largest change the optimisation made to one keyframe-to-keyframe step, metres: how far
/// the optimised step moves the next keyframe from where the odometry step put it. A snap to
/// the returning fix would show the whole drift here at one keyframe.
fn largest_step_change(g: &PoseGraph) -> f64 {
    g.keyframes()
        .windows(2)
        .map(|k| {
            let odom = k[0].odom_pose.inverse() * k[1].odom_pose;
            let opt = k[0].pose.inverse() * k[1].pose;
            se3::translation_norm(&(odom.inverse() * opt))
        })
        .fold(0.0, f64::max)
}

fn max(v: &[f64]) -> f64 {
    v.iter().cloned().fold(0.0, f64::max)
}

#[test]
fn square_loop_is_corrected_by_one_loop_factor() {
    // 300 m square (75 m sides), a keyframe every 2 m, 0.05 deg of yaw drift per keyframe
    // (0.025 deg/m, at the odometry model's one sigma) and 0.5 % scale error.
    let truth = square(75.0, 2.0);
    let odom = drifted(&truth, 0.05f64.to_radians(), 1);
    let mut g = PoseGraph::new(GraphConfig::default());
    for (i, o) in odom.iter().enumerate() {
        g.add_keyframe(i as f64, *o, None);
    }
    let before = position_errors(&g, &truth);
    let n = truth.len() - 1;
    // The last keyframe is back at the first: the loop measures the truth relative pose.
    g.add_loop(0, n, truth[0].inverse() * truth[n]);
    let report = g.optimise();
    let after = position_errors(&g, &truth);
    println!(
        "square loop: max error {:.2} m -> {:.3} m, end {:.2} m -> {:.3} m, {} iterations",
        max(&before),
        max(&after),
        before[n],
        after[n],
        report.iterations
    );
    assert!(
        max(&before) > 5.0,
        "drift too small to test: {}",
        max(&before)
    );
    assert!(report.final_cost < report.initial_cost);
    assert!(after[n] < 0.1, "end error {}", after[n]);
    assert!(max(&after) < 1.0, "max error after {}", max(&after));
    // The correction is spread: no optimised step departs much from its odometry step.
    let jump = largest_step_change(&g);
    println!("square loop: largest step change {jump:.3} m");
    assert!(jump < 0.2, "correction jumps {jump} m between keyframes");
}

#[test]
fn gnss_after_an_outage_pulls_the_stretch_back_smoothly() {
    // 400 m along a gentle curve, a keyframe every 2 m; RTK lost for keyframes 60..140.
    let truth: Vec<Isometry3<f64>> = (0..200)
        .map(|i| {
            let s = i as f64 * 2.0;
            let yaw = 0.3 * (s / 100.0).sin();
            pose(s, 20.0 * (s / 100.0).sin(), yaw)
        })
        .collect();
    let odom = drifted(&truth, 0.1f64.to_radians(), 2);
    let mut g = PoseGraph::new(GraphConfig::default());
    let mut rng = StdRng::seed_from_u64(3);
    let outage = 60..140;
    let mut snapped_jump = 0.0f64;
    for (i, o) in odom.iter().enumerate() {
        let kf = g.add_keyframe(i as f64, *o, None);
        if !outage.contains(&i) {
            let noise = Vector3::new(
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.03..0.03),
            );
            g.add_gnss(kf, truth[i].translation.vector + noise, 0.02, 0.03);
            // Optimise as the agent would: while RTK holds and when it returns.
            if i < outage.start || i == outage.end {
                if i == outage.end {
                    // What a position snap would do: jump by the drift accumulated.
                    snapped_jump = (g.keyframes()[kf].pose.translation.vector
                        - truth[i].translation.vector)
                        .norm();
                }
                g.optimise();
            }
        }
    }
    g.optimise();
    let err = position_errors(&g, &truth);
    let worst_outage = max(&err[outage.clone()]);
    let worst_jump = largest_step_change(&g);
    println!(
        "gnss outage: drift at return {snapped_jump:.2} m, worst error in outage after {worst_outage:.3} m, \
         largest correction step between keyframes {worst_jump:.3} m"
    );
    assert!(
        snapped_jump > 3.0,
        "drift too small to test: {snapped_jump}"
    );
    assert!(worst_outage < 1.0, "outage stretch error {worst_outage}");
    assert!(max(&err[..outage.start]) < 0.1);
    assert!(max(&err[outage.end..]) < 0.1);
    assert!(
        worst_jump < snapped_jump / 10.0,
        "correction jumps {worst_jump} m between keyframes"
    );
}

fn oriented(points: Vec<[f32; 3]>) -> Arc<OrientedCloud> {
    let cfg = FilterConfig {
        max_density_per_m3: 0.0,
        ..FilterConfig::default()
    };
    Arc::new(normals_and_density(
        points,
        [0.0; 3],
        &cfg,
        &mut StdRng::seed_from_u64(1),
    ))
}

#[test]
fn verification_accepts_a_true_loop_and_rejects_a_wrong_one() {
    let w = world(4, 200.0, 200);
    let cfg = GraphConfig::default();
    let a = pose(0.0, 0.0, 0.2);
    let b = pose(1.2, -0.8, 0.2 + 0.9);
    let elsewhere = pose(50.0, 40.0, 0.2);
    let ca = oriented(scan(&w, &a, 40.0, 1));
    let cb = oriented(scan(&w, &b, 40.0, 2));
    let ce = oriented(scan(&w, &elsewhere, 40.0, 3));
    // The descriptor's yaw seeds the ICP, as in detect_loop.
    let sa = ScanContext::new(&ca.points, 60.0, 2.0);
    let sb = ScanContext::new(&cb.points, 60.0, 2.0);
    let (_, yaw) = sb.distance(&sa);
    let init = Isometry3::from_parts(
        Default::default(),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
    );
    let (measured, inl, rms) = verify_loop(&cb, &ca, &init, &cfg).expect("true loop accepted");
    let truth = a.inverse() * b;
    let d = truth.inverse() * measured;
    println!(
        "true loop: inliers {inl:.2}, rms {rms:.3} m, error {:.3} m {:.4} rad",
        se3::translation_norm(&d),
        se3::rotation_angle(&d)
    );
    assert!(se3::translation_norm(&d) < 0.1 && se3::rotation_angle(&d) < 0.01);
    // The same scan against another place, with the best the descriptor offers.
    let se = ScanContext::new(&ce.points, 60.0, 2.0);
    let (_, yaw_e) = sb.distance(&se);
    let init_e = Isometry3::from_parts(
        Default::default(),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_e),
    );
    let wrong = verify_loop(&cb, &ce, &init_e, &cfg);
    println!("wrong loop: {wrong:?}");
    assert!(wrong.is_err(), "wrong loop accepted: {wrong:?}");
}

/// Two parallel walls 3 m high along x, 6 m apart, sampled every 0.3 m: a corridor.
fn corridor() -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for i in 0..=600 {
        let x = -90.0 + 0.3 * i as f32;
        for j in 0..=10 {
            let z = 0.3 * j as f32;
            v.push([x, -3.0, z]);
            v.push([x, 3.0, z]);
        }
    }
    v
}

#[test]
fn a_true_revisit_is_pinned_in_every_direction_and_a_fit_sliding_along_walls_is_not() {
    let cfg = GraphConfig::default();
    // A true revisit among boxes (as above): accepted, and its paired normals pin x, y and z.
    let w = world(4, 200.0, 200);
    let a = pose(0.0, 0.0, 0.2);
    let b = pose(1.2, -0.8, 0.2 + 0.9);
    let ca = oriented(scan(&w, &a, 40.0, 1));
    let cb = oriented(scan(&w, &b, 40.0, 2));
    let init = a.inverse() * b * se3::from_xyz_rpy([0.3, -0.2, 0.0], [0.0, 0.0, 0.05]);
    let index = crate::index::KdIndex::build(&ca.points);
    let (measured, inl, rms) = verify_loop(&cb, &ca, &init, &cfg).expect("true loop accepted");
    let true_c = translation_constraint(&cb, &ca, &index, &measured, 1.0);
    println!("true revisit: inliers {inl:.2}, rms {rms:.3} m, constraint {true_c:.4}");
    assert!(true_c >= cfg.loop_min_constraint, "{true_c}");
    // A corridor: the robot 4 m further along it taken for the same place. The walls fit
    // their walls at any offset along them and the ground rings are flat, so the ICP explains
    // the scan as well as at a true revisit; only the directions the normals pin tell.
    let w = corridor();
    let here = pose(0.0, 0.0, 0.0);
    let further = pose(4.0, 0.0, 0.0);
    let ch = oriented(scan(&w, &here, 40.0, 4));
    let cf = oriented(scan(&w, &further, 40.0, 5));
    let index = crate::index::KdIndex::build(&ch.points);
    let slid = cfg_without_constraint(&cfg);
    let (m, inl, rms) =
        verify_loop(&cf, &ch, &Isometry3::identity(), &slid).expect("the inlier gate passes it");
    let c = translation_constraint(&cf, &ch, &index, &m, 1.0);
    let err = (m.translation.vector - (here.inverse() * further).translation.vector).norm();
    println!(
        "corridor 4 m apart: inliers {inl:.2}, rms {rms:.3} m, constraint {c:.5}, error {err:.2} m"
    );
    assert!(err > 2.0, "the fit slid: {err} m off the truth");
    assert!(c < 0.1 * true_c, "{c} against {true_c}");
    let got = verify_loop(&cf, &ch, &Isometry3::identity(), &cfg);
    assert!(
        matches!(got, Err(LoopRejection::Degenerate { .. })),
        "a sliding fit is not a loop: {got:?}"
    );
}

/// `cfg` with the constraint test off: what the verification accepted before it.
fn cfg_without_constraint(cfg: &GraphConfig) -> GraphConfig {
    GraphConfig {
        loop_min_constraint: 0.0,
        ..cfg.clone()
    }
}

/// Drives the circuit `truth` through the synthetic world `w` with odometry `odom`, a keyframe and
/// its scan at every pose, and a loop search after each; returns the graph and the loops found.
fn drive_circuit(
    cfg: GraphConfig,
    w: &[[f32; 3]],
    truth: &[Isometry3<f64>],
    odom: &[Isometry3<f64>],
) -> (PoseGraph, Vec<LoopClosure>) {
    let mut g = PoseGraph::new(cfg);
    let mut closures = Vec::new();
    for (i, (t, o)) in truth.iter().zip(odom).enumerate() {
        let kf = g.add_keyframe(
            i as f64,
            *o,
            Some(oriented(scan(w, t, 40.0, 10 + i as u64))),
        );
        if let Ok(c) = g.detect_loop(kf) {
            closures.push(c);
        }
    }
    (g, closures)
}

/// The loops include one from the circuit's end back to its start, and every one is a true
/// revisit (within the keyframe spacing).
fn assert_true_loops_back_to_the_start(closures: &[LoopClosure], truth: &[Isometry3<f64>]) {
    let n = truth.len() - 1;
    assert!(
        closures.iter().any(|c| c.to == n && c.from <= 1),
        "no loop back to the start: {closures:?}"
    );
    for c in closures {
        let d = (truth[c.from].translation.vector - truth[c.to].translation.vector).norm();
        assert!(d < 4.5, "false loop {c:?} ({d} m apart)");
    }
}

#[test]
fn detected_loop_closes_a_drifted_circuit() {
    // A 160 m square circuit through the synthetic world, a keyframe every 4 m with its scan;
    // the odometry drifts 0.1 deg of yaw per keyframe and 0.5 % in scale. Back at the start, the place is found,
    // verified and the graph pulls the end back.
    let w = world(5, 200.0, 200);
    let truth = square(40.0, 4.0);
    let odom = drifted(&truth, 0.1f64.to_radians(), 6);
    let cfg = GraphConfig {
        loop_exclude_recent_s: 10.0,
        ..GraphConfig::default()
    };
    let (mut g, closures) = drive_circuit(cfg, &w, &truth, &odom);
    let n = truth.len() - 1;
    let before = position_errors(&g, &truth)[n];
    assert_true_loops_back_to_the_start(&closures, &truth);
    g.optimise();
    let after = position_errors(&g, &truth)[n];
    println!(
        "detected loop: {} closures, end error {before:.2} m -> {after:.3} m",
        closures.len()
    );
    assert!(before > 1.0, "drift too small to test: {before}");
    assert!(after < 0.15, "end error after {after}");
}

#[test]
fn a_revisit_the_descriptor_misses_is_found_near_the_graphs_own_pose() {
    // The same circuit with little drift, and a descriptor that never matches (as in an open,
    // repetitive world where the best match is another place): the nearest older keyframe by
    // the graph's own poses is verified instead, and closes the loop back at the start.
    let w = world(5, 200.0, 200);
    let truth = square(40.0, 4.0);
    let odom = drifted(&truth, 0.02f64.to_radians(), 6);
    let run = |radius_m: f64| {
        let cfg = GraphConfig {
            loop_exclude_recent_s: 10.0,
            place_max_distance: 0.0,
            loop_search_radius_m: radius_m,
            ..GraphConfig::default()
        };
        drive_circuit(cfg, &w, &truth, &odom)
    };
    let (_, none) = run(0.0);
    assert!(none.is_empty(), "the descriptor alone found {none:?}");
    let (mut g, closures) = run(5.0);
    let n = truth.len() - 1;
    assert_true_loops_back_to_the_start(&closures, &truth);
    let before = position_errors(&g, &truth)[n];
    g.optimise();
    let after = position_errors(&g, &truth)[n];
    println!(
        "proximity loop: {} closures, end error {before:.3} m -> {after:.3} m",
        closures.len()
    );
    assert!(
        after < before && after < 0.1,
        "end error {before} -> {after}"
    );
}

/// Height of the rolling ground of [`ring_scan`] at world `(x, y)`, metres.
fn ground_z(x: f32, y: f32) -> f32 {
    0.4 * (x / 6.0).sin() * (y / 9.0).cos()
}

/// What a 16-beam spinning lidar at `pose` (world<-sensor, 1.5 m above the ground) sees of
/// `world` within `range_m`: the objects' points as [`scan`] keeps them, and the rolling ground
/// ([`ground_z`]) only on the eight rings its downward beams (-15..-1 deg, 2 deg apart) draw,
/// one point every 0.5 deg. Sweeps from places a metre apart share no ground ring, and one ring
/// alone is a curve, not a surface.
fn ring_scan(world: &[[f32; 3]], pose: &Isometry3<f64>, range_m: f32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    let inv = pose.inverse().cast::<f32>();
    let fwd = pose.cast::<f32>();
    let mut out: Vec<[f32; 3]> = world
        .iter()
        .map(|p| inv * nalgebra::Point3::from(*p))
        .filter(|q| q.coords.xy().norm() < range_m && rng.random_bool(0.8))
        .map(|q| [q.x, q.y, q.z])
        .collect();
    let height = pose.translation.vector.z as f32;
    for ring in 0..8 {
        let r = height / (15.0f32 - 2.0 * ring as f32).to_radians().tan();
        if r > range_m {
            continue;
        }
        for k in 0..720 {
            let a = (k as f32 * 0.5).to_radians();
            let w = fwd * nalgebra::Point3::new(r * a.cos(), r * a.sin(), -height);
            let g = inv * nalgebra::Point3::new(w.x, w.y, ground_z(w.x, w.y));
            out.push([g.x, g.y, g.z + rng.random_range(-0.01..0.01)]);
        }
    }
    out
}

#[test]
fn a_revisit_between_the_old_sweeps_is_verified_against_their_submap() {
    // A straight pass along y = 0, a keyframe every 2 m; much later the robot comes back
    // between two of them, 0.7 m to the side and turned. Against the nearest old keyframe alone
    // its ground rings find no partner (the rings are where each sweep's beams hit the ground),
    // so the ICP explains too little of the sweep; against that keyframe's neighbours in its
    // frame it is verified, and measured right.
    let w = world(7, 200.0, 25);
    // Thinned as the agent's keyframe clouds are.
    let cloud = |p: &Isometry3<f64>, seed: u64| {
        oriented(crate::filters::voxel_downsample(
            &ring_scan(&w, p, 40.0, seed),
            0.3,
        ))
    };
    let truth: Vec<Isometry3<f64>> = (0..15).map(|i| pose(2.0 * i as f64, 0.0, 0.0)).collect();
    let revisit = pose(13.0, 0.7, 0.6);
    let run = |submap: usize| {
        let cfg = GraphConfig {
            loop_exclude_recent_s: 10.0,
            place_max_distance: 0.0,
            loop_submap_keyframes: submap,
            ..GraphConfig::default()
        };
        let mut g = PoseGraph::new(cfg);
        for (i, t) in truth.iter().enumerate() {
            g.add_keyframe(i as f64, *t, Some(cloud(t, 30 + i as u64)));
        }
        let kf = g.add_keyframe(100.0, revisit, Some(cloud(&revisit, 99)));
        g.detect_loop(kf)
    };
    let alone = run(0);
    println!("against the nearest keyframe alone: {alone:?}");
    assert!(
        matches!(alone, Err(LoopRejection::PoorFit { .. })),
        "{alone:?}"
    );
    let c = run(5).expect("verified against the submap");
    let d = (truth[c.from].inverse() * revisit).inverse() * c.measured;
    println!(
        "against the submap: keyframe {} inliers {:.2}, rms {:.3} m, error {:.3} m {:.4} rad",
        c.from,
        c.inlier_ratio,
        c.rms_m,
        se3::translation_norm(&d),
        se3::rotation_angle(&d)
    );
    assert!(se3::translation_norm(&d) < 0.05 && se3::rotation_angle(&d) < 0.005);
}

#[test]
fn a_look_alike_place_further_than_the_graph_can_have_drifted_is_no_loop() {
    // A world that repeats every 40 m along x: at x = 40 the robot sees what it saw at x = 0,
    // and the descriptor and the ICP agree that it is the same place. RTK held every keyframe
    // on the way, so the graph cannot be 40 m off: the loop is refused.
    let tile = world(9, 40.0, 10);
    let w: Vec<[f32; 3]> = (-3..=4)
        .flat_map(|k| {
            tile.iter()
                .map(move |p| [p[0] + 40.0 * k as f32, p[1], p[2]])
        })
        .collect();
    let truth: Vec<Isometry3<f64>> = (0..=20).map(|i| pose(2.0 * i as f64, 0.0, 0.0)).collect();
    let run = |cfg: GraphConfig, gnss: bool| {
        let mut g = PoseGraph::new(GraphConfig {
            loop_exclude_recent_s: 10.0,
            ..cfg
        });
        let mut last = Err(LoopRejection::NoDescriptor);
        for (i, t) in truth.iter().enumerate() {
            let kf = g.add_keyframe(
                i as f64,
                *t,
                Some(oriented(scan(&w, t, 40.0, 50 + i as u64))),
            );
            if gnss {
                g.add_gnss(kf, t.translation.vector, 0.02, 0.04);
            }
            last = g.detect_loop(kf);
        }
        last
    };
    let look_alike = run(
        GraphConfig {
            loop_min_drift_m: 1e9,
            ..GraphConfig::default()
        },
        true,
    )
    .expect("without the drift test the look-alike passes the verification");
    assert_eq!((look_alike.from, look_alike.to), (0, 20), "{look_alike:?}");
    for gnss in [true, false] {
        let got = run(GraphConfig::default(), gnss);
        println!("RTK on every keyframe {gnss}: {got:?}");
        let Err(LoopRejection::Inconsistent {
            correction_m,
            allowed_m,
        }) = got
        else {
            panic!("the look-alike is a loop: {got:?}");
        };
        // Held by RTK the graph can be off by the floor only; on odometry alone, 5 % of the 40 m.
        let expected = if gnss { 1.0 } else { 1.0 + 0.05 * 40.0 };
        assert!((allowed_m - expected).abs() < 0.05, "{allowed_m}");
        // 40 m away, less the 2 x 8 m the ICP could move: refused before it runs.
        assert!(correction_m >= 40.0 - 16.0 - 0.1, "{correction_m}");
    }
}

/// The tilt of a keyframe's pose against the truth's, radians (yaw does not count).
fn tilt_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let (ua, ub) = (
        a.rotation.inverse() * Vector3::z(),
        b.rotation.inverse() * Vector3::z(),
    );
    ua.angle(&ub)
}

#[test]
fn gravity_factors_hold_the_keyframes_tilt_where_positions_do_not() {
    // 200 m straight and level, a keyframe every 2 m, odometry pitching 0.05 deg more per
    // keyframe, RTK on every keyframe. Positions pin where the keyframes are; how they are
    // tilted is left to the odometry chain, bent back only as far as the next positions pull.
    let truth: Vec<Isometry3<f64>> = (0..100).map(|i| pose(i as f64 * 2.0, 0.0, 0.0)).collect();
    let mut odom = vec![truth[0]];
    for w in truth.windows(2) {
        let step = w[0].inverse() * w[1];
        let bent = Isometry3::from_parts(
            step.translation,
            step.rotation * UnitQuaternion::from_euler_angles(0.0, 0.05f64.to_radians(), 0.0),
        );
        odom.push(odom.last().unwrap() * bent);
    }
    let run = |gravity: bool| {
        let mut g = PoseGraph::new(GraphConfig::default());
        let mut rng = StdRng::seed_from_u64(5);
        for (i, o) in odom.iter().enumerate() {
            let kf = g.add_keyframe(i as f64, *o, None);
            let noise = Vector3::from_fn(|_, _| rng.random_range(-0.02..0.02));
            g.add_gnss(kf, truth[i].translation.vector + noise, 0.02, 0.03);
            if gravity {
                // An accelerometer's up, 0.1 deg off at random.
                let wobble = UnitQuaternion::from_euler_angles(
                    rng.random_range(-0.1f64..0.1).to_radians(),
                    rng.random_range(-0.1f64..0.1).to_radians(),
                    0.0,
                );
                let up = wobble * (truth[i].rotation.inverse() * Vector3::z());
                g.add_gravity(kf, up, 0.005);
            }
        }
        g.optimise();
        let tilt: Vec<f64> = g
            .keyframes()
            .iter()
            .zip(&truth)
            .map(|(k, t)| tilt_error(&k.pose, t).to_degrees())
            .collect();
        (max(&tilt), max(&position_errors(&g, &truth)))
    };
    let (without, pos_without) = run(false);
    let (with, pos_with) = run(true);
    println!(
        "keyframe tilt error: {without:.3} deg with positions only, {with:.3} deg with gravity factors (positions {pos_without:.3} / {pos_with:.3} m)"
    );
    assert!(
        without > 0.3,
        "the drift should show without gravity: {without}"
    );
    assert!(
        with < 0.15 && with < without / 3.0,
        "tilt error {with} deg with gravity factors, {without} without"
    );
    assert!(pos_with < 0.1, "positions {pos_with} m");
}

//! Pipeline tests on synthetic worlds cast with the VLP-16-like model of [`crate::synth`].

use crate::synth::{cast_scan, lattice_points, LidarSpec, Rng};
use crate::{Class, Config, Evidence, Mapper, RobotPose};
use common::grid::{decode_tile, encode_tile, wire_tile, CellState, TileIndex};

const SENSOR_H: f64 = 0.7;

fn spec() -> LidarSpec {
    LidarSpec {
        az_step_deg: 0.4,
        max_range_m: 25.0,
        ..LidarSpec::vlp16()
    }
}

/// Drives the robot along `path` (x, y, t) through a time-varying world, one scan per pose.
fn drive(
    m: &mut Mapper,
    world: &dyn Fn(f64, f64, f64) -> f64,
    path: &[(f64, f64, f64)],
) -> Vec<crate::UpdateReport> {
    drive_as(m, world, path, false)
}

/// [`drive`], the sweeps given with their sensor origin (`beams`: free space is marched) or as
/// bare points.
fn drive_as(
    m: &mut Mapper,
    world: &dyn Fn(f64, f64, f64) -> f64,
    path: &[(f64, f64, f64)],
    beams: bool,
) -> Vec<crate::UpdateReport> {
    let mut rng = Rng::new(7);
    let mut reps = Vec::new();
    for w in path
        .windows(2)
        .map(|w| (w[0], Some(w[1])))
        .chain(path.last().map(|p| (*p, None)))
    {
        let ((x, y, t), next) = w;
        let yaw = next
            .map(|(nx, ny, _)| (ny - y).atan2(nx - x))
            .unwrap_or(0.0);
        let z = world(x, y, t);
        let h = |px: f64, py: f64| world(px, py, t);
        let pts = cast_scan(&h, [x, y, z + SENSOR_H], &spec(), &mut rng);
        let robot = RobotPose {
            x_m: x,
            y_m: y,
            z_m: z,
            yaw_rad: yaw,
        };
        let rep = if beams {
            m.update_sweep(pts, [x, y, z + SENSOR_H], &robot, t)
        } else {
            m.update_points(pts, &robot, t, Evidence::Scan)
        };
        reps.push(rep.unwrap());
    }
    reps
}

fn line(from: (f64, f64), to: (f64, f64), t0: f64, secs: f64) -> Vec<(f64, f64, f64)> {
    let n = (secs * 10.0).round() as usize;
    (0..=n)
        .map(|i| {
            let f = i as f64 / n as f64;
            (
                from.0 + (to.0 - from.0) * f,
                from.1 + (to.1 - from.1) * f,
                t0 + i as f64 * 0.1,
            )
        })
        .collect()
}

fn cell_of(m: &Mapper, x: f64, y: f64) -> (i64, i64) {
    m.lattice().cell_of(x, y)
}

/// Classes of the cells whose centres lie in the rectangle.
fn classes_in(m: &Mapper, x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<Class> {
    let (a, b) = (cell_of(m, x0, y0), cell_of(m, x1, y1));
    let mut v = Vec::new();
    for cy in a.1..=b.1 {
        for cx in a.0..=b.0 {
            v.push(m.class(cx, cy));
        }
    }
    v
}

fn count(v: &[Class], f: impl Fn(Class) -> bool) -> usize {
    v.iter().filter(|c| f(**c)).count()
}

#[test]
fn flat_ground_has_no_obstacles() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(
        &mut m,
        &|_, _, _| 0.0,
        &line((-2.0, 0.0), (2.0, 0.0), 0.0, 4.0),
    );
    let v = classes_in(&m, -10.0, -10.0, 10.0, 10.0);
    let known = count(&v, |c| c == Class::Traversable || c.is_obstacle());
    let obst = count(&v, Class::is_obstacle);
    assert!(known > 3000, "only {known} cells classified");
    assert_eq!(obst, 0, "{obst} false obstacles of {known}");
    // The footprint is traversable even inside the blind zone.
    assert_eq!(
        m.class(cell_of(&m, 2.0, 0.0).0, cell_of(&m, 2.0, 0.0).1),
        Class::Traversable
    );
}

/// 5 cm step at x = 3 m, 10 cm step at x = 6 m (ground 0.15 m beyond).
fn steps(x: f64, _y: f64, _t: f64) -> f64 {
    if x < 3.0 {
        0.0
    } else if x < 6.0 {
        0.05
    } else {
        0.15
    }
}

#[test]
fn ten_cm_step_blocks_five_cm_step_does_not() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &steps, &line((-4.0, -1.0), (2.0, 1.0), 0.0, 8.0));
    let (mut rows10, mut hit10, mut false5) = (0, 0, 0);
    for cy in cell_of(&m, 0.0, -3.0).1..=cell_of(&m, 0.0, 3.0).1 {
        // The two cells on either side of each border.
        let c10 = [m.class(29, cy), m.class(30, cy)];
        if c10.iter().all(|c| *c != Class::Unknown) {
            rows10 += 1;
            hit10 += usize::from(c10.iter().any(|c| c.is_obstacle()));
        }
        false5 += [13, 14, 15, 16]
            .iter()
            .filter(|&&cx| m.class(cx, cy).is_obstacle())
            .count();
    }
    assert!(rows10 >= 25, "10 cm border observed in {rows10} rows");
    // Rows where the riser's points fall evenly on both sides of a cell border are the hard
    // case for mean heights; the top-of-cell rule catches nearly all of them.
    assert!(
        hit10 * 100 >= rows10 * 95,
        "10 cm step blocked in {hit10} of {rows10} rows"
    );
    assert_eq!(false5, 0, "5 cm step marked in {false5} cells");
}

/// 30 deg ramp for y < 0, 15 deg ramp for y >= 0, both from x = 3 m to x = 4 m, plateaus after.
fn ramps(x: f64, y: f64, _t: f64) -> f64 {
    let g = if y < 0.0 { 30f64 } else { 15f64 }.to_radians().tan();
    (x - 3.0).clamp(0.0, 1.0) * g
}

#[test]
fn slopes_over_23_deg_block_gentler_ones_do_not() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &ramps, &line((-3.0, 0.0), (1.5, 0.0), 0.0, 6.0));
    let steep = classes_in(&m, 3.3, -2.5, 3.7, -0.6);
    let gentle = classes_in(&m, 3.1, 0.6, 3.9, 2.5);
    let seen = |v: &[Class]| count(v, |c| c != Class::Unknown && c != Class::Undecided);
    assert!(
        seen(&steep) > 20 && seen(&gentle) > 20,
        "{} {}",
        seen(&steep),
        seen(&gentle)
    );
    assert_eq!(
        count(&steep, Class::is_obstacle),
        seen(&steep),
        "30 deg ramp: {steep:?}"
    );
    assert_eq!(
        count(&gentle, Class::is_obstacle),
        0,
        "15 deg ramp: {gentle:?}"
    );
}

fn pole(x: f64, y: f64, _t: f64) -> f64 {
    if (x - 4.0).hypot(y - 1.0) < 0.12 {
        2.0
    } else {
        0.0
    }
}

#[test]
fn pole_is_an_obstacle_inflated_with_decaying_costs() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &pole, &line((-1.0, 0.0), (1.0, 0.0), 0.0, 3.0));
    let (px, py) = cell_of(&m, 4.0, 1.0);
    assert_eq!(m.class(px, py), Class::Obstacle);
    assert_eq!(m.cell(px, py).state, CellState::Obstacle);
    // The step rule also marks the ground cell touching the pole; 0.4 m (2 cells) beyond that
    // is inflated; farther is traversable with a cost that decays to zero at 1.2 m.
    assert!(m.class(px, py - 2).is_obstacle() || m.class(px, py - 2) == Class::Traversable);
    let near = m.cell(px, py - 3);
    assert_eq!(near.state, CellState::Inflated, "{near:?}");
    let (c5, c7) = (m.cell(px, py - 5), m.cell(px, py - 7));
    assert_eq!(c5.state, CellState::Traversable);
    assert!(c5.cost > c7.cost && c7.cost > 0, "{} {}", c5.cost, c7.cost);
    assert_eq!(m.cell(px, py - 10).cost, 0);
}

/// A 0.4 x 0.4 x 1.7 m person at (3, 0) until t = 2 s, gone after.
fn walker(x: f64, y: f64, t: f64) -> f64 {
    if t < 2.0 && (x - 3.0).abs() < 0.2 && y.abs() < 0.2 {
        1.7
    } else {
        0.0
    }
}

#[test]
fn newer_evidence_clears_cells_a_walker_left() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &walker, &line((-1.0, -1.0), (-0.6, -1.0), 0.0, 1.9));
    let during = classes_in(&m, 2.8, -0.2, 3.2, 0.2);
    assert!(
        count(&during, Class::is_obstacle) > 0,
        "walker not seen: {during:?}"
    );
    drive(&mut m, &walker, &line((-0.5, -1.0), (1.0, 1.0), 2.0, 6.0));
    let after = classes_in(&m, 2.6, -0.4, 3.4, 0.4);
    assert!(count(&after, |c| c == Class::Traversable) > 5, "{after:?}");
    assert_eq!(
        count(&after, Class::is_obstacle),
        0,
        "walker left marks: {after:?}"
    );
}

#[test]
fn platform_edge_is_a_negative_obstacle() {
    // Robot on a 1 m platform ending at x = 5 m; the ground below is out of the cone.
    let plat = |x: f64, _y: f64, _t: f64| if x < 5.0 { 1.0 } else { 0.0 };
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &plat, &line((0.0, 0.0), (1.5, 0.0), 0.0, 3.0));
    // Per row, the first unobserved cell past the observed edge is a negative obstacle.
    for y in -5..=5 {
        let row = classes_in(&m, 4.9, f64::from(y) * 0.2, 5.5, f64::from(y) * 0.2);
        assert!(row.contains(&Class::NegativeObstacle), "row {y}: {row:?}");
    }
    // Nothing on the platform top is marked.
    let top = classes_in(&m, 3.0, -1.0, 4.7, 1.0);
    assert_eq!(count(&top, Class::is_obstacle), 0, "{top:?}");
    // And flat ground with ring gaps gives none.
    let mut f = Mapper::new(Config::default()).unwrap();
    drive(
        &mut f,
        &|_, _, _| 0.0,
        &line((0.0, 0.0), (1.5, 0.0), 0.0, 3.0),
    );
    let v = classes_in(&f, -8.0, -8.0, 8.0, 8.0);
    assert_eq!(count(&v, |c| c == Class::NegativeObstacle), 0);
}

#[test]
fn incremental_equals_full_reclassification() {
    let world = |x: f64, y: f64, t: f64| walker(x, y, t) + steps(x, y, t) + pole(x, y, t);
    let path = line((-1.0, -1.0), (1.5, 1.0), 0.0, 4.0);
    let mut inc = Mapper::new(Config::default()).unwrap();
    let mut full = Mapper::new(Config::default()).unwrap();
    full.set_full_reclassification(true);
    drive(&mut inc, &world, &path);
    drive(&mut full, &world, &path);
    let v = inc.planner_view();
    let (mut diff, mut known) = (0, 0);
    for cy in v.min_cy..v.min_cy + i64::from(v.height) {
        for cx in v.min_cx..v.min_cx + i64::from(v.width) {
            known += usize::from(inc.class(cx, cy) != Class::Unknown);
            if inc.class(cx, cy) != full.class(cx, cy) || inc.cell(cx, cy) != full.cell(cx, cy) {
                diff += 1;
            }
        }
    }
    assert!(known > 2000);
    assert_eq!(diff, 0, "{diff} of {known} cells differ");
}

#[test]
fn changed_tiles_are_reported_once_and_tiles_round_trip() {
    let mut m = Mapper::new(Config::default()).unwrap();
    let reps = drive(&mut m, &walker, &line((-3.0, 0.0), (3.0, 0.0), 0.0, 6.0));
    let changed: Vec<TileIndex> = reps.iter().flat_map(|r| r.changed_tiles.clone()).collect();
    assert!(changed.len() > 4, "{changed:?}");
    for r in &reps {
        assert!(
            r.changed_tiles.windows(2).all(|w| w[0] < w[1]),
            "sorted, once"
        );
    }
    // Every tile with a known cell was reported changed at some point; all round-trip the codec.
    for t in m.tiles() {
        let known = t.cells.iter().any(|c| c.state != CellState::Unknown);
        assert!(!known || changed.contains(&t.index), "{:?}", t.index);
        assert_eq!(decode_tile(&encode_tile(&t)).unwrap(), wire_tile(&t));
        assert_eq!(m.tile_cells(t.index), Some(t.cells.as_slice()));
    }
    // Nothing new (no points, the robot where it last stood): nothing reported.
    let last = RobotPose {
        x_m: 3.0,
        z_m: walker(3.0, 0.0, 6.0),
        ..Default::default()
    };
    let quiet = m.update_points(vec![], &last, 6.0, Evidence::Scan);
    assert!(quiet.unwrap().changed_tiles.is_empty());
}

#[test]
fn bad_input_is_a_typed_error() {
    let mut m = Mapper::new(Config::default()).unwrap();
    let bad = RobotPose {
        x_m: f64::NAN,
        ..Default::default()
    };
    assert!(m.update_points(vec![], &bad, 0.0, Evidence::Scan).is_err());
    let ok = RobotPose::default();
    let r = m
        .update_points(
            vec![[f32::NAN, 0.0, 0.0], [1.0, 1.0, 0.0]],
            &ok,
            1.0,
            Evidence::Scan,
        )
        .unwrap();
    assert_eq!(r.dropped_non_finite, 1);
    assert!(matches!(
        m.update_points(vec![], &ok, 0.0, Evidence::Scan),
        Err(crate::MapError::TimeWentBack { .. })
    ));
    assert!(Mapper::new(Config {
        grid_size_m: -1.0,
        ..Config::default()
    })
    .is_err());
}

/// A LiDAR sweep is stamped at its revolution's start and arrives a period later; a depth
/// frame mapped in between carries a newer stamp. The sweep must still be mapped (it was
/// refused as "time went back", so a robot with a depth camera mapped only the camera's 5 m).
#[test]
fn a_sweep_stamped_before_the_last_depth_frame_is_still_mapped() {
    let mut m = Mapper::new(Config::default()).unwrap();
    let robot = RobotPose {
        z_m: 0.0,
        ..Default::default()
    };
    let flat = |_: f64, _: f64| 0.0;
    let mut rng = Rng::new(3);
    // The camera's frame: a patch of ground a metre ahead, at 2.05 s.
    let patch: Vec<[f32; 3]> = (0..100)
        .map(|i| [1.0 + 0.01 * (i % 10) as f32, 0.01 * (i / 10) as f32, 0.0])
        .collect();
    m.update_points(patch, &robot, 2.05, Evidence::Scan)
        .unwrap();
    // The sweep that started at 2.0 s, delivered after it.
    let pts = cast_scan(&flat, [0.0, 0.0, SENSOR_H], &spec(), &mut rng);
    let rep = m
        .update_sweep(pts, [0.0, 0.0, SENSOR_H], &robot, 2.0)
        .expect("a sweep a period older than the last frame is mapped");
    assert!(rep.dirty_cells > 100, "{rep:?}");
    let (cx, cy) = cell_of(&m, 8.0, 0.0);
    assert!(m.height_m(cx, cy).is_some(), "ground 8 m out mapped");
    // Older than an evidence epoch is still refused.
    let far_back = cast_scan(&flat, [0.0, 0.0, SENSOR_H], &spec(), &mut rng);
    assert!(matches!(
        m.update_sweep(far_back, [0.0, 0.0, SENSOR_H], &robot, 1.0),
        Err(crate::MapError::TimeWentBack { .. })
    ));
}

#[test]
#[ignore = "debug"]
fn debug_steps() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &pole, &line((-1.0, 0.0), (1.0, 0.0), 0.0, 3.0));
    for cy in (-3..=7).rev() {
        let mut s = String::new();
        for cx in 17..=22 {
            let nb = m.height_stats(cx, cy);
            s += &format!(
                "{:?}/{}/{:.3}/{:.4} ",
                m.class(cx, cy),
                nb.n,
                nb.mean_m,
                nb.var_m2
            );
        }
        println!("{cy}: {s}");
    }
}

/// A GNSS correction lifts the map frame by 10 cm halfway along a drive: the scans after it see
/// the same flat ground 10 cm higher. Cells seen just before follow the frame (no step appears
/// between old and new evidence); without following, the seam would be a wall of false steps.
#[test]
fn cells_follow_a_frame_correction_and_old_cells_keep_theirs() {
    let lift = 0.1;
    let run = |follow: bool| {
        let mut m = Mapper::new(Config::default()).unwrap();
        // An old visit far back in time, then the drive.
        drive(
            &mut m,
            &|_, _, _| 0.0,
            &line((-30.0, 0.0), (-29.0, 0.0), 0.0, 1.0),
        );
        drive(
            &mut m,
            &|_, _, _| 0.0,
            &line((-3.0, 0.0), (0.0, 0.0), 100.0, 3.0),
        );
        if follow {
            let delta = nalgebra::Isometry3::translation(0.0, 0.0, lift);
            let moved = m.follow_frame(&delta, 30.0);
            assert!(moved > 1000, "{moved} cells moved");
        }
        drive(
            &mut m,
            &|_, _, _| lift,
            &line((0.0, 0.0), (3.0, 0.0), 103.1, 3.0),
        );
        m
    };
    let m = run(true);
    let v = classes_in(&m, -8.0, -8.0, 8.0, 8.0);
    let obst = count(&v, Class::is_obstacle);
    assert_eq!(obst, 0, "{obst} false obstacles after following the frame");
    let (cx, cy) = cell_of(&m, -3.0, 4.0);
    let h = m.height_m(cx, cy).unwrap();
    assert!((h - lift).abs() < 0.03, "followed cell at {h} m");
    // The cells seen 100 s earlier, 30 m away, kept their frame.
    let (cx, cy) = cell_of(&m, -33.0, 0.0);
    let h = m.height_m(cx, cy).unwrap();
    assert!(h.abs() < 0.03, "old cell moved to {h} m");

    let m = run(false);
    let v = classes_in(&m, -8.0, -8.0, 8.0, 8.0);
    assert!(
        count(&v, Class::is_obstacle) > 20,
        "the control run should show the seam"
    );
}

/// Frame corrections too small to matter are kept and composed, not dropped: four lifts of
/// 0.1 mm move no cell, and the 1 cm lift after them moves the cells by all five together.
#[test]
fn slivers_of_frame_correction_add_up_before_the_cells_follow() {
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(
        &mut m,
        &|_, _, _| 0.0,
        &line((-3.0, 0.0), (0.0, 0.0), 0.0, 3.0),
    );
    let (cx, cy) = cell_of(&m, -3.0, 4.0);
    let h0 = m.height_m(cx, cy).unwrap();
    let sliver = nalgebra::Isometry3::translation(0.0, 0.0, 1e-4);
    for _ in 0..4 {
        assert_eq!(m.follow_frame(&sliver, 30.0), 0, "a sliver moved cells");
    }
    let lift = nalgebra::Isometry3::translation(0.0, 0.0, 0.01);
    assert!(m.follow_frame(&lift, 30.0) > 1000);
    let h = m.height_m(cx, cy).unwrap();
    assert!(
        (h - h0 - 0.0104).abs() < 1e-5,
        "moved by {} m, not 10.4 mm",
        h - h0
    );
    // Nothing is kept over: the next sliver waits again.
    assert_eq!(m.follow_frame(&sliver, 30.0), 0);
}

/// A 0.3 m wide strip at y = 0 that is a 6 cm rise from the ground on its north side and a 10 cm
/// drop to the ground on its south side. Passed at 2.5 m on the north side, the drop lies in the
/// strip's shadow; a later pass 13 m to the south (beyond `processing_distance_m`) shows it.
fn strip(x: f64, y: f64, _t: f64) -> f64 {
    if y > 0.15 {
        0.04
    } else if x.abs() <= 4.0 && y >= -0.15 {
        0.1
    } else {
        0.0
    }
}

#[test]
fn a_later_distant_view_of_a_steps_shadowed_side_marks_the_step() {
    let run = |world: &dyn Fn(f64, f64, f64) -> f64, far_step_m: f64| {
        let cfg = Config {
            far_step_distance_m: far_step_m,
            ..Config::default()
        };
        let mut m = Mapper::new(cfg).unwrap();
        drive(&mut m, world, &line((-6.0, 2.5), (6.0, 2.5), 0.0, 12.0));
        drive(
            &mut m,
            world,
            &line((8.0, -13.1), (-8.0, -13.1), 20.0, 16.0),
        );
        count(&classes_in(&m, -3.5, -0.3, 3.5, 0.3), Class::is_obstacle)
    };
    let (with, without) = (run(&strip, 20.0), run(&strip, 0.0));
    eprintln!("strip obstacle cells: {with} with the far-step rule, {without} without");
    assert!(
        with >= 30,
        "only {with} strip cells are obstacles (without the rule {without})"
    );
    assert!(
        without < with / 2,
        "the north pass alone found {without} of {with}"
    );
    // Flat ground seen the same two ways gains no obstacles.
    assert_eq!(run(&|_, _, _| 0.0, 20.0), 0);
}

/// A slim person in the cells at x 2.8-3.0 m, y -0.2-0.2 m until t = 2 s, a wall across
/// x = 8 m behind it and a post at (3, 2) that stays.
fn walker_wall_post(x: f64, y: f64, t: f64) -> f64 {
    let person = t < 2.0 && (2.82..2.98).contains(&x) && y.abs() < 0.18;
    if person || (8.0..8.3).contains(&x) || ((x - 3.0).abs() < 0.2 && (y - 2.0).abs() < 0.2) {
        1.7
    } else {
        0.0
    }
}

#[test]
fn a_distant_view_through_a_walkers_trail_clears_it_and_keeps_what_stays() {
    // Seen from 4 m while the person stands there, then only from 13-14 m (the robot has moved on):
    // the grazing ring that crosses the cell 0.45 m up and ends on the wall proves it empty, and
    // the next ring down shows its ground.
    let run = |clear_reach_m: f64| {
        let mut m = Mapper::new(Config {
            clear_reach_m,
            ..Config::default()
        })
        .unwrap();
        drive_as(
            &mut m,
            &walker_wall_post,
            &line((-1.0, -1.0), (-0.6, -1.0), 0.0, 1.9),
            true,
        );
        let during = classes_in(&m, 2.81, -0.19, 2.99, 0.19);
        assert!(count(&during, Class::is_obstacle) > 0, "{during:?}");
        drive_as(
            &mut m,
            &walker_wall_post,
            &line((-10.2, 0.0), (-10.6, 0.0), 2.0, 2.0),
            true,
        );
        // Positive obstacles: the drop-off lip the negative-obstacle rule draws at the edge of
        // the person's shadow is that rule's business (it holds while the shadow is unseen).
        let obstacle = |c: Class| c == Class::Obstacle;
        (
            count(&classes_in(&m, 2.81, -0.19, 2.99, 0.19), obstacle),
            count(&classes_in(&m, 2.9, 1.9, 3.1, 2.1), obstacle),
        )
    };
    let (trail, post) = run(Config::default().clear_reach_m);
    assert_eq!(trail, 0, "the walker's cells stayed obstacles");
    assert!(post > 0, "the post that stays was wiped");
    // Control: free space marched only within the processing distance keeps the trail.
    let (trail, _) = run(0.0);
    assert!(
        trail > 0,
        "control: without far clearing the trail should stay"
    );
}

#[test]
fn a_view_is_the_cells_it_covers() {
    // The view copies rows in runs per tile; it must equal reading every cell on its own,
    // across tile edges, at windows not aligned to tiles and reaching past the held tiles.
    let mut m = Mapper::new(Config::default()).unwrap();
    drive(&mut m, &steps, &line((-2.0, 0.0), (2.0, 0.5), 0.0, 3.0));
    let ((x0, y0), (x1, y1)) = m.bounds().unwrap();
    let mut known = 0;
    for (min_cx, min_cy, w, h) in [
        (x0 - 7, y0 - 3, (x1 - x0 + 20) as u32, (y1 - y0 + 9) as u32),
        (x0 + 5, y0 + 61, 130, 3),
        (x1 - 2, y1 - 2, 1, 1),
    ] {
        let v = m.view(min_cx, min_cy, w, h);
        assert_eq!(v.cells.len(), w as usize * h as usize);
        for y in 0..i64::from(h) {
            for x in 0..i64::from(w) {
                let want = m.cell(min_cx + x, min_cy + y);
                known += usize::from(want != common::grid::Cell::UNKNOWN);
                assert_eq!(v.get(min_cx + x, min_cy + y), want, "({x}, {y})");
            }
        }
    }
    assert!(known > 1000, "{known}");
}

/// Points on a square lattice `side` points wide, 7 cm apart, from (`x0`, `y0`), at height `z`.
fn sheet(x0: f32, y0: f32, side: usize, z: f32) -> Vec<[f32; 3]> {
    lattice_points(
        [f64::from(x0), f64::from(y0)],
        0.07,
        [side, side],
        |_, _| f64::from(z),
    )
}

#[test]
fn a_canopy_taken_in_before_its_ground_was_seen_goes_once_the_ground_is() {
    let robot = RobotPose {
        x_m: 0.0,
        y_m: 0.0,
        z_m: 0.0,
        yaw_rad: 0.0,
    };
    let mut m = Mapper::new(Config::default()).unwrap();
    // A sweep crossed a canopy 2.4 m up with no ring on the ground below or around it: with
    // no ground known, the canopy set its own ceiling and came in as the cells' surface.
    m.update_points(sheet(3.0, 2.0, 30, 2.4), &robot, 10.0, Evidence::Scan)
        .unwrap();
    let (cx, cy) = cell_of(&m, 4.0, 3.0);
    assert!(m.height_m(cx, cy).is_some_and(|h| h > 2.3));
    // A later sweep sees the ground below and around, and not the canopy.
    let rep = m
        .update_points(sheet(2.0, 1.0, 60, 0.0), &robot, 12.0, Evidence::Scan)
        .unwrap();
    assert!(
        m.height_m(cx, cy).is_some_and(|h| h.abs() < 0.05),
        "{:?}",
        m.height_m(cx, cy)
    );
    let patch = classes_in(&m, 3.0, 2.0, 5.0, 4.0);
    assert_eq!(count(&patch, |c| c == Class::Obstacle), 0, "{patch:?}");
    assert_eq!(
        count(&patch, |c| c == Class::Traversable),
        patch.len(),
        "{patch:?}"
    );
    assert!(rep.ceiling_wiped > 100, "{}", rep.ceiling_wiped);
}

#[test]
fn steps_judged_against_a_canopy_clear_when_a_far_view_wipes_it() {
    let at = |x_m: f64, y_m: f64| RobotPose {
        x_m,
        y_m,
        z_m: 0.0,
        yaw_rad: 0.0,
    };
    let in_patch = |p: &[f32; 3]| (2.95..5.1).contains(&p[0]) && (1.95..4.1).contains(&p[1]);
    let mut m = Mapper::new(Config::default()).unwrap();
    // A canopy with nothing of the ground below or around it, then the ground around it and
    // none below: the cells around are judged, from close by, as steps down from the canopy.
    m.update_points(
        sheet(3.0, 2.0, 30, 2.4),
        &at(0.0, 0.0),
        10.0,
        Evidence::Scan,
    )
    .unwrap();
    let mut around = sheet(2.0, 1.0, 60, 0.0);
    around.retain(|p| !in_patch(p));
    m.update_points(around, &at(0.0, 0.0), 11.0, Evidence::Scan)
        .unwrap();
    let steps = count(&classes_in(&m, 2.0, 1.0, 6.0, 5.0), |c| {
        c == Class::Obstacle
    });
    assert!(steps > 20, "the setting: steps around the canopy ({steps})");
    // From 19 m, beyond the processing distance, a view of the ground below the canopy.
    let mut below = sheet(2.0, 1.0, 60, 0.0);
    below.retain(in_patch);
    let rep = m
        .update_points(below, &at(-15.0, 3.0), 30.0, Evidence::Scan)
        .unwrap();
    assert!(rep.ceiling_wiped > 50, "{}", rep.ceiling_wiped);
    let (cx, cy) = cell_of(&m, 4.0, 3.0);
    assert!(m.height_m(cx, cy).is_some_and(|h| h.abs() < 0.05));
    let after = classes_in(&m, 2.0, 1.0, 6.0, 5.0);
    assert_eq!(count(&after, |c| c == Class::Obstacle), 0, "{after:?}");
}

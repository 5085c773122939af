//! The incremental map rebuild through [`TerrainMap`]: a rebuild fed a few kept sweeps per live
//! sweep ends with the same map as one made in one go from the same sweeps, and the live map
//! keeps serving (and taking sweeps) until the rebuilt one replaces it.

use super::rebuild::{to_map, Remap};
use super::{robot_pose, TerrainMap};
use crate::localiser::PoseMap;
use crate::AgentConfig;
use mapping::synth::{cast_scan, LidarSpec, Rng};
use mapping::Class;
use nalgebra::{Isometry3, Translation3};
use sensing::{Point, Scan};

/// Flat ground with a 1 m box at (6, 0).
fn world(x: f64, y: f64) -> f64 {
    if (x - 6.0).abs() < 0.5 && y.abs() < 0.5 {
        1.0
    } else {
        0.0
    }
}

const SENSOR_H_M: f64 = 0.7;
/// Where drift put the robot: this far north of the truth.
const DRIFT_Y_M: f64 = 1.0;

fn terrain(sweeps_per_tick: usize) -> TerrainMap {
    let mut cfg = AgentConfig::default();
    cfg.slam.graph.enabled = true;
    cfg.slam.graph.map_rebuild_spacing_m = 0.5;
    cfg.slam.graph.map_rebuild_sweeps_per_tick = sweeps_per_tick;
    TerrainMap::new(&cfg).expect("default configuration")
}

fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), Default::default())
}

/// A VLP-16-like scan of `height` out to `max_range_m` from the sensor above (x, 0), in the
/// lidar frame.
fn scan_at(height: &dyn Fn(f64, f64) -> f64, x: f64, max_range_m: f64, seed: u64) -> Vec<Point> {
    let spec = LidarSpec {
        az_step_deg: 0.8,
        max_range_m,
        ..LidarSpec::vlp16()
    };
    let mut rng = Rng::new(seed);
    cast_scan(height, [x, 0.0, SENSOR_H_M], &spec, &mut rng)
        .into_iter()
        .map(|p| Point {
            x: p[0] - x as f32,
            y: p[1],
            z: p[2] - SENSOR_H_M as f32,
            intensity: 0.0,
            ring: 0,
            t_s: 0.0,
        })
        .collect()
}

/// Sweep `i` of a drive along y = 0 (0.5 m apart), seen from the truth: its time, the true
/// x and the returns in the lidar frame.
fn sweep_points(i: u32) -> (f64, f64, Vec<Point>) {
    let x = 0.5 * f64::from(i);
    let points = scan_at(&world, x, 20.0, u64::from(i) + 3);
    (10.0 + 0.1 * f64::from(i), x, points)
}

/// Sweep `i` mapped `offset_y` north of the truth (each is kept); the SLAM frame is the
/// drifted one.
fn drive_sweep(m: &mut TerrainMap, i: u32, offset_y: f64) {
    let (stamp_s, x, points) = sweep_points(i);
    let scan = Scan { stamp_s, points };
    let base = at(x, offset_y, 0.0);
    let pose = PoseMap::from_iso(base);
    m.update(&scan, &at(x, offset_y, SENSOR_H_M), &pose)
        .expect("a sweep");
    m.keep_sweep(scan.stamp_s, &at(x, DRIFT_Y_M, 0.0), &pose, &scan.points);
}

/// Obstacle cells (class before inflation) with centres in `[x0, x1] x [y0, y1]`.
fn obstacles_in(m: &TerrainMap, (x0, x1): (f64, f64), (y0, y1): (f64, f64)) -> usize {
    let mp = m.mapper();
    let l = mp.lattice();
    let (c0, r0) = l.cell_of(x0, y0);
    let (c1, r1) = l.cell_of(x1, y1);
    (r0..=r1)
        .flat_map(|r| (c0..=c1).map(move |c| (c, r)))
        .filter(|&(c, r)| mp.class(c, r) == Class::Obstacle)
        .count()
}

const NORTH: ((f64, f64), (f64, f64)) = ((5.3, 6.7), (0.9, 1.7));
const TRUE_BOX: ((f64, f64), (f64, f64)) = ((5.3, 6.7), (-0.7, 0.3));

/// The correction: the graph puts the SLAM frame `DRIFT_Y_M` south.
fn correction(_t: f64) -> Option<Isometry3<f64>> {
    Some(at(0.0, -DRIFT_Y_M, 0.0))
}

fn base_from_lidar() -> Isometry3<f64> {
    at(0.0, 0.0, SENSOR_H_M)
}

#[test]
fn an_incremental_rebuild_ends_with_the_one_shot_map_and_the_live_map_serves_meanwhile() {
    const SWEEPS: u32 = 13;
    let mut one_shot = terrain(0);
    let mut stepped = terrain(3);
    for i in 0..SWEEPS {
        drive_sweep(&mut one_shot, i, DRIFT_Y_M);
        drive_sweep(&mut stepped, i, DRIFT_Y_M);
    }
    let t_s = 20.0;
    let blf = base_from_lidar();
    let tiles_one_shot = one_shot.correct(t_s, &blf, correction).unwrap();
    assert!(
        !tiles_one_shot.is_empty(),
        "the one-shot rebuild is done at once"
    );
    assert_eq!(one_shot.rebuild_counts().0, 1);
    assert_eq!(obstacles_in(&one_shot, NORTH.0, NORTH.1), 0);
    assert!(obstacles_in(&one_shot, TRUE_BOX.0, TRUE_BOX.1) > 0);

    assert!(stepped.correct(t_s, &blf, correction).unwrap().is_empty());
    assert_eq!(stepped.rebuild_progress(), Some(0));
    let mut ticks = 0;
    let tiles = loop {
        let tiles = stepped.advance_rebuild(t_s, &blf).unwrap();
        ticks += 1;
        if !tiles.is_empty() {
            break tiles;
        }
        // Meanwhile the live (drifted) map is the one served.
        assert_eq!(stepped.rebuild_progress(), Some(3 * ticks));
        assert!(obstacles_in(&stepped, NORTH.0, NORTH.1) > 0);
        assert!(ticks < 10, "the rebuild ends");
    };
    // 13 sweeps, 3 a tick: the fifth tick feeds the last one and swaps.
    assert_eq!(ticks, 5);
    assert_eq!(stepped.rebuild_progress(), None);
    assert_eq!(tiles, tiles_one_shot);
    assert_eq!(
        common::grid::map_digest(&stepped.mapper().tiles()),
        common::grid::map_digest(&one_shot.mapper().tiles()),
        "the same map, cell for cell"
    );
}

#[test]
fn live_sweeps_during_a_rebuild_are_mapped_and_kept_and_the_rebuild_catches_up() {
    let mut m = terrain(2);
    for i in 0..10 {
        drive_sweep(&mut m, i, DRIFT_Y_M);
    }
    let blf = base_from_lidar();
    assert!(m.correct(11.0, &blf, correction).unwrap().is_empty());
    // The drive goes on at the corrected pose while the rebuild runs: each sweep is kept too,
    // so the shadow gains 2 and loses 1 a sweep.
    let mut swapped_at = None;
    for i in 10..30 {
        let t = 10.0 + 0.1 * f64::from(i);
        let tiles = m.advance_rebuild(t, &blf).unwrap();
        if !tiles.is_empty() {
            swapped_at = Some(i);
            break;
        }
        // The live map serves, and takes the sweeps at the corrected pose (its free space
        // clears the drifted box as it goes).
        assert_eq!(m.rebuild_counts().0, 0);
        assert_eq!(m.rebuild_progress(), Some(2 * (i as usize - 9)));
        drive_sweep(&mut m, i, 0.0);
        assert!(obstacles_in(&m, TRUE_BOX.0, TRUE_BOX.1) > 0 || i < 12);
    }
    // 10 sweeps behind, 2 fed and 1 more kept a sweep: the ninth tick (before sweep 18 is
    // mapped) feeds the last two, sweeps 16 and 17, and swaps.
    assert_eq!(swapped_at, Some(18));
    assert_eq!(m.rebuild_counts(), (1, 18));
    assert_eq!(
        obstacles_in(&m, NORTH.0, NORTH.1),
        0,
        "the drifted box went"
    );
    assert!(obstacles_in(&m, TRUE_BOX.0, TRUE_BOX.1) > 0);
    // A correction that moves nothing more starts nothing.
    assert!(m.correct(12.0, &blf, correction).unwrap().is_empty());
    assert_eq!(m.rebuild_progress(), None);
}

#[test]
fn the_quantised_kept_sweeps_rebuild_nearly_the_map_the_full_precision_sweeps_make() {
    const SWEEPS: u32 = 13;
    let mut m = terrain(0);
    for i in 0..SWEEPS {
        drive_sweep(&mut m, i, DRIFT_Y_M);
    }
    let blf = base_from_lidar();
    assert!(!m.correct(20.0, &blf, correction).unwrap().is_empty());
    // The same sweeps at the same (true) poses, from their f32 returns.
    let mut exact = mapping::Mapper::new(m.mapper().config().clone()).unwrap();
    for i in 0..SWEEPS {
        let (t_s, x, points) = sweep_points(i);
        let r = Remap {
            t_s,
            map_from_base: at(x, 0.0, 0.0),
            live_from_base: at(x, 0.0, 0.0),
            points: points.iter().map(|p| [p.x, p.y, p.z]).collect(),
        };
        let (pts, origin) = to_map(&r, &blf);
        let robot = robot_pose(&PoseMap::from_iso(r.map_from_base));
        exact.update_sweep(pts, origin, &robot, t_s).unwrap();
    }
    let l = exact.lattice();
    let (c0, r0) = l.cell_of(-20.0, -20.0);
    let (c1, r1) = l.cell_of(26.0, 20.0);
    let (mut observed, mut differ, mut dz_cm) = (0usize, 0usize, 0i32);
    for r in r0..=r1 {
        for c in c0..=c1 {
            let (a, b) = (exact.cell(c, r), m.mapper().cell(c, r));
            if a.state != common::grid::CellState::Unknown {
                observed += 1;
            }
            if exact.class(c, r) != m.mapper().class(c, r) || a.state != b.state || a.cost != b.cost
            {
                differ += 1;
                // No obstacle is lost or made by the quantisation.
                assert!(
                    exact.class(c, r) != Class::Obstacle
                        && m.mapper().class(c, r) != Class::Obstacle,
                    "cell ({c}, {r})"
                );
            }
            dz_cm = dz_cm.max((i32::from(a.height_cm) - i32::from(b.height_cm)).abs());
        }
    }
    println!(
        "quantised vs f32 rebuild: {differ} of {observed} observed cells differ, max height difference {dz_cm} cm"
    );
    assert!(observed > 1000, "{observed}");
    // Measured: 39 of 3370 (steps of 1.03 mm; 27 at 0.94 mm), single-hit cells at the
    // sensor's 20 m fringe whose few returns moved by about half a millimetre (a return on a
    // cell border, a grazing beam).
    assert!(
        differ * 50 <= observed,
        "{differ} of {observed} cells differ"
    );
    assert!(dz_cm <= 1, "{dz_cm} cm");
}

/// Flat ground, the 1 m box at (6, 0), and a 3 m wall from x = 40 m: beyond the mapper's 30 m
/// range, so the beams that end on it only mark free space.
fn far_world(x: f64, y: f64) -> f64 {
    if x > 40.0 {
        3.0
    } else {
        world(x, y)
    }
}

#[test]
fn a_rebuild_at_unchanged_poses_reproduces_the_live_map() {
    // Every sweep kept (spacing 0), the drive's sweeps cast out to 60 m: what the rebuild is
    // fed is then what the live map was, and at the same poses it must make the same map, up
    // to the returns' quantisation. Before the store kept the returns beyond the mapper's
    // range, their free space was lost and the mapper's beam stride fell on other beams.
    let mut cfg = AgentConfig::default();
    cfg.slam.graph.enabled = true;
    cfg.slam.graph.map_rebuild_spacing_m = 0.0;
    let mut m = TerrainMap::new(&cfg).expect("default configuration");
    let mut far = 0usize;
    for i in 0..20u32 {
        let x = 0.3 * f64::from(i);
        let points = scan_at(&far_world, x, 60.0, u64::from(i) + 11);
        far += points.iter().filter(|p| p.x.hypot(p.y) > 30.0).count();
        let scan = Scan {
            stamp_s: 10.0 + 0.1 * f64::from(i),
            points,
        };
        let base = at(x, 0.0, 0.0);
        let pose = PoseMap::from_iso(base);
        m.update(&scan, &at(x, 0.0, SENSOR_H_M), &pose).unwrap();
        m.keep_sweep(scan.stamp_s, &base, &pose, &scan.points);
    }
    assert!(far > 1000, "the wall gives returns beyond the range: {far}");
    assert_eq!(m.rebuild_counts().1, 20, "every sweep kept");
    let again = m
        .remap_unchanged(&base_from_lidar())
        .unwrap()
        .expect("a store");
    let live = m.mapper();
    let l = live.lattice();
    let (c0, r0) = l.cell_of(-30.0, -30.0);
    let (c1, r1) = l.cell_of(36.0, 30.0);
    let (mut observed, mut differ, mut obstacles, mut obstacles_differ) = (0, 0, 0, 0);
    for r in r0..=r1 {
        for c in c0..=c1 {
            let (a, b) = (live.cell(c, r), again.cell(c, r));
            observed += usize::from(a.state != common::grid::CellState::Unknown);
            obstacles += usize::from(live.class(c, r) == Class::Obstacle);
            differ += usize::from(a.state != b.state || a.height_cm != b.height_cm);
            obstacles_differ += usize::from(
                (live.class(c, r) == Class::Obstacle) != (again.class(c, r) == Class::Obstacle),
            );
        }
    }
    println!(
        "rebuild at unchanged poses: {differ} of {observed} observed cells differ, obstacle cells {obstacles_differ} of {obstacles} differ ({far} returns beyond 30 m)"
    );
    assert!(observed > 3000 && obstacles > 10, "{observed} {obstacles}");
    assert_eq!(obstacles_differ, 0, "the same obstacles");
    assert!(
        differ * 100 <= observed,
        "{differ} of {observed} cells differ"
    );
}

/// Sweep `i` mapped at the corrected pose `dz` above the truth (the map frame moved up by a
/// frame shift), kept.
fn drive_sweep_raised(m: &mut TerrainMap, i: u32, dz: f64) {
    let (stamp_s, x, points) = sweep_points(i);
    let scan = Scan { stamp_s, points };
    let pose = PoseMap::from_iso(at(x, 0.0, dz));
    m.update(&scan, &at(x, 0.0, dz + SENSOR_H_M), &pose)
        .expect("a sweep");
    m.keep_sweep(scan.stamp_s, &at(x, DRIFT_Y_M, 0.0), &pose, &scan.points);
}

#[test]
fn a_frame_shift_during_a_rebuild_reaches_the_rebuilt_map_where_the_live_map_took_it() {
    // The frame rises 0.2 m (a GNSS height correction) while the rebuild is ten sweeps behind.
    // The live map's heights followed it after sweep 11; the sweeps after it were mapped (and
    // kept) in the raised frame. The rebuilt map must take the shift at the same point of its
    // feed: taken when it came, the shadow raised the few sweeps it had fed and then added
    // sweeps 5-11 unraised, drawing a 0.2 m step through its ground.
    const SHIFT_AT: u32 = 12;
    const DZ_M: f64 = 0.2;
    let blf = base_from_lidar();
    let shift = at(0.0, 0.0, DZ_M);
    let drive = |m: &mut TerrainMap| {
        for i in 0..10 {
            drive_sweep(m, i, DRIFT_Y_M);
        }
        let _ = m.correct(11.0, &blf, correction).unwrap();
        for i in 10..30u32 {
            let t = 10.0 + 0.1 * f64::from(i);
            let _ = m.advance_rebuild(t, &blf).unwrap();
            if i == SHIFT_AT {
                m.follow_frame(&shift);
            }
            let dz = if i >= SHIFT_AT { DZ_M } else { 0.0 };
            drive_sweep_raised(m, i, dz);
        }
    };
    // Rebuilt at once at the correction: what the map is when every sweep comes in order.
    let mut one_shot = terrain(0);
    drive(&mut one_shot);
    let mut stepped = terrain(2);
    drive(&mut stepped);
    assert_eq!(
        stepped.rebuild_counts(),
        (1, 30),
        "swapped in, every sweep kept"
    );
    assert_eq!(stepped.rebuild_progress(), None);
    let (a, b) = (one_shot.mapper(), stepped.mapper());
    let l = a.lattice();
    let (c0, r0) = l.cell_of(-20.0, -20.0);
    let (c1, r1) = l.cell_of(34.0, 20.0);
    let (mut observed, mut differ, mut obstacles_differ, mut dz_cm) = (0, 0, 0, 0i32);
    for r in r0..=r1 {
        for c in c0..=c1 {
            let (p, q) = (a.cell(c, r), b.cell(c, r));
            observed += usize::from(p.state != common::grid::CellState::Unknown);
            differ += usize::from(p.state != q.state || a.class(c, r) != b.class(c, r));
            obstacles_differ += usize::from(
                (a.class(c, r) == Class::Obstacle) != (b.class(c, r) == Class::Obstacle),
            );
            if p.state != common::grid::CellState::Unknown
                && q.state != common::grid::CellState::Unknown
            {
                dz_cm = dz_cm.max((i32::from(p.height_cm) - i32::from(q.height_cm)).abs());
            }
        }
    }
    println!(
        "shift during a rebuild: {differ} of {observed} observed cells differ from the one-shot map, {obstacles_differ} in obstacle class, max height difference {dz_cm} cm"
    );
    assert!(observed > 1000, "{observed}");
    // Sweeps 10-18 reach the one-shot map as they came and the rebuilt one from the store,
    // quantised to about a millimetre: a few fringe cells may differ (observed in one map
    // only), no obstacle, no height of a cell both observed.
    assert_eq!(
        obstacles_differ, 0,
        "the same obstacles as the one-shot map"
    );
    assert!(
        differ * 50 <= observed,
        "{differ} of {observed} cells differ"
    );
    assert!(dz_cm <= 1, "{dz_cm} cm");
    assert!(obstacles_in(&stepped, TRUE_BOX.0, TRUE_BOX.1) > 0);
    assert_eq!(obstacles_in(&stepped, NORTH.0, NORTH.1), 0);
}

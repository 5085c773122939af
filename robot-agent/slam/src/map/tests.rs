use super::*;

/// A dense "scan" (sensor frame) of a wall at x = `wall_x`, plus an optional box at x = 3.
fn scan(wall_x: f32, with_box: bool) -> Vec<Point> {
    let mut v = Vec::new();
    for ia in -300..=300 {
        for ie in -30..=30 {
            let az = ia as f32 * 0.002;
            let el = ie as f32 * 0.002;
            let dir = Vector3::new(az.cos() * el.cos(), az.sin() * el.cos(), el.sin());
            let in_box = with_box && az.abs() < 0.1 && el.abs() < 0.05;
            let r = if in_box { 3.0 / dir.x } else { wall_x / dir.x };
            let p = dir * r;
            v.push(Point::xyz(p.x, p.y, p.z));
        }
    }
    v
}

fn as_cloud(points: &[Point]) -> OrientedCloud {
    OrientedCloud {
        points: points.iter().map(|p| [p.x, p.y, p.z]).collect(),
        normals: points.iter().map(|_| [-1.0, 0.0, 0.0]).collect(),
    }
}

fn box_points(map: &Map) -> usize {
    map.cloud()
        .points
        .iter()
        .filter(|p| (p[0] - 3.0).abs() < 0.05)
        .count()
}

#[test]
fn fast_atan2_is_close_to_libm() {
    for i in 0..3600 {
        let a = (i as f32).to_radians() * 0.1 - 3.1;
        for r in [0.5f32, 10.0] {
            let (y, x) = (r * a.sin(), r * a.cos());
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{y} {x}");
        }
    }
}

#[test]
fn box_that_moves_away_is_removed_and_the_wall_stays() {
    let cfg = MapConfig::default();
    let dyn_cfg = DynamicConfig::default();
    let mut map = Map::new(MapIndexKind::KdTree, 1.1);
    let first = scan(8.0, true);
    map.update(
        &as_cloud(&first),
        &first,
        &Isometry3::identity(),
        0.0,
        &cfg,
        &dyn_cfg,
    );
    let boxed = box_points(&map);
    assert!(boxed > 100, "box not in the map: {boxed}");
    let wall_before = map.len() - boxed;
    // The box left: the beams now go through where it was and hit the wall.
    let empty = scan(8.0, false);
    for _ in 0..3 {
        map.update(
            &OrientedCloud::default(),
            &empty,
            &Isometry3::identity(),
            1.0,
            &cfg,
            &dyn_cfg,
        );
    }
    assert_eq!(box_points(&map), 0);
    let wall_after = map.len();
    assert!(
        wall_after as f64 > 0.99 * wall_before as f64,
        "wall lost: {wall_before} -> {wall_after}"
    );
    assert!(map.p_dynamic().iter().all(|p| *p < 0.5));
}

#[test]
fn static_scene_seen_again_stays() {
    let mut map = Map::new(MapIndexKind::KdTree, 1.1);
    let s = scan(8.0, true);
    for _ in 0..5 {
        map.update(
            &as_cloud(&s),
            &s,
            &Isometry3::identity(),
            0.0,
            &MapConfig::default(),
            &DynamicConfig::default(),
        );
    }
    assert!(box_points(&map) > 100);
    // Re-observing adds nothing new (all within min_dist_new_point of existing points).
    assert_eq!(map.len(), s.len());
}

#[test]
fn insertion_respects_min_distance_and_distance_limit() {
    let mut map = Map::new(MapIndexKind::KdTree, 1.1);
    let cfg = MapConfig {
        distance_limit_m: 10.0,
        ..MapConfig::default()
    };
    let dyn_cfg = DynamicConfig {
        enabled: false,
        ..DynamicConfig::default()
    };
    let c = OrientedCloud {
        points: vec![[1.0, 0.0, 0.0], [1.05, 0.0, 0.0], [1.2, 0.0, 0.0]],
        normals: vec![[1.0, 0.0, 0.0]; 3],
    };
    let s = map.update(&c, &[], &Isometry3::identity(), 0.0, &cfg, &dyn_cfg);
    assert_eq!(s.added, 3, "an empty map takes everything");
    let c2 = OrientedCloud {
        points: vec![[1.03, 0.0, 0.0], [1.5, 0.0, 0.0]],
        normals: vec![[1.0, 0.0, 0.0]; 2],
    };
    let s = map.update(&c2, &[], &Isometry3::identity(), 1.0, &cfg, &dyn_cfg);
    assert_eq!(s.added, 1);
    let far = Isometry3::translation(20.0, 0.0, 0.0);
    let s = map.update(&OrientedCloud::default(), &[], &far, 2.0, &cfg, &dyn_cfg);
    assert_eq!((s.removed_far, map.len()), (4, 0));
}

/// A VLP-16-like sweep (16 lasers, 2 deg apart, 1800 columns, sensor 0.75 m above flat
/// ground) of a wall at x = 15 m (up to 4 m high), a pole at (5, 3) and, optionally, a person
/// at (6, -1). Returns per-point rings; upward beams that miss everything get no return.
fn ring_scan(person: bool) -> Vec<Point> {
    let ground_z = -0.75f32;
    let cylinders: Vec<(f32, f32, f32, f32)> = {
        let mut c = vec![(5.0, 3.0, 0.08, 3.75)];
        if person {
            c.push((6.0, -1.0, 0.25, 1.0));
        }
        c
    };
    let mut out = Vec::new();
    for col in 0..1800 {
        let az = col as f32 * std::f32::consts::TAU / 1800.0;
        for ring in 0..16u16 {
            let el = (-15.0 + 2.0 * f32::from(ring)).to_radians();
            let d = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let mut best = f32::INFINITY;
            if d.z < 0.0 {
                best = best.min(ground_z / d.z);
            }
            if d.x > 0.0 {
                let t = 15.0 / d.x;
                if (d.z * t) < 3.25 {
                    best = best.min(t);
                }
            }
            for (cx, cy, r, top) in &cylinders {
                // |(t d - c)_xy| = r
                let (dx, dy) = (d.x, d.y);
                let a = dx * dx + dy * dy;
                let b = -2.0 * (dx * cx + dy * cy);
                let c = cx * cx + cy * cy - r * r;
                let disc = b * b - 4.0 * a * c;
                if disc >= 0.0 {
                    let t = (-b - disc.sqrt()) / (2.0 * a);
                    let z = t * d.z;
                    if t > 0.0 && z >= ground_z && z <= *top {
                        best = best.min(t);
                    }
                }
            }
            if best < 100.0 {
                let p = d * best;
                out.push(Point {
                    ring,
                    ..Point::xyz(p.x, p.y, p.z)
                });
            }
        }
    }
    out
}

fn count_near(map: &Map, cx: f32, cy: f32, r: f32, z_min: f32) -> usize {
    map.cloud()
        .points
        .iter()
        .filter(|p| (p[0] - cx).hypot(p[1] - cy) <= r && p[2] >= z_min)
        .count()
}

#[test]
fn a_person_who_walked_away_is_cleared_and_the_pole_and_wall_stay() {
    let cfg = MapConfig::default();
    let dyn_cfg = DynamicConfig::default();
    let mut map = Map::new(MapIndexKind::KdTree, 1.1);
    let with = ring_scan(true);
    map.update(
        &as_cloud(&with),
        &with,
        &Isometry3::identity(),
        0.0,
        &cfg,
        &dyn_cfg,
    );
    // Above the ground under the feet; the person's head is above the sensor, where the
    // lasers that pass through its place later get no return at all.
    let person = count_near(&map, 6.0, -1.0, 0.4, -0.5);
    let pole = count_near(&map, 5.0, 3.0, 0.2, -0.5);
    let wall = map.cloud().points.iter().filter(|p| p[0] > 14.9).count();
    assert!(
        person > 20 && pole > 10 && wall > 200,
        "{person} {pole} {wall}"
    );
    let without = ring_scan(false);
    for _ in 0..6 {
        map.observe(&without, &Isometry3::identity(), &dyn_cfg);
    }
    assert_eq!(count_near(&map, 6.0, -1.0, 0.4, -0.5), 0);
    let pole_after = count_near(&map, 5.0, 3.0, 0.2, -0.5);
    let wall_after = map.cloud().points.iter().filter(|p| p[0] > 14.9).count();
    assert!(pole_after * 10 >= pole * 9, "pole {pole} -> {pole_after}");
    // The wall behind the person was hidden by it in the first scan; nothing of it may go.
    assert!(wall_after >= wall, "wall {wall} -> {wall_after}");
    // Ray-model removals are counted and the index stays usable after them.
    let mut nb = Vec::new();
    map.knn(&[15.0, 0.0, 0.0], 3, 1.0, &mut nb);
    assert_eq!(nb.len(), 3);
    assert!(nb.iter().all(|(i, _)| (*i as usize) < map.len()));
}

#[test]
fn unstructured_scans_skip_the_range_image() {
    let scan = ring_scan(false);
    let flat: Vec<Point> = scan.iter().map(|p| Point::xyz(p.x, p.y, p.z)).collect();
    let dirs: Vec<(f32, f32)> = flat
        .iter()
        .map(|p| angles(&Vector3::new(p.x, p.y, p.z)))
        .collect();
    let ranges: Vec<f32> = flat.iter().map(|p| p.range_m()).collect();
    let rings: Vec<u16> = flat.iter().map(|p| p.ring).collect();
    assert!(RangeImage::new(&rings, &dirs, &ranges, 0.0035, -0.1, 16).is_none());
    let rings: Vec<u16> = scan.iter().map(|p| p.ring).collect();
    // The two top lasers see only the pole (the sky over the wall elsewhere).
    let im = RangeImage::new(&rings, &dirs, &ranges, 0.0035, -0.1, 16).expect("16 rings");
    assert_eq!(im.els.len(), 16);
    let top = im.els[15] - std::f32::consts::FRAC_PI_2;
    assert!(
        (top - 15f32.to_radians()).abs() < 1e-3,
        "{}",
        top.to_degrees()
    );
    let free = im.rows[15].iter().filter(|r| **r == f32::INFINITY).count();
    assert!(free * 100 > 98 * im.rows[15].len(), "{free}");
    // A laser with no return at all is still placed, on the line through the others.
    let skyless: Vec<usize> = (0..scan.len()).filter(|i| scan[*i].ring != 15).collect();
    let pick = |v: &[u16]| skyless.iter().map(|i| v[*i]).collect::<Vec<_>>();
    let im = RangeImage::new(
        &pick(&rings),
        &skyless.iter().map(|i| dirs[*i]).collect::<Vec<_>>(),
        &skyless.iter().map(|i| ranges[*i]).collect::<Vec<_>>(),
        0.0035,
        -0.1,
        16,
    )
    .expect("15 rings seen");
    assert_eq!(im.els.len(), 16);
    let top = im.els[15] - std::f32::consts::FRAC_PI_2;
    assert!(
        (top - 15f32.to_radians()).abs() < 1e-3,
        "{}",
        top.to_degrees()
    );
    assert!(im.rows[15].iter().all(|r| *r == f32::INFINITY));
}
